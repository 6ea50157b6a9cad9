"""The writer thread's half of a Recorder: queued items encoded and written into zstd chunks.

`ChunkWriter` owns the open file and mcap's writer: it registers each topic's channel on
first use (capture.recording.topics), encodes each queued item (capture.recording.encode),
and closes a chunk (`flush`) when the Recorder says: mcap's `Writer.flush()` (mcap >= 1.6)
finishes the open chunk and writes it out, then the file is fsync'ed; `chunk_size` is set
high so that the timer, not the size, decides. The file's end is the last complete chunk
(`good_offset`), where a failed recording is cut back to.
"""

from __future__ import annotations

import collections
import io
import logging
import os
import threading
import time
import zlib
from pathlib import Path

import numpy as np

from capture import __version__
from capture.recording import topics as T
from capture.recording import write_queue as wq
from capture.recording.chunk_digests import CHUNK_DIGESTS, Tally
from capture.recording.digests import Sealer
from capture.recording.encode import (
    Encoded,
    encode_depth,
    encode_event,
    encode_features,
    encode_gait,
    encode_imu,
    encode_inference,
    encode_processed,
    encode_truth,
)
from capture.recording.metadata import CameraRecord
from devices.clock import now_ns

log = logging.getLogger(__name__)

# The live recording's size goal, 2.5 MB/s at 45 fps: on the mock walk zstandard's level 5
# meets it where the default level 3 does not, for more compression time, which the writer
# thread absorbs without adding latency (`walkcap bench` measures both).
ZSTD_LEVEL = 5
ZSTD_LEVEL_FAST = 1  # replay: somewhat larger files than level 5, several times faster


class _ZstdAtLevel(threading.local):
    """Stands in for the zstandard module inside mcap's writer, which compresses every
    chunk with `zstandard.compress(data)` at level 3 and has no setting for the level
    (mcap 1.6). Each recorder's writer thread sets its own level here; any other use
    goes to the real module. Should mcap stop calling `zstandard.compress`, chunks are
    simply written at mcap's own level."""

    level = ZSTD_LEVEL

    def __init__(self, module) -> None:
        self._module = module

    def compress(self, data: bytes) -> bytes:
        return self._module.ZstdCompressor(level=self.level).compress(data)

    def __getattr__(self, name: str):
        return getattr(self._module, name)


def set_zstd_level(level: int) -> None:
    """Chunks written on this thread compressed at `level` (the stand-in installed in
    mcap's writer on first use)."""
    import mcap.writer

    if not isinstance(mcap.writer.zstandard, _ZstdAtLevel):
        mcap.writer.zstandard = _ZstdAtLevel(mcap.writer.zstandard)
    mcap.writer.zstandard.level = level


MEDIA_TYPES = {
    ".toml": "application/toml",
    ".json": "application/json",
    ".npy": "application/x-npy",
    ".txt": "text/plain",
    ".yaml": "application/yaml",
}


class TrackedFile:
    """The recording's file as the mcap writer sees it: complete writes, counted bytes, and
    a CRC-32 of what was written since the last `region` (capture.recording.chunk_digests)."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.position = 0
        self._region_start = 0
        self._crc = 0

    def write(self, data) -> int:
        view = memoryview(data)
        total = len(view)
        self._crc = zlib.crc32(view, self._crc)
        while view:
            n = os.write(self.fd, view)
            self.position += n
            view = view[n:]
        return total

    def tell(self) -> int:
        return self.position

    def region(self) -> tuple[int, int, int]:
        """(offset, length, CRC-32) of the bytes written since the last call."""
        out = (self._region_start, self.position - self._region_start, self._crc)
        self._region_start, self._crc = self.position, 0
        return out

    def flush(self) -> None:
        pass  # nothing is buffered here; fsync() makes it durable

    def fsync(self) -> None:
        os.fsync(self.fd)

    def truncate(self, size: int) -> None:
        os.ftruncate(self.fd, size)
        os.lseek(self.fd, size, os.SEEK_SET)
        self.position = size
        self._region_start, self._crc = size, 0  # a cut file is never finished: no digest

    def close(self) -> None:
        if self.fd >= 0:
            fd, self.fd = self.fd, -1
            os.close(fd)


def _media_type(name: str) -> str:
    return MEDIA_TYPES.get(Path(name).suffix.lower(), "application/octet-stream")


class ChunkWriter:
    """An MCAP file being written in chunks; used by one thread at a time (the Recorder's
    caller while it starts, then its writer thread)."""

    def __init__(
        self,
        file: TrackedFile,
        path: Path,
        *,
        chunk_interval_s: float,
        gray: bool,
        cloud_voxel_m: float,
        cloud_max_points: int,
        declared: dict[str, T.Topic],
    ) -> None:
        from mcap.writer import CompressionType, Writer

        self.file = file
        self.path = path
        self._writer = Writer(file, chunk_size=64 * 1024 * 1024, compression=CompressionType.ZSTD)
        self._sealed = Sealer(self._writer)  # header, metadata, schemas, channels: digests
        self._chunk_interval_s = chunk_interval_s
        self._gray = gray
        self._cloud_voxel_m = cloud_voxel_m
        self._cloud_max_points = cloud_max_points
        self._declared = declared  # topics beyond walkcap's own (the Recorder's, shared)
        self._channels: dict[str, tuple[int, bool]] = {}  # topic -> channel id, sensor data
        self.messages = 0
        self.errors = 0  # items that could not be encoded (logged)
        self.chunks = 0
        self.good_offset = 0  # where the last complete chunk ends
        self.first_ns: int | None = None  # log-time span of the sensor data written
        self.last_ns: int | None = None
        self._span: list[int] | None = None  # sensor log-time span of the open chunk
        self._open_messages = 0
        self._next_flush = 0.0
        self.growth: collections.deque = collections.deque(maxlen=6)  # (wall s, bytes)
        self._geometry = None
        self._frame_times: dict[int, tuple[int, int]] = {}  # index -> (time, log time)
        self._tally: Tally | None = None  # what `info` reads instead of the chunks

    def start(self, metadata: dict[str, dict], attachments: dict[str, bytes]) -> int:
        """Header, metadata records and attachments, on disk; returns their Unix time."""
        from mcap.writer import LIBRARY_IDENTIFIER

        self._tally = Tally(metadata)
        self._sealed.start(
            "",
            f"walkcap {__version__}; {LIBRARY_IDENTIFIER}",
            [(name, T.encode_metadata(values)) for name, values in metadata.items()],
        )
        created = time.time_ns()
        for name, data in attachments.items():
            self._writer.add_attachment(created, now_ns(), name, _media_type(name), bytes(data))
        self._writer.flush()
        self.file.fsync()
        self.good_offset = self.file.tell()
        self._tally.region(*self.file.region())
        self._next_flush = time.monotonic() + self._chunk_interval_s
        return created

    # ---- chunks ---------------------------------------------------------------------------

    def seconds_to_flush(self) -> float:
        return max(0.0, self._next_flush - time.monotonic())

    def flush_due(self) -> bool:
        """A chunk interval passed, by the wall clock or by the sensor data's own times (so
        replayed or synthetic data is chunked as live data is)."""
        if time.monotonic() >= self._next_flush:
            return True
        return (
            self._span is not None and self._span[1] - self._span[0] >= self._chunk_interval_s * 1e9
        )

    def flush(self) -> None:
        """The open chunk written out and fsync'ed."""
        if self._open_messages:
            self._writer.flush()
            self.file.fsync()
            self.chunks += 1
            self.good_offset = self.file.tell()
            if self._tally is not None:
                self._tally.region(*self.file.region())
        self.growth.append((time.monotonic(), self.good_offset))
        self._open_messages = 0
        self._span = None
        self._next_flush = time.monotonic() + self._chunk_interval_s

    def finish(self, end: dict) -> None:
        """The chunk digests, the closing metadata record, summary and index; the file closed."""
        self._writer.flush()  # a chunk still open (the Recorder flushes first) is digested
        if self._tally is not None:
            self._tally.region(*self.file.region())
            self._sealed.metadata(CHUNK_DIGESTS, self._tally.values())
        self._sealed.metadata("recording_end", T.encode_metadata(end))
        self._writer.finish()
        self.file.fsync()
        self.file.close()

    def cut(self) -> None:
        """After a write error: the half-written chunk cut off, the file closed."""
        try:  # the file ends with the last complete chunk
            self.file.truncate(self.good_offset)
            self.file.fsync()
        except OSError:
            pass
        try:
            self.file.close()
        except OSError:
            pass

    # ---- messages -------------------------------------------------------------------------

    def _channel(self, topic: str) -> tuple[int, bool]:
        channel = self._channels.get(topic)
        if channel is None:
            spec = self._declared.get(topic) or T.TOPICS[topic]
            schema = self._sealed.schema(spec.schema_name, spec.schema_encoding, spec.schema_data)
            channel_id = self._sealed.channel(
                topic, spec.message_encoding, schema, {"description": spec.description}
            )
            channel = self._channels[topic] = (channel_id, spec.sensor)
        return channel

    def add(self, m: Encoded) -> None:
        channel_id, sensor = self._channel(m.topic)
        log_time = int(m.log_time)
        publish_time, sequence = int(m.publish_time), int(m.sequence) & 0xFFFFFFFF
        self._writer.add_message(channel_id, log_time, m.data, publish_time, sequence)
        if self._tally is not None:
            self._tally.message(m.topic, log_time, publish_time, sequence, m.data)
        self.messages += 1
        self._open_messages += 1
        if sensor:
            if self.first_ns is None:
                self.first_ns = log_time
            self.last_ns = log_time if self.last_ns is None else max(self.last_ns, log_time)
            if self._span is None:
                self._span = [log_time, log_time]
            else:
                self._span[0] = min(self._span[0], log_time)
                self._span[1] = max(self._span[1], log_time)

    def add_json(self, topic: str, time_ns: int, entry: dict) -> None:
        """A JSON message logged and published at `time_ns` (labels, events)."""
        self.add(Encoded(topic, time_ns, time_ns, T.encode_json(entry)))

    def write(self, item: wq.QueuedItem) -> None:
        """A queued item's messages; an item that cannot be encoded is logged and counted."""
        try:
            messages = self._ENCODERS[type(item)](self, item)
        except OSError:
            raise  # a write error (the geometry attachment): the recording cannot go on
        except Exception:  # bad data or a bug: lose this item, not the recording
            log.exception("recorder: cannot encode %s", item.kind)
            self.errors += 1
            return
        for m in messages:
            self.add(m)

    # ---- encoders: a queued item -> its messages --------------------------------------------

    def _remember(self, index: int, time_ns: int, log_time: int) -> None:
        self._frame_times[index] = (time_ns, log_time)
        if len(self._frame_times) > 512:
            self._frame_times.pop(next(iter(self._frame_times)))

    def _log_time(self, index: int, default: int) -> int:
        return self._frame_times.get(index, (default, default))[1]

    def _encode_depth_frame(self, item: wq.QueuedFrame) -> list[Encoded]:
        frame = item.frame
        t = frame.device_time_ns if item.time_ns is None else item.time_ns
        log_time = frame.host_time_ns
        self._remember(frame.index, t, log_time)
        if frame.geometry != self._geometry:
            self._write_geometry(frame)
        return encode_depth(frame, t, log_time, self._gray)

    def _write_geometry(self, frame) -> None:
        """The rays (once per camera) that turn /camera/depth back into xyz."""
        g = frame.geometry
        rays = np.ascontiguousarray(g.rays(), dtype=np.float32)
        buf = io.BytesIO()
        np.save(buf, rays)
        self._writer.add_attachment(
            time.time_ns(),
            frame.host_time_ns,
            T.RAYS_ATTACHMENT,
            "application/x-npy",
            buf.getvalue(),
        )
        camera = CameraRecord.of(g, T.RAYS_ATTACHMENT, frame.index)
        self._sealed.metadata(camera.NAME, T.encode_metadata(camera.to_dict()))
        self._geometry = g
        off_ray = T.ray_error_m(frame.xyz, rays, frame.confidence)
        if off_ray > 0.0005:  # the rays do not fit royale's points: say so in the file
            t = frame.host_time_ns
            event = {
                "time_ns": t,
                "device": "recorder",
                "kind": "rays_mismatch",
                "message": f"points lie up to {off_ray * 1000:.1f} mm off the camera's "
                "rays: depth rebuilds are approximate",
                "details": {"max_off_ray_m": off_ray},
            }
            self.add_json(T.EVENTS, t, event)
            log.warning("recording %s: %s", self.path, event["message"])

    def _encode_imu_sample(self, item: wq.QueuedImuSample) -> list[Encoded]:
        return encode_imu(item.sample)

    def _encode_processing(self, item: wq.QueuedProcessing) -> list[Encoded]:
        self._remember(item.index, item.time_ns, item.log_time)
        return encode_processed(
            item.index,
            item.time_ns,
            item.log_time,
            item.cloud,
            item.image,
            item.quaternion,
            item.flag,
            self._cloud_voxel_m,
            self._cloud_max_points,
        )

    def _encode_inference(self, item: wq.QueuedInference) -> list[Encoded]:
        return encode_inference(item.index, item.time_ns, item.log_time, item.probs, item.fused)

    def _encode_features(self, item: wq.QueuedFeatures) -> list[Encoded]:
        log_time = self._log_time(item.index, item.time_ns)
        return encode_features(item.index, item.time_ns, log_time, item.features)

    def _encode_truth(self, item: wq.QueuedTruth) -> list[Encoded]:
        log_time = self._log_time(item.index, item.time_ns)
        return encode_truth(item.index, item.time_ns, log_time, item.truth)

    def _encode_gait(self, item: wq.QueuedGait) -> list[Encoded]:
        return encode_gait(item.event, item.log_time)

    def _take_encoded_frame(self, item: wq.QueuedEncodedFrame) -> list[Encoded]:
        self._remember(item.index, item.time_ns, item.log_time)
        return item.messages

    def _take_recorded(self, item: wq.QueuedRecorded) -> list[Encoded]:
        return item.messages

    def _encode_message(self, item: wq.QueuedMessage) -> list[Encoded]:
        if item.topic not in self._declared:
            raise ValueError(f"{item.topic}: not declared")
        return [Encoded(item.topic, item.log_time, item.time_ns, T.encode_json(item.message))]

    def _encode_device_event(self, item: wq.QueuedDeviceEvent) -> list[Encoded]:
        return encode_event(item.event)

    _ENCODERS = {
        wq.QueuedFrame: _encode_depth_frame,
        wq.QueuedImuSample: _encode_imu_sample,
        wq.QueuedProcessing: _encode_processing,
        wq.QueuedInference: _encode_inference,
        wq.QueuedFeatures: _encode_features,
        wq.QueuedTruth: _encode_truth,
        wq.QueuedGait: _encode_gait,
        wq.QueuedEncodedFrame: _take_encoded_frame,
        wq.QueuedRecorded: _take_recorded,
        wq.QueuedDeviceEvent: _encode_device_event,
        wq.QueuedMessage: _encode_message,
    }
