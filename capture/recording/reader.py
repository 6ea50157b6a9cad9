"""Reading walkcap recordings in Python: metadata, topics decoded into numpy and dicts.

    rec = open_recording("S01_indoor_t01.mcap")
    rec.metadata["session"]["subject"]
    for m in rec.messages(["/camera/cloud"]):    # m.data: (N, 3) float32
        ...
    trial = read_trial(path)                     # per-frame arrays for evaluation
    for frame in depth_frames(path):             # DepthFrame with xyz rebuilt exactly
        ...

Finished files are read through their index. Unfinished ones (a crash, a full disk) are
read record by record up to where they stop (capture.recording._mcap.scan), so everything that
reached the disk is readable without `walkcap recover`.
Messages are decoded with the schema stored in the file (protobuf descriptors, JSON).
Metadata comes back typed (JSON values; older files' known fields parsed from text).
Times are session-clock nanoseconds; `Recording.unix_time_ns` and
`RecordedMessage.unix_time_ns` give the same instants as Unix time. The operator's labels
are read with their undos applied (`effective_changes`); the file keeps both.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import struct
import zlib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import orjson

from capture.errors import CaptureError
from capture.recording import topics as T
from capture.recording._mcap import (
    RECORD_HEAD,
    Damage,
    ScanResult,
    check_magic,
    file_bytes,
    scan,
    summary_damage,
)
from devices.frames import MODES, CameraGeometry, DepthFrame, ImuSample


@dataclass
class RecordedMessage:
    topic: str
    log_time_ns: int  # host receive time, session clock
    publish_time_ns: int  # sample time, session clock
    sequence: int  # frame index for camera topics, packet counter for /imu
    data: Any  # numpy array (images, clouds, quaternions) or dict (JSON topics)
    unix_offset_ns: int | None = None  # the recording's session clock -> Unix time

    @property
    def unix_time_ns(self) -> int | None:
        """The sample time (publish time) as Unix time, ns; None if the file has no offset."""
        return None if self.unix_offset_ns is None else self.publish_time_ns + self.unix_offset_ns


@dataclass
class TopicInfo:
    topic: str
    count: int
    schema_name: str
    message_encoding: str
    description: str = ""


@dataclass
class Recording:
    path: Path
    complete: bool  # finished by the writer (summary and index present)
    reason: str  # why an unfinished file stops where it does
    size: int
    library: str
    metadata: dict[str, dict[str, Any]]  # the last record of each name, values typed
    metadata_records: list[tuple[str, dict[str, Any]]]  # all, in file order, typed
    attachments: dict[str, bytes]  # the last attachment of each name
    attachment_sizes: dict[str, int]
    topics: dict[str, TopicInfo]
    start_ns: int | None  # first and last log time of any message
    end_ns: int | None
    _log_times: dict[str, np.ndarray] | None = field(default=None, repr=False)
    raw_metadata_records: list[tuple[str, dict[str, str]]] = field(default_factory=list)
    # Damaged regions found while opening an unfinished file (a finished one is read
    # through its index: `capture.recording._mcap.check` reads and checks every chunk).
    damaged: list[Damage] = field(default_factory=list)

    @property
    def duration_s(self) -> float:
        return 0.0 if self.start_ns is None else (self.end_ns - self.start_ns) * 1e-9

    @property
    def unix_offset_ns(self) -> int | None:
        """Add to a session-clock time (any log or publish time) for Unix time in ns."""
        value = self.metadata.get("recording", {}).get("unix_offset_ns")
        try:
            return int(value) if value not in (None, "") else None
        except (TypeError, ValueError):
            return None

    def unix_time_ns(self, session_ns):
        """Session-clock time(s) as Unix time in ns (None when the file has no offset)."""
        offset = self.unix_offset_ns
        if offset is None or session_ns is None:
            return None
        if isinstance(session_ns, np.ndarray):
            return session_ns.astype(np.int64) + offset
        return int(session_ns) + offset

    @property
    def id(self) -> str:
        """The recording's unique id; files without one get a stand-in from their name."""
        derived = self.metadata.get("derivation", {}).get("id")
        return str(
            derived or self.metadata.get("recording", {}).get("id") or f"file:{self.path.name}"
        )

    @property
    def trial(self) -> tuple[str, str, int | None]:
        """(subject, condition, trial) from the session metadata."""
        session = self.metadata.get("session", {})
        try:
            number = int(session.get("trial"))
        except (TypeError, ValueError):
            number = None
        return str(session.get("subject") or ""), str(session.get("condition") or ""), number

    def messages(
        self, topics: Iterable[str] | str | None = None, *, raw: bool = False
    ) -> Iterator[RecordedMessage]:
        """Messages in file order (which is time order per topic), decoded with the file's
        schemas; `raw=True` gives the protobuf objects and JSON dicts without conversion."""
        if isinstance(topics, str):
            topics = [topics]
        wanted = None if topics is None else set(topics)
        decoders = _Decoders()
        offset = self.unix_offset_ns
        with _damage_is_an_error(self.path):
            for schema, channel, message in _iter_raw(self.path, self.complete, wanted):
                decoded = decoders.decode(schema, channel, message.data)
                if not raw:
                    decoded = convert(channel.topic, decoded)
                yield RecordedMessage(
                    channel.topic,
                    message.log_time,
                    message.publish_time,
                    message.sequence,
                    decoded,
                    offset,
                )

    def read(self, topic: str, *, raw: bool = False) -> list[RecordedMessage]:
        return list(self.messages([topic], raw=raw))

    def sequences(self, topic: str) -> list[tuple[int, int, int]]:
        """(sequence, publish time, log time) of every message on `topic`, in log-time
        order, without decoding them: a sensor's own count and clock beside the host's."""
        with _damage_is_an_error(self.path):
            items = [
                (m.sequence, m.publish_time, m.log_time)
                for _, _, m in _iter_raw(self.path, self.complete, {topic})
            ]
        return sorted(items, key=lambda x: x[2])

    def log_times(self) -> dict[str, np.ndarray]:
        """Sorted log times of every topic, from the index when there is one (no decoding)."""
        if self._log_times is None:
            with _damage_is_an_error(self.path):
                self._log_times = _log_times(self.path, self.complete)
        return self._log_times

    def rays(self) -> np.ndarray:
        """The camera's unit ray per pixel (H, W, 3) float32, as recorded."""
        data = self.attachments.get(T.RAYS_ATTACHMENT)
        if data is None:
            raise CaptureError(f"{self.path}: no {T.RAYS_ATTACHMENT} (no depth frames recorded)")
        return np.load(io.BytesIO(data))

    def geometry(self) -> CameraGeometry:
        camera = self.metadata.get("camera")
        if not camera:
            return CameraGeometry()
        kwargs = {}
        for name in CameraGeometry.__dataclass_fields__:
            if name in camera:
                kwargs[name] = type(getattr(CameraGeometry(), name))(camera[name])
        return CameraGeometry(**kwargs)


@contextlib.contextmanager
def _damage_is_an_error(path: Path):
    """Bytes damaged inside a finished file (a bad disk, a bad copy) surface from the mcap,
    zstd and protobuf libraries as their own exceptions: one clear error instead."""
    try:
        yield
    except CaptureError:
        raise
    except Exception as e:
        raise CaptureError(
            f"{path}: the file is damaged ({type(e).__name__}: {e}); "
            "copy what is readable with `walkcap recover`"
        ) from None


def _damage_line(path: Path, what: str) -> str:
    return f"{path}: damaged, {what}; copy what is intact with `walkcap recover`"


def convert(topic: str, decoded: Any) -> Any:
    """A decoded message as walkcap data: images as arrays, clouds (N, 3), quaternions."""
    if topic in (T.DEPTH, T.CONFIDENCE, T.GRAY, T.BINARY_IMAGE):
        return T.image_from_message(decoded)
    if topic == T.CLOUD:
        return T.cloud_from_message(decoded)
    if topic == T.TF:
        return T.quaternion_from_transform(decoded)
    return decoded


class _Decoders:
    """Decoders built from the schemas in the file: protobuf descriptors, JSON."""

    def __init__(self) -> None:
        from mcap_protobuf.decoder import DecoderFactory

        self._protobuf = DecoderFactory()
        self._by_channel: dict[int, Any] = {}

    def decode(self, schema, channel, data: bytes) -> Any:
        decoder = self._by_channel.get(channel.id)
        if decoder is None:
            if channel.message_encoding == "json":
                decoder = orjson.loads
            else:
                decoder = self._protobuf.decoder_for(channel.message_encoding, schema)
                if decoder is None:
                    raise CaptureError(
                        f"{channel.topic}: cannot decode {channel.message_encoding} "
                        f"messages with schema {schema.name if schema else None}"
                    )
            self._by_channel[channel.id] = decoder
        return decoder(data)


def _iter_raw(path: Path, complete: bool, topics: set[str] | None):
    """(schema, channel, message) in file order."""
    from mcap.records import Channel, Message, Schema

    with open(path, "rb") as f:
        if complete:
            yield from _iter_indexed(f, topics)
            return
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        result = ScanResult()
        origin = None
        for record in scan(f, result):
            if result.lost:  # every reader stops at damage, with the same line
                raise CaptureError(_damage_line(path, result.lost[0].describe(origin)))
            if isinstance(record, Message) and origin is None:
                origin = record.log_time
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                channel = channels.get(record.channel_id)
                if channel is None or (topics is not None and channel.topic not in topics):
                    continue
                yield schemas.get(channel.schema_id), channel, record


_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time


def _iter_indexed(f, topics: set[str] | None):
    """A finished file's messages chunk by chunk, in file order, through its index:
    chunks without a wanted channel are not read, and one chunk is in memory at a time
    (the mcap library's file-order iteration opens every chunk before the first message:
    a whole long recording in memory, and a wait before anything comes)."""
    from mcap.reader import make_reader
    from mcap.records import Message

    summary = make_reader(f).get_summary()
    wanted = {cid for cid, c in summary.channels.items() if topics is None or c.topic in topics}
    if not wanted:
        return
    stats = summary.statistics
    origin = stats.message_start_time if stats is not None and stats.message_count else None
    for index in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
        if index.message_index_offsets and wanted.isdisjoint(index.message_index_offsets):
            continue
        try:
            messages = list(
                _chunk_messages(f, index.chunk_start_offset, index.chunk_length, wanted)
            )
        except Exception as e:  # CRC, zstd or a record running past the chunk's end
            damage = Damage(
                index.chunk_start_offset,
                index.chunk_length,
                str(e) or type(e).__name__,
                index.message_start_time,
                index.message_end_time,
                tuple(
                    sorted(
                        summary.channels[c].topic
                        for c in index.message_index_offsets
                        if c in summary.channels
                    )
                ),
            )
            raise CaptureError(_damage_line(Path(f.name), damage.describe(origin))) from None
        for cid, sequence, log_time, publish_time, data in messages:
            channel = summary.channels[cid]
            yield (
                summary.schemas.get(channel.schema_id),
                channel,
                Message(
                    channel_id=cid,
                    sequence=sequence,
                    log_time=log_time,
                    publish_time=publish_time,
                    data=data,
                ),
            )


def _chunk_messages(f, offset: int, length: int, wanted: set[int]):
    """(channel id, sequence, log time, publish time, data) of the chunk record at
    `offset`, for the wanted channels. Damage raises (ValueError, zstd's errors). The
    records inside are walked here rather than by mcap's breakup_chunk, which builds an
    object for every message: most are IMU samples a frame reader skips."""
    from mcap.data_stream import ReadDataStream
    from mcap.opcode import Opcode
    from mcap.records import Chunk

    f.seek(offset)
    record = f.read(length)
    if len(record) != length:  # the record's head is not read: the index (CRC) says where
        raise ValueError(f"no chunk at byte {offset}")
    chunk = Chunk.read(ReadDataStream(io.BytesIO(memoryview(record)[RECORD_HEAD.size :])))
    if chunk.compression == "zstd":
        import zstandard

        records = zstandard.ZstdDecompressor().decompress(
            chunk.data, max_output_size=chunk.uncompressed_size
        )
    elif chunk.compression == "":
        records = chunk.data
    else:
        raise ValueError(f"chunk compression {chunk.compression!r}: walkcap reads zstd or none")
    if len(records) != chunk.uncompressed_size:
        raise ValueError(
            f"chunk at byte {offset}: {len(records)} bytes, not {chunk.uncompressed_size}"
        )
    if chunk.uncompressed_crc and zlib.crc32(records) != chunk.uncompressed_crc:
        raise ValueError("chunk CRC mismatch")
    at, end = 0, len(records)
    while at < end:
        opcode, body_length = RECORD_HEAD.unpack_from(records, at)
        at += RECORD_HEAD.size
        if at + body_length > end:
            raise ValueError(f"chunk at byte {offset}: a record runs past its end")
        if opcode == Opcode.MESSAGE:
            cid, sequence, log_time, publish_time = _MESSAGE_HEAD.unpack_from(records, at)
            if cid in wanted:
                yield (
                    cid,
                    sequence,
                    log_time,
                    publish_time,
                    records[at + _MESSAGE_HEAD.size : at + body_length],
                )
        at += body_length


def open_recording(path: str | os.PathLike) -> Recording:
    """Open a recording: metadata, attachments and topic counts, finished or not.
    Raises CaptureError (one line) for a missing file or one that is not MCAP."""

    p = Path(path)
    if not p.exists():
        raise CaptureError(f"{p}: no such file")
    check_magic(p)
    with _damage_is_an_error(p):
        return _open(p)


def _open(p: Path) -> Recording:
    from mcap.reader import make_reader

    size = p.stat().st_size
    with open(p, "rb") as f:
        try:
            reader = make_reader(f)
            summary = None if summary_damage(file_bytes(f)) else reader.get_summary()
        except Exception:  # no footer, cut-off summary: read it record by record
            summary = None
        if summary is not None and summary.statistics is not None:
            raw = [(m.name, dict(m.metadata)) for m in reader.iter_metadata()]
            records = decode_metadata_records(raw)
            attachments = {a.name: a.data for a in reader.iter_attachments()}
            sizes = {a.name: a.data_size for a in summary.attachment_indexes}
            stats = summary.statistics
            topics = {}
            for cid, channel in summary.channels.items():
                schema = summary.schemas.get(channel.schema_id)
                topics[channel.topic] = TopicInfo(
                    channel.topic,
                    stats.channel_message_counts.get(cid, 0),
                    schema.name if schema else "",
                    channel.message_encoding,
                    channel.metadata.get("description", ""),
                )
            library = reader.get_header().library
            start = stats.message_start_time if stats.message_count else None
            end = stats.message_end_time if stats.message_count else None
            return Recording(
                p,
                True,
                "",
                size,
                library,
                dict(records),
                records,
                attachments,
                sizes,
                topics,
                start,
                end,
                raw_metadata_records=raw,
            )
    return _open_unfinished(p, size)


def _open_unfinished(p: Path, size: int) -> Recording:
    from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema

    result = ScanResult()
    schemas, channels = {}, {}
    raw, attachments = [], {}
    counts: dict[int, int] = {}
    times: dict[int, list[int]] = {}
    library = ""
    with open(p, "rb") as f:
        for record in scan(f, result):
            if isinstance(record, Message):
                counts[record.channel_id] = counts.get(record.channel_id, 0) + 1
                times.setdefault(record.channel_id, []).append(record.log_time)
            elif isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Metadata):
                raw.append((record.name, dict(record.metadata)))
            elif isinstance(record, Attachment):
                attachments[record.name] = record.data
            elif isinstance(record, Header):
                library = record.library
    if result.records == 0 and result.reason.startswith(("unreadable", "damaged")):
        raise CaptureError(f"{p}: no MCAP record can be read after the magic ({result.reason})")
    topics, log_times = {}, {}
    for cid, channel in channels.items():
        schema = schemas.get(channel.schema_id)
        topics[channel.topic] = TopicInfo(
            channel.topic,
            counts.get(cid, 0),
            schema.name if schema else "",
            channel.message_encoding,
            channel.metadata.get("description", ""),
        )
        log_times[channel.topic] = np.sort(np.asarray(times.get(cid, []), dtype=np.int64))
    every = [t for ts in log_times.values() for t in (ts[:1].tolist() + ts[-1:].tolist())]
    records = decode_metadata_records(raw)
    return Recording(
        p,
        False,
        result.reason or "no summary",
        size,
        library,
        dict(records),
        records,
        attachments,
        {k: len(v) for k, v in attachments.items()},
        topics,
        min(every) if every else None,
        max(every) if every else None,
        log_times,
        raw,
        result.damaged,
    )


# Files written before metadata values were JSON hold strings: the known fields are typed
# here so that old and new files read alike.
_INT, _FLOAT, _BOOL = "int", "float", "bool"
_STRING_FIELDS = {
    "session": {
        "height_m": _FLOAT,
        "weight_kg": _FLOAT,
        "age": _INT,
        "amputee": _BOOL,
        "residual_limb_cm": _FLOAT,
        "trial": _INT,
    },
    "recording": {
        "unix_offset_ns": _INT,
        "chunk_interval_s": _FLOAT,
        "cloud_quantum_m": _FLOAT,
        "cloud_max_points": _INT,
        "cloud_voxel_m": _FLOAT,
    },
    "recording_end": {
        k: _INT
        for k in ("messages", "chunks", "dropped", "errors", "labels", "closed_unix_time_ns")
    },
    "camera": {
        "width": _INT,
        "height": _INT,
        "fx": _FLOAT,
        "fy": _FLOAT,
        "cx": _FLOAT,
        "cy": _FLOAT,
        "min_range_m": _FLOAT,
        "max_range_m": _FLOAT,
        "from_frame_index": _INT,
    },
}


def _typed_string(text: str, kind: str | None) -> Any:
    if kind is None:
        return text
    if text == "" or text == "None":
        return None
    try:
        if kind == _BOOL:
            return {"true": True, "false": False}.get(text.lower(), text)
        return int(text) if kind == _INT else float(text)
    except ValueError:
        return text


def decode_metadata_records(
    raw: list[tuple[str, dict[str, str]]],
) -> list[tuple[str, dict[str, Any]]]:
    """Metadata records with typed values: JSON values decoded (capture.recording.topics), or, in
    files from before JSON values, the known fields parsed from their strings."""
    json_values = any(
        name == "recording" and T.METADATA_VALUES_KEY in values for name, values in raw
    )
    out = []
    for name, values in raw:
        if json_values or name in T.JSON_ONLY_RECORDS:
            out.append((name, {k: T.decode_metadata_value(v) for k, v in values.items()}))
        else:
            kinds = _STRING_FIELDS.get(name, {})
            out.append((name, {k: _typed_string(v, kinds.get(k)) for k, v in values.items()}))
    return out


def _log_times(path: Path, complete: bool) -> dict[str, np.ndarray]:
    """Log times per topic from the message indexes: no chunk is decompressed."""
    from mcap.data_stream import ReadDataStream
    from mcap.reader import make_reader
    from mcap.records import MessageIndex

    times: dict[str, list[int]] = {}
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
        for channel in summary.channels.values():
            times.setdefault(channel.topic, [])
        for chunk in summary.chunk_indexes:
            if not chunk.message_index_offsets:  # no index: read the chunk itself
                return {k: v for k, v in _scan_times(path).items()}
            for cid, offset in chunk.message_index_offsets.items():
                if cid not in summary.channels:  # a damaged index: read the messages instead
                    return _scan_times(path)
                f.seek(offset + 9)
                index = MessageIndex.read(ReadDataStream(f))
                times[summary.channels[cid].topic].extend(t for t, _ in index.records)
    return {k: np.sort(np.asarray(v, dtype=np.int64)) for k, v in times.items()}


def _scan_times(path: Path) -> dict[str, np.ndarray]:
    times: dict[str, list[int]] = {}
    for _, channel, message in _iter_raw(path, False, None):
        times.setdefault(channel.topic, []).append(message.log_time)
    return {k: np.sort(np.asarray(v, dtype=np.int64)) for k, v in times.items()}


# ---- analysis helpers -------------------------------------------------------------------


def imu_sample(d: dict) -> ImuSample:
    """An /imu message, decoded, as the ImuSample the driver delivered."""

    def arr(key):
        v = d.get(key)
        return None if v is None else np.asarray(v, dtype=np.float64)

    return ImuSample(
        host_time_ns=int(d["host_time_ns"]),
        time_ns=d.get("time_ns"),
        packet_counter=d.get("packet_counter"),
        sample_time_fine=d.get("sample_time_fine"),
        quaternion=arr("quaternion"),
        acceleration=arr("acceleration"),
        rate_of_turn=arr("rate_of_turn"),
        status_word=d.get("status_word"),
        extra=d.get("extra") or {},
    )


def mode_index(mode: str | None) -> int:
    return MODES.index(mode) if mode in MODES else -1


def read_trial(path: str | os.PathLike) -> dict:
    """Per-frame arrays of one trial, in frame order (frames with a CNN output):

    - frame_index (N,), time_ns (N,): the frame's sample time, session clock;
      unix_time_ns (N,): the same instant as Unix time (None if the file has no offset)
    - probabilities (N, 5): CNN softmax, mode order MODES
    - cnn_decisions (N,): argmax; decisions (N,): the fused (HMM) decision recorded for
      the frame, -1 if none; voted (N,): the voted decision, -1 if none
    - labels (N,): the operator's mode in force at the frame's time (-1: none yet), undos
      applied (effective_changes: an undone change never happened)
    - truth (N,) simulator's true mode, or None when the recording has no /sim/truth
    - the two references (inference.evaluation): locomotion (N,), the subject's mode keyed
      live (undos applied, offline corrections not); terrain (N,), what each image shows:
      the simulator's truth, else the labels made offline in `replay --tui` laid over the
      live keys (`labels`), else None; terrain_source: "simulator", "offline labels" or None
    - camera_elevation_deg (N,): the camera's optical axis above the horizon (/tf), NaN
      where the frame had no orientation: the gait cue of fusion "steady+gait"
    - label_changes: every recorded change [(time_ns, mode, source)] in time order, undos
      and what they undid included (the audit trail); reference_changes: the ones that
      define `labels`; metadata (typed); id; modes: MODES
    """
    rec = open_recording(path)
    cnn: dict[int, dict] = {}
    fused: dict[int, int] = {}
    voted: dict[int, int] = {}
    truth: dict[int, int] = {}
    changes: list[tuple[int, str, str]] = []
    elevation: dict[int, float] = {}
    wanted = [T.CNN, T.FUSED, T.LABELS, T.TRUTH, T.TF]
    for m in rec.messages(wanted):
        d = m.data
        if m.topic == T.CNN:
            cnn[int(d["frame_index"])] = d
        elif m.topic == T.FUSED:
            fused[int(d["frame_index"])] = mode_index(d.get("decision"))
            if d.get("voted") is not None and d.get("voted_frame_index") is not None:
                voted[int(d["voted_frame_index"])] = mode_index(d["voted"])
        elif m.topic == T.LABELS:
            changes.append((int(d["time_ns"]), d.get("mode", ""), d.get("source", "")))
        elif m.topic == T.TRUTH:
            truth[int(d["frame_index"])] = mode_index(d.get("mode"))
        elif m.topic == T.TF:  # camera -> world [w, x, y, z]: the optical axis's height
            _, x, y, _ = (float(v) for v in d)
            elevation[m.sequence] = math.degrees(
                math.asin(max(-1.0, min(1.0, 1 - 2 * (x * x + y * y))))
            )
    index = np.array(sorted(cnn), dtype=np.int64)
    times = np.array([int(cnn[i]["time_ns"]) for i in index], dtype=np.int64)
    probs = np.array(
        [[np.nan if p is None else p for p in cnn[i]["probabilities"]] for i in index],
        dtype=np.float64,
    ).reshape(-1, len(MODES))
    changes.sort(key=lambda c: c[0])  # stable: same-time changes keep their file order
    reference = effective_changes(changes)
    labels = labels_at(times, reference)
    truth_array = (
        np.array([truth.get(int(i), -1) for i in index], dtype=int)
        if T.TRUTH in rec.topics
        else None
    )
    offline = any(c[2] == CORRECTION for c in changes)
    terrain_source = (
        "simulator" if truth_array is not None else "offline labels" if offline else None
    )
    return {
        "frame_index": index,
        "time_ns": times,
        "unix_time_ns": rec.unix_time_ns(times),
        "probabilities": probs,
        "cnn_decisions": np.array([mode_index(cnn[i]["decision"]) for i in index], dtype=int),
        "decisions": np.array([fused.get(int(i), -1) for i in index], dtype=int),
        "voted": np.array([voted.get(int(i), -1) for i in index], dtype=int),
        "labels": labels,
        "truth": truth_array,
        "locomotion": labels_at(times, [c for c in reference if c[2] != CORRECTION]),
        "terrain": truth_array if truth_array is not None else labels if offline else None,
        "terrain_source": terrain_source,
        "camera_elevation_deg": np.array([elevation.get(int(i), np.nan) for i in index]),
        "label_changes": changes,
        "reference_changes": reference,
        "metadata": rec.metadata,
        "id": rec.id,
        "modes": MODES,
    }


def read_trials(paths, reference: str = "terrain") -> list:
    """Evaluation trials (inference.evaluation.Trial) from recordings, one a file.

    reference: what accuracy is scored against, "terrain" (what the images show) or
    "locomotion" (the subject's mode keyed live); see read_trial.
    """
    return [read_evaluation_trial(p, reference) for p in paths]


def read_evaluation_trial(path, reference: str = "terrain", name: str | None = None):
    """One recording's evaluation trial (see read_trials), named `name` (default: the
    path); one task of a corpus job (capture.corpus.jobs)."""
    from inference.evaluation import trial_from_recording

    return trial_from_recording(str(name or path), read_trial(path), reference)


def labeled_session(path: str | os.PathLike, reference: str = "terrain"):
    """The recording as a training session (inference.dataset.LabeledSession): every
    classifier input image, labelled with what it shows (`reference` "terrain": the
    simulator's truth where the recording has it, else the labels), the operator's mode at
    its time ("labels"), or the simulator's truth ("truth"); -1 where there is none."""
    from inference.dataset import LabeledSession

    rec = open_recording(path)
    images: dict[int, np.ndarray] = {}
    times: dict[int, int] = {}
    for m in rec.messages([T.BINARY_IMAGE]):
        images[m.sequence] = (np.asarray(m.data) > 0).astype(np.uint8)
        times[m.sequence] = m.publish_time_ns
    if not images:
        raise CaptureError(f"{rec.path}: no classifier images (/camera/binary_image) to train on")
    index = sorted(images)
    t = np.array([times[i] for i in index], dtype=np.int64)
    if reference == "terrain":
        reference = "truth" if T.TRUTH in rec.topics else "labels"
    if reference == "truth":
        truth = {
            int(m.data["frame_index"]): mode_index(m.data.get("mode"))
            for m in rec.messages([T.TRUTH])
        }
        labels = np.array([truth.get(i, -1) for i in index], dtype=np.int64)
    else:
        changes = sorted(
            (
                (int(m.data["time_ns"]), m.data.get("mode", ""), m.data.get("source", ""))
                for m in rec.messages([T.LABELS])
            ),
            key=lambda c: c[0],
        )
        labels = labels_at(t, effective_changes(changes)).astype(np.int64)
    session = rec.metadata.get("session", {})
    return LabeledSession(
        name=Path(rec.path).stem,
        images=np.stack([images[i] for i in index]),
        labels=labels,
        preset=session.get("condition", ""),
        source="recording",
        meta={"path": str(rec.path), "session": dict(session), "reference": reference},
    )


UNDO = "undo"  # a label whose source is "undo" or "undo:MODE" takes back a change
CORRECTION = "correction"  # labels added in the replay UI (tui.replay), over the originals


def is_undo(source: str) -> bool:
    return source == UNDO or source.startswith(UNDO + ":")


def effective_changes(changes: list[tuple[int, str, str]]) -> list[tuple[int, str, str]]:
    """The label changes that define the reference, in time order: each undo removes the
    latest change still in force before it, as if it never happened (the mode before it
    holds from its time); two undos remove two changes. The undo itself records the mode
    the operator went back to: where that differs from what is left (the undone change was
    the first in the file, e.g. the mode in force at the start), that mode holds from the
    undone change's time. Corrections (source "correction") are laid over the result:
    they apply from their time until the next change."""
    ordered = sorted(changes, key=lambda c: c[0])  # stable: same-time changes keep file order
    kept: list[tuple[int, str, str]] = []
    for change in ordered:
        t, mode, source = change
        if source == CORRECTION:
            continue
        if not is_undo(source):
            kept.append(change)
            continue
        if not kept:
            continue  # nothing in this file to take back
        undone = kept.pop()
        before = kept[-1][1] if kept else ""
        if mode and mode != before:
            kept.append((undone[0], mode, source))
    corrections = [c for c in ordered if c[2] == CORRECTION]
    return sorted(kept + corrections, key=lambda c: c[0])


def labels_at(times_ns: np.ndarray, changes: list[tuple[int, str, str]]) -> np.ndarray:
    """The mode index in force at each time: the last change at or before it (-1: none)."""
    out = np.full(len(times_ns), -1, dtype=int)
    if not changes:
        return out
    change_times = np.array([c[0] for c in changes], dtype=np.int64)
    modes = np.array([mode_index(c[1]) for c in changes], dtype=int)
    k = np.searchsorted(change_times, np.asarray(times_ns, dtype=np.int64), side="right") - 1
    ok = k >= 0
    out[ok] = modes[k[ok]]
    return out


_TRUTH_WAIT_FRAMES = 64  # frames held back waiting for their truth, at most


def depth_frames(path: str | os.PathLike) -> Iterator[DepthFrame]:
    """The recorded depth frames with xyz rebuilt from range and rays (within 0.5 mm along
    each ray), confidence as recorded, gray if recorded (else zeros), truth if present.
    device_time_ns is the recorded sample time (publish time)."""
    rec = open_recording(path)
    if T.DEPTH not in rec.topics:
        return
    rays = rec.rays()
    geometry = rec.geometry()
    parts = (T.DEPTH, T.CONFIDENCE) + ((T.GRAY,) if T.GRAY in rec.topics else ())
    with_truth = T.TRUTH in rec.topics
    pending: dict[int, dict] = {}  # frames still missing a part
    whole: dict[int, dict] = {}  # frames waiting for their truth
    truth: dict[int, dict] = {}
    last_truth = -1
    # One pass: a frame's truth is written next to its depth; a frame goes out once its
    # truth is read, or once a later frame's truth shows that it has none.
    for m in rec.messages(parts + ((T.TRUTH,) if with_truth else ())):
        if m.topic == T.TRUTH:
            t = dict(m.data)
            index = int(t.pop("frame_index"))
            truth[index] = t
            last_truth = max(last_truth, index)
        else:
            entry = pending.setdefault(m.sequence, {"log": m.log_time_ns, "pub": m.publish_time_ns})
            entry[m.topic] = m.data
            if all(p in entry for p in parts):
                whole[m.sequence] = pending.pop(m.sequence)
        ready = [i for i in whole if not with_truth or i in truth or i < last_truth]
        if len(whole) > _TRUTH_WAIT_FRAMES:  # the truth stopped: wait no longer
            ready = list(whole)
        for index in sorted(ready):
            yield _frame(index, whole.pop(index), rays, geometry, truth.pop(index, None))
    for index, entry in sorted({**whole, **pending}.items()):  # a cut file: best effort
        if T.DEPTH in entry:
            yield _frame(index, entry, rays, geometry, truth.get(index))


def _frame(
    index: int, entry: dict, rays: np.ndarray, geometry: CameraGeometry, truth: dict | None
) -> DepthFrame:
    depth = entry[T.DEPTH]
    confidence = entry.get(T.CONFIDENCE)
    if confidence is None:
        confidence = np.where(depth > 0, 255, 0).astype(np.uint8)
    gray = entry.get(T.GRAY)
    if gray is None:
        gray = np.zeros(depth.shape, np.uint16)
    if truth is not None:
        truth = {k: v for k, v in truth.items() if k != "time_ns"}
    return DepthFrame(
        index=index,
        device_time_ns=entry["pub"],
        host_time_ns=entry["log"],
        xyz=T.xyz_from_range(depth, rays),
        confidence=confidence,
        gray=gray,
        geometry=geometry,
        truth=truth,
        range_mm=depth,
    )


def find_gaps(
    times_ns: np.ndarray, factor: float | None = None, period_s: float | None = None
) -> list[tuple[int, float]]:
    """Gaps in a regular stream: intervals longer than `factor` (default: the live alarms'
    GAP_PERIODS) x the period (default: the median interval), as (start time ns, length s)."""
    from capture.recording.gaps import GAP_PERIODS

    factor = GAP_PERIODS if factor is None else factor
    t = np.asarray(times_ns, dtype=np.int64)
    if len(t) < 3:
        return []
    dt = np.diff(t)
    median = period_s * 1e9 if period_s else float(np.median(dt))
    if median <= 0:
        return []
    long = np.nonzero(dt > factor * median)[0]
    return [(int(t[i]), float(dt[i]) * 1e-9) for i in long]
