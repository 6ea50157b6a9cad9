"""The Recorder: one MCAP file per trial, written on its own thread, never blocking capture.

Callers (the session's threads) hand data to `write_*`; each call only puts a reference
into a bounded queue and returns. The writer thread encodes (capture.recording.topics), writes zstd
chunks (level 5; replays level 1, see ZSTD_LEVEL_FAST) and closes a chunk at least every
`chunk_interval_s`, by the wall clock and by the data's own time span (so replayed or
synthetic data is chunked the same way), then fsyncs.
A kill loses at most the open chunk: about a second. If the queue is full the item is
dropped, counted, and the count written to /events at the next chunk: never silently.

Labels and operator markers never go through the bounded queue: they are first appended
to the journal beside the file (fsync'ed, capture.recording.journal), then to a small unbounded
queue that the writer drains first.

Chunk closing: mcap's `Writer.flush()` (mcap >= 1.6) finishes the open chunk and writes it
out; `chunk_size` is set high so that the timer, not the size, decides.

A write error (disk full, device gone) stops the recording cleanly: the file is cut back
to the end of the last complete chunk, the state becomes "failed" with a one-line message,
and what was written stays readable (capture.recording.reader reads unfinished files; `walkcap
recover` rebuilds the index).
"""

from __future__ import annotations

import collections
import errno
import io
import logging
import os
import queue
import threading
import time
import uuid
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from capture import __version__
from capture.errors import CaptureError
from capture.recording import topics as T
from capture.recording.journal import Journal, fsync_directory, journal_path
from devices.clock import now_ns
from devices.scheduling import NORMAL_PRIORITY, realtime_priority

CLOUD_VOXEL_M = 0.02  # /camera/cloud: one point per voxel of this size (see encode_processed)
CLOUD_MAX_POINTS = 4096

log = logging.getLogger(__name__)

_STOP = object()
_OPERATOR_KINDS = ("marker", "note")

# The live recording's size goal, 2.5 MB/s at 45 fps: zstandard's default level 3 writes the
# mock walk at 2.54 MB/s, level 5 at 2.47 MB/s, for 1.6 times the compression time (89 ms
# for a second of 45 fps data), which the writer thread absorbs without adding latency.
ZSTD_LEVEL = 5
ZSTD_LEVEL_FAST = 1  # replay: a fifth larger than level 5 in a seventh of the time (13 ms)


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


def _zstd_levels() -> _ZstdAtLevel:
    """The stand-in, installed in mcap's writer on first use."""
    import mcap.writer

    if not isinstance(mcap.writer.zstandard, _ZstdAtLevel):
        mcap.writer.zstandard = _ZstdAtLevel(mcap.writer.zstandard)
    return mcap.writer.zstandard


MEDIA_TYPES = {
    ".toml": "application/toml",
    ".json": "application/json",
    ".npy": "application/x-npy",
    ".txt": "text/plain",
    ".yaml": "application/yaml",
}


class RecorderState(StrEnum):
    """A str equal to its text ("recording", ...) in comparisons, f-strings, the journal."""

    IDLE = "idle"  # not started
    RECORDING = "recording"
    STOPPED = "stopped"  # closed, the file complete
    FAILED = "failed"  # a write error ended it; RecorderStats.message says why


@dataclass
class RecorderStats:
    path: str
    state: RecorderState
    message: str = ""  # why it failed, in one line; or a warning (journal trouble)
    bytes_written: int = 0
    messages: int = 0
    dropped: int = 0
    dropped_by_kind: dict = field(default_factory=dict)
    shed: int = 0  # derived items (clouds, images, inference, features) shed to keep raw data
    shed_by_kind: dict = field(default_factory=dict)
    queue_depth: int = 0
    queue_size: int = 0
    labels: int = 0
    chunks: int = 0
    errors: int = 0  # items that could not be encoded (logged)
    duration_s: float = 0.0  # span of the sensor data written
    bytes_per_s: float = 0.0  # file growth over the last few chunks


# ---- the queue's items: one record per write_* call, one encoder per record (Recorder._ENCODERS)
# Slotted dataclasses, not frozen: one allocation per item, built in a sixth of a frozen one's
# time (0.2 against 1.4 us) on the callers' 45 fps path. Nothing modifies an item once queued.


class QueuedItem:
    """One write_* call's data on its way to the writer thread."""

    __slots__ = ()
    kind: ClassVar[str]  # what its drops are counted as (RecorderStats.dropped_by_kind, /events)
    # Computed from the raw data (clouds, images, inference, features): shed first when the
    # writer falls behind, so raw depth, IMU samples and events keep their place.
    derived: ClassVar[bool] = False
    # A depth frame weighs megabytes; IMU samples, events and messages bytes: the queue
    # bounds the heavy ones by its size and holds LIGHT_FACTOR times as many light ones,
    # so the backlog of a host stall (5 s of IMU samples at once) finds room.
    heavy: ClassVar[bool] = False


@dataclass(slots=True)
class QueuedFrame(QueuedItem):
    kind: ClassVar[str] = "frame"
    heavy: ClassVar[bool] = True
    frame: Any  # a DepthFrame
    time_ns: int | None  # publish time; None: the frame's device time


@dataclass(slots=True)
class QueuedImuSample(QueuedItem):
    kind: ClassVar[str] = "imu"
    sample: Any  # an ImuSample


@dataclass(slots=True)
class QueuedProcessing(QueuedItem):
    kind: ClassVar[str] = "processed"
    derived: ClassVar[bool] = True
    index: int
    time_ns: int
    log_time: int
    cloud: np.ndarray
    image: np.ndarray
    quaternion: Any  # None: orientation unknown
    flag: str


@dataclass(slots=True)
class QueuedInference(QueuedItem):
    kind: ClassVar[str] = "inference"
    derived: ClassVar[bool] = True
    index: int
    time_ns: int
    log_time: int
    probs: Any
    fused: dict | None


@dataclass(slots=True)
class QueuedFeatures(QueuedItem):
    kind: ClassVar[str] = "features"
    derived: ClassVar[bool] = True
    index: int
    time_ns: int
    features: dict


@dataclass(slots=True)
class QueuedTruth(QueuedItem):
    kind: ClassVar[str] = "truth"
    index: int
    time_ns: int
    truth: dict


@dataclass(slots=True)
class QueuedEncodedFrame(QueuedItem):
    """A frame's messages encoded in another process (replay's reader)."""

    kind: ClassVar[str] = "encoded"
    heavy: ClassVar[bool] = True
    index: int
    time_ns: int
    log_time: int
    messages: list


@dataclass(slots=True)
class QueuedMessage(QueuedItem):
    """A JSON message on a topic declared with Recorder.declare_topic (an LSL stream)."""

    kind: ClassVar[str] = "message"
    topic: str
    time_ns: int
    log_time: int
    message: dict


@dataclass(slots=True)
class QueuedDeviceEvent(QueuedItem):
    kind: ClassVar[str] = "event"
    event: Any  # a DeviceEvent or a dict


# Raw items queued beyond this share of their room (frames: seconds of them at 45 fps): the
# writer is behind, derived ones are shed and raw ones go first.
SHED_BACKLOG = 0.25
LIGHT_FACTOR = 8  # light raw items (IMU, events, messages, truth) held: this x the size


class WriteQueue:
    """The writer's queue in two parts: raw items (depth, IMU, events, truth, messages)
    and derived ones (clouds, images, inference, features), taken in the order they came.
    When the writer falls behind (raw items pile up), raw ones go first and derived ones
    are shed, the queued ones too, so raw data is dropped only when its own part is full
    (the disk itself cannot keep up)."""

    def __init__(self, maxsize: int) -> None:
        self.maxsize = maxsize
        self._raw: collections.deque = collections.deque()
        self._heavy = 0  # heavy items among the raw ones
        self._derived: collections.deque = collections.deque()
        self._derived_max = max(1, maxsize // 2)
        self._cond = threading.Condition()
        self._count = 0  # items put: each queued one carries its number, the order they came
        self.shed: collections.Counter = collections.Counter()  # derived items shed, by kind

    def qsize(self) -> int:
        return len(self._raw) + len(self._derived)

    def put_nowait(self, item) -> None:
        self.put(item, block=False)

    def put(self, item, block: bool = True, timeout: float | None = None) -> None:
        """Queue an item; queue.Full when a raw one finds no room. Without `block` a
        derived item that finds no room, or the writer behind on raw data, is shed."""
        derived = getattr(item, "derived", False)
        with self._cond:
            while True:
                if derived:
                    behind = self._behind() and not block
                    if not behind and len(self._derived) < self._derived_max:
                        self._derived.append((self._count, item))
                        break
                    if not block:
                        self.shed[item.kind] += 1
                        return
                elif item is _STOP or self._room(item):
                    self._raw.append((self._count, item))
                    self._heavy += getattr(item, "heavy", False)
                    if self._behind() and not block:
                        self._shed_queued()
                    break
                if not block or not self._cond.wait(timeout):
                    raise queue.Full
            self._count += 1
            self._cond.notify_all()

    def _behind(self) -> bool:
        light = len(self._raw) - self._heavy
        return (
            self._heavy > SHED_BACKLOG * self.maxsize
            or light > SHED_BACKLOG * LIGHT_FACTOR * self.maxsize
        )

    def _room(self, item) -> bool:
        if item.heavy:
            return self._heavy < self.maxsize
        return len(self._raw) - self._heavy < LIGHT_FACTOR * self.maxsize

    def _shed_queued(self) -> None:
        while self._derived:
            self.shed[self._derived.popleft()[1].kind] += 1

    def get(self, timeout: float | None = None):
        """The oldest item; raw ones first while they pile up; the stop mark comes last."""
        with self._cond:
            while True:
                raw, derived = self._raw, self._derived
                if raw and (
                    not derived
                    or (raw[0][1] is not _STOP and self._behind())
                    or (raw[0][1] is not _STOP and raw[0][0] < derived[0][0])
                ):
                    item = raw.popleft()[1]
                    self._heavy -= getattr(item, "heavy", False)
                    break
                if derived:
                    item = derived.popleft()[1]
                    break
                if not self._cond.wait(timeout):
                    raise queue.Empty
            self._cond.notify_all()
            return item

    def get_nowait(self):
        with self._cond:
            if not self._raw and not self._derived:
                raise queue.Empty
        return self.get(0)


class _TrackedFile:
    """The recording's file as the mcap writer sees it: complete writes, counted bytes."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.position = 0

    def write(self, data) -> int:
        view = memoryview(data)
        total = len(view)
        while view:
            n = os.write(self.fd, view)
            self.position += n
            view = view[n:]
        return total

    def tell(self) -> int:
        return self.position

    def flush(self) -> None:
        pass  # nothing is buffered here; fsync() makes it durable

    def fsync(self) -> None:
        os.fsync(self.fd)

    def truncate(self, size: int) -> None:
        os.ftruncate(self.fd, size)
        os.lseek(self.fd, size, os.SEEK_SET)
        self.position = size

    def close(self) -> None:
        if self.fd >= 0:
            fd, self.fd = self.fd, -1
            os.close(fd)


def _media_type(name: str) -> str:
    return MEDIA_TYPES.get(Path(name).suffix.lower(), "application/octet-stream")


def _failure_message(e: BaseException, path: Path, seconds: float) -> str:
    after = f"recording stopped after {seconds:.1f} s"
    keep = f"what was written is readable; `walkcap recover {path}` rebuilds its index"
    if isinstance(e, OSError) and e.errno in (errno.ENOSPC, errno.EDQUOT):
        return f"disk full: {after}; {keep} once there is space"
    if isinstance(e, OSError) and e.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        return f"cannot write {path} ({e.strerror}): {after}; {keep}"
    if isinstance(e, OSError):
        return f"write error ({e.strerror or e}): {after}; {keep}"
    return f"internal error ({type(e).__name__}: {e}): {after}; {keep}"


class Recorder:
    """An MCAP recording being written. `start()`, then `write_*` from any thread, `close()`.

    `write_*` keep references to the arrays they are given (no copy on the caller's
    thread): the caller must not modify them afterwards.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        metadata: dict[str, dict] | None = None,
        attachments: dict[str, bytes] | None = None,
        queue_size: int = 512,
        chunk_interval_s: float = 1.0,
        gray: bool = False,
        cloud_max_points: int = CLOUD_MAX_POINTS,
        cloud_voxel_m: float = CLOUD_VOXEL_M,
        blocking: bool = False,
        zstd_level: int = ZSTD_LEVEL,
        recording_id: str | None = None,
        priority: int = 0,
    ) -> None:
        self.path = Path(path)
        # SCHED_FIFO priority of the writer thread (0: normal): above the pipeline's, so the
        # raw data's writer is never starved by the work derived from it.
        self._priority_rt = priority
        self.scheduling = NORMAL_PRIORITY
        self.journal_path = journal_path(self.path)
        # Values of any JSON type: written as JSON (capture.recording.topics.encode_metadata).
        self._metadata = {name: dict(values) for name, values in (metadata or {}).items()}
        # The recording's identity, in its "recording" record.
        self.id = recording_id or str(uuid.uuid4())
        self._attachments = dict(attachments or {})
        self._queue = WriteQueue(queue_size)
        self._queue_size = queue_size
        self._priority: collections.deque = collections.deque()  # labels, markers: unbounded
        self._chunk_interval_s = chunk_interval_s
        self._gray = gray
        self._cloud_max_points = cloud_max_points
        self._cloud_voxel_m = cloud_voxel_m
        # Offline writers (replay, synth) wait for the disk instead of dropping: nothing live
        # is waiting on them.
        self._blocking = blocking
        self._zstd_level = zstd_level
        self._state = RecorderState.IDLE
        self._message = ""
        self._accepting = False
        self._lock = threading.Lock()
        self._dropped: collections.Counter = collections.Counter()
        self._reported_drops: collections.Counter = collections.Counter()
        self._reported_shed: collections.Counter = collections.Counter()
        self._labels = 0
        self._file: _TrackedFile | None = None
        self._writer = None
        self._journal: Journal | None = None
        self._thread: threading.Thread | None = None
        # writer-thread state
        self._channels: dict[str, int] = {}
        self._declared: dict[str, T.TopicSpec] = {}  # topics beyond walkcap's own
        self._descriptions: dict[str, str] = {}
        self._messages = 0
        self._errors = 0
        self._chunks = 0
        self._good_offset = 0
        self._geometry = None
        self._frame_times: dict[int, tuple[int, int]] = {}  # index -> (time, log time)
        self._first_ns: int | None = None
        self._last_ns: int | None = None
        self._span: list[int] | None = None  # sensor log-time span of the open chunk
        self._open_messages = 0
        self._next_flush = 0.0
        self._growth: collections.deque = collections.deque(maxlen=6)  # (wall s, bytes)

    # ---- life cycle (caller's thread) ---------------------------------------------------

    def start(self) -> None:
        """Create the file and its journal, write header, metadata and attachments, start."""
        from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer

        if self._state != RecorderState.IDLE:
            raise CaptureError(f"recorder for {self.path} already started")
        folder = self.path.parent
        if not folder.is_dir():
            self._set_failed(f"recordings folder {folder} does not exist")
            raise CaptureError(self._message)
        try:
            fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError:
            self._set_failed(f"{self.path} exists: a recording is never overwritten")
            raise CaptureError(self._message) from None
        except OSError as e:
            self._set_failed(f"cannot create the recording {self.path}: {e.strerror}")
            raise CaptureError(self._message) from None
        self._file = _TrackedFile(fd)
        try:
            self._journal = Journal(self.journal_path)
            self._writer = Writer(
                self._file, chunk_size=64 * 1024 * 1024, compression=CompressionType.ZSTD
            )
            self._writer.start(profile="", library=f"walkcap {__version__}; {LIBRARY_IDENTIFIER}")
            for name, values in self._recording_metadata().items():
                self._writer.add_metadata(name, T.encode_metadata(values))
            created = time.time_ns()
            for name, data in self._attachments.items():
                self._writer.add_attachment(created, now_ns(), name, _media_type(name), bytes(data))
            self._writer.flush()
            self._file.fsync()
            fsync_directory(folder)
            self._good_offset = self._file.tell()
            self._journal.append(
                {
                    "type": "start",
                    "recording": self.path.name,
                    "time_ns": now_ns(),
                    "unix_time_ns": created,
                }
            )
        except OSError as e:
            self._abandon_start()
            self._set_failed(f"cannot write the recording {self.path}: {e.strerror or e}")
            raise CaptureError(self._message) from None
        self._state = RecorderState.RECORDING
        self._accepting = True
        self._next_flush = time.monotonic() + self._chunk_interval_s
        self._thread = threading.Thread(target=self._run, name="walkcap-recorder", daemon=True)
        self._thread.start()
        self.scheduling = realtime_priority(self._thread.native_id, self._priority_rt)

    def _abandon_start(self) -> None:
        """Start failed half-way: leave no empty or broken files behind."""
        for closing in (self._file, self._journal):
            try:
                if closing is not None:
                    closing.close()
            except OSError:
                pass
        for p in (self.path, self.journal_path):
            try:
                p.unlink()
            except OSError:
                pass

    def _recording_metadata(self) -> dict[str, dict]:
        unix_offset = time.time_ns() - now_ns()
        recording = {
            "id": self.id,
            T.METADATA_VALUES_KEY: T.METADATA_VALUES,
            "format_version": T.FORMAT_VERSION,
            "writer": f"walkcap {__version__}",
            "clock": "session clock: time.monotonic_ns of the recording host",
            "unix_offset_ns": unix_offset,  # add to a log time for Unix time
            "chunk_interval_s": self._chunk_interval_s,
            "depth": "range along each pixel's ray in mm (16UC1) x attachment "
            f"{T.RAYS_ATTACHMENT} = xyz; within 0.5 mm",
            "cloud_quantum_m": T.CLOUD_QUANTUM_M,
            "cloud_max_points": self._cloud_max_points,
            "cloud_voxel_m": self._cloud_voxel_m,
            "journal": self.journal_path.name,
            "topics": T.DESCRIPTIONS,
        }
        return {**self._metadata, "recording": recording}

    def close(self) -> RecorderStats:
        """Write what is queued, finalise the file (summary and index), return the stats."""
        self._accepting = False
        thread = self._thread
        if thread is not None:
            while thread.is_alive():
                try:
                    self._queue.put(_STOP, timeout=0.2)
                    break
                except queue.Full:
                    continue
            thread.join()
            self._thread = None
        if self._journal is not None:
            try:
                self._journal.append(
                    {
                        "type": "end",
                        "time_ns": now_ns(),
                        "state": self._state,
                        "message": self._message,
                    }
                )
            except OSError as e:
                log.warning("journal %s: %s", self.journal_path, e)
            self._journal.close()
            self._journal = None
        return self.stats()

    def __enter__(self) -> Recorder:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def stats(self) -> RecorderStats:
        with self._lock:
            dropped = dict(self._dropped)
        shed = dict(self._queue.shed)
        span = 0.0
        if self._first_ns is not None and self._last_ns is not None:
            span = (self._last_ns - self._first_ns) * 1e-9
        growth = list(self._growth)
        rate = 0.0
        if len(growth) > 1 and growth[-1][0] > growth[0][0]:
            rate = (growth[-1][1] - growth[0][1]) / (growth[-1][0] - growth[0][0])
        return RecorderStats(
            path=str(self.path),
            state=self._state,
            message=self._message,
            bytes_written=self._file.position if self._file is not None else 0,
            messages=self._messages,
            dropped=sum(dropped.values()),
            dropped_by_kind=dropped,
            shed=sum(shed.values()),
            shed_by_kind=shed,
            queue_depth=self._queue.qsize(),
            queue_size=self._queue_size,
            labels=self._labels,
            chunks=self._chunks,
            errors=self._errors,
            duration_s=span,
            bytes_per_s=rate,
        )

    @property
    def state(self) -> RecorderState:
        return self._state

    # ---- writes (any thread; never block, never encode) ------------------------------

    def _put(self, item: QueuedItem) -> None:
        if self._accepting:
            try:
                if self._blocking:
                    while self._accepting and self._state == RecorderState.RECORDING:
                        try:
                            self._queue.put(item, timeout=0.5)
                            return
                        except queue.Full:
                            continue
                else:
                    self._queue.put_nowait(item)
                    return
            except queue.Full:
                pass
        if self._state in (RecorderState.RECORDING, RecorderState.FAILED):
            with self._lock:
                self._dropped[item.kind] += 1

    def write_frame(self, frame, time_ns: int | None = None) -> None:
        """Depth (range + confidence) of a DepthFrame; publish time = `time_ns` or device time."""
        self._put(QueuedFrame(frame, time_ns))

    def write_imu(self, sample) -> None:
        self._put(QueuedImuSample(sample))

    def write_processed(
        self,
        frame_index: int,
        time_ns: int,
        log_time_ns: int,
        cloud: np.ndarray,
        image: np.ndarray,
        quaternion,
        flag: str,
    ) -> None:
        """Leveled cloud, classifier input image, camera orientation (None: unknown), flag."""
        self._put(
            QueuedProcessing(frame_index, time_ns, log_time_ns, cloud, image, quaternion, flag)
        )

    def write_inference(
        self, frame_index: int, time_ns: int, log_time_ns: int, cnn_probs, fused: dict | None
    ) -> None:
        """CNN probabilities of this frame; `fused` (may be empty) refers to an earlier frame."""
        self._put(QueuedInference(frame_index, time_ns, log_time_ns, cnn_probs, fused))

    def write_features(self, frame_index: int, time_ns: int, features: dict) -> None:
        self._put(QueuedFeatures(frame_index, time_ns, features))

    def write_truth(self, frame_index: int, time_ns: int, truth: dict) -> None:
        self._put(QueuedTruth(frame_index, time_ns, truth))

    def write_encoded(
        self, frame_index: int, time_ns: int, log_time_ns: int, messages: list
    ) -> None:
        """One frame's messages encoded elsewhere (encode_depth, encode_processed,
        encode_truth: replay's reader process), written as given. The camera's rays must be
        among the attachments: no depth frame passes here to take them from."""
        self._put(QueuedEncodedFrame(frame_index, time_ns, log_time_ns, messages))

    def declare_topic(self, topic: str, schema: dict, description: str) -> None:
        """A JSON topic beyond walkcap's own (another device's LSL stream), with its JSON
        Schema; declared before its first write_message."""
        if topic in T.TOPICS:
            raise CaptureError(f"{topic} is one of walkcap's own topics")
        self._descriptions[topic] = description
        self._declared[topic] = T.json_topic_spec(topic, schema)

    def write_message(self, topic: str, time_ns: int, log_time_ns: int, message: dict) -> None:
        """A JSON message on a declared topic; publish time `time_ns`, log time the receipt."""
        self._put(QueuedMessage(topic, time_ns, log_time_ns, message))

    def write_label(self, time_ns: int, mode: str, source: str) -> None:
        """The operator's mode from `time_ns` on. Journaled (on disk) before this returns."""
        entry = T.label_json(time_ns, mode, source)
        self._journal_append({"type": "label", **entry})
        with self._lock:
            self._labels += 1
        if self._state == RecorderState.RECORDING:
            self._priority.append((T.LABELS, entry))

    def write_event(self, event) -> None:
        """A DeviceEvent or a dict (time_ns, device, kind, message, details). Operator
        markers and notes are journaled and never dropped; device events are queued."""
        if isinstance(event, dict):
            event = {"time_ns": now_ns(), **event}
            device, kind = event.get("device", ""), event.get("kind", "")
        else:
            device, kind = event.device, event.kind
        if device == "operator" or kind in _OPERATOR_KINDS:
            entry = T.event_json(event)
            self._journal_append({"type": "event", **T.jsonable(entry)})
            if self._state == RecorderState.RECORDING:
                self._priority.append((T.EVENTS, entry))
        else:
            self._put(QueuedDeviceEvent(event))

    def _journal_append(self, entry: dict) -> None:
        journal = self._journal
        if journal is None:
            return
        try:
            journal.append(entry)
        except OSError as e:
            log.error("journal %s: %s", self.journal_path, e)
            if self._state == RecorderState.RECORDING:
                self._message = f"journal not writable ({e.strerror or e}): labels only in the file"

    # ---- the writer thread --------------------------------------------------------------

    def _run(self) -> None:
        _zstd_levels().level = self._zstd_level  # every chunk is compressed on this thread
        try:
            while True:
                self._drain_priority()
                timeout = max(0.0, self._next_flush - time.monotonic())
                try:
                    item = self._queue.get(timeout=timeout)
                except queue.Empty:
                    item = None
                if item is _STOP:
                    break
                if item is not None:
                    self._handle(item)
                if self._flush_due():
                    self._flush()
            self._finish()
        except BaseException as e:  # a write error must end in a clean, readable file
            self._fail(e)

    def _drain_priority(self) -> None:
        while self._priority:
            topic, entry = self._priority.popleft()
            t = entry["time_ns"]
            self._add(topic, t, t, T.encode_json(entry))

    def _flush_due(self) -> bool:
        if time.monotonic() >= self._next_flush:
            return True
        return (
            self._span is not None and self._span[1] - self._span[0] >= self._chunk_interval_s * 1e9
        )

    def _flush(self) -> None:
        self._report_drops()
        self._drain_priority()
        if self._open_messages:
            self._writer.flush()
            self._file.fsync()
            self._chunks += 1
            self._good_offset = self._file.tell()
        self._growth.append((time.monotonic(), self._good_offset))
        self._open_messages = 0
        self._span = None
        self._next_flush = time.monotonic() + self._chunk_interval_s

    def _finish(self) -> None:
        self._flush()  # the last chunk first: a file cut during finish() still has it
        end = {
            "messages": self._messages,
            "chunks": self._chunks,
            "dropped": sum(self._dropped.values()),
            "shed": sum(self._queue.shed.values()),
            "errors": self._errors,
            "labels": self._labels,
            "closed_unix_time_ns": time.time_ns(),
        }
        self._writer.add_metadata("recording_end", T.encode_metadata(end))
        self._writer.finish()
        self._file.fsync()
        self._file.close()
        self._state = RecorderState.STOPPED

    def _fail(self, e: BaseException) -> None:
        seconds = (self._last_ns - self._first_ns) * 1e-9 if self._first_ns is not None else 0.0
        self._accepting = False
        self._set_failed(_failure_message(e, self.path, seconds))
        log.error("recording %s: %s", self.path, self._message, exc_info=not isinstance(e, OSError))
        if self._file is not None:
            try:  # cut the half-written chunk: the file ends with the last complete one
                self._file.truncate(self._good_offset)
                self._file.fsync()
            except OSError:
                pass
            try:
                self._file.close()
            except OSError:
                pass
        self._journal_append({"type": "failed", "time_ns": now_ns(), "message": self._message})
        while True:  # free the frames still queued
            try:
                self._queue.get_nowait()
            except queue.Empty:
                break

    def _set_failed(self, message: str) -> None:
        self._state = RecorderState.FAILED
        self._message = message

    def _report_drops(self) -> None:
        shed = collections.Counter(self._queue.shed)
        new_shed, self._reported_shed = shed - self._reported_shed, shed
        if new_shed:
            self._recorder_event(
                "shed", "recorder behind: {n} derived items shed ({what}); raw data kept", new_shed
            )
        with self._lock:
            new = self._dropped - self._reported_drops
            self._reported_drops = collections.Counter(self._dropped)
        if new:
            self._recorder_event("drop", "recorder fell behind: {n} items dropped ({what})", new)

    def _recorder_event(self, kind: str, message: str, counts: collections.Counter) -> None:
        """One /events entry for items the recorder lost or shed, counted by topic."""
        what = ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))
        t = now_ns()
        event = {
            "time_ns": t,
            "device": "recorder",
            "kind": kind,
            "message": message.format(n=sum(counts.values()), what=what),
            "details": dict(counts),
        }
        self._add(T.EVENTS, t, t, T.encode_json(event))

    def _channel(self, topic: str) -> int:
        channel = self._channels.get(topic)
        if channel is None:
            spec = self._declared.get(topic) or T.topic_spec(topic)
            schema = self._writer.register_schema(
                spec.schema_name, spec.schema_encoding, spec.schema_data
            )
            description = self._descriptions.get(topic) or T.DESCRIPTIONS[topic]
            channel = self._writer.register_channel(
                topic, spec.message_encoding, schema, {"description": description}
            )
            self._channels[topic] = channel
        return channel

    def _add(
        self,
        topic: str,
        log_time: int,
        publish_time: int,
        data: bytes,
        sequence: int = 0,
        sensor: bool = False,
    ) -> None:
        self._writer.add_message(
            self._channel(topic), int(log_time), data, int(publish_time), int(sequence) & 0xFFFFFFFF
        )
        self._messages += 1
        self._open_messages += 1
        if sensor:
            if self._first_ns is None:
                self._first_ns = log_time
            self._last_ns = log_time if self._last_ns is None else max(self._last_ns, log_time)
            if self._span is None:
                self._span = [log_time, log_time]
            else:
                self._span[0] = min(self._span[0], log_time)
                self._span[1] = max(self._span[1], log_time)

    def _handle(self, item: QueuedItem) -> None:
        try:
            messages = self._ENCODERS[type(item)](self, item)
        except OSError:
            raise  # a write error (the geometry attachment): the recording cannot go on
        except Exception:  # bad data or a bug: lose this item, not the recording
            log.exception("recorder: cannot encode %s", item.kind)
            self._errors += 1
            return
        for topic, log_time, publish_time, data, sequence, sensor in messages:
            self._add(topic, log_time, publish_time, data, sequence, sensor)

    # Encoders: queued item -> [(topic, log_time, publish_time, bytes, sequence, sensor)]

    def _remember(self, index: int, time_ns: int, log_time: int) -> None:
        self._frame_times[index] = (time_ns, log_time)
        if len(self._frame_times) > 512:
            self._frame_times.pop(next(iter(self._frame_times)))

    def _log_time(self, index: int, default: int) -> int:
        return self._frame_times.get(index, (default, default))[1]

    def _encode_depth_frame(self, item: QueuedFrame) -> list:
        frame = item.frame
        t = frame.device_time_ns if item.time_ns is None else item.time_ns
        log_time = frame.host_time_ns
        self._remember(frame.index, t, log_time)
        if frame.geometry != self._geometry:
            self._write_geometry(frame)
        return encode_depth(frame, t, log_time, self._gray)

    def _write_geometry(self, frame) -> None:
        """The rays (once per camera) that turn /camera/depth back into xyz."""
        import dataclasses

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
        camera = dict(dataclasses.asdict(g))
        camera["rays_attachment"] = T.RAYS_ATTACHMENT
        camera["from_frame_index"] = frame.index
        self._writer.add_metadata("camera", T.encode_metadata(camera))
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
            self._add(T.EVENTS, t, t, T.encode_json(event))
            log.warning("recording %s: %s", self.path, event["message"])

    def _encode_imu_sample(self, item: QueuedImuSample) -> list:
        sample = item.sample
        t = sample.time_ns if sample.time_ns is not None else sample.host_time_ns
        seq = sample.packet_counter or 0
        return [(T.IMU, sample.host_time_ns, t, T.encode_json(T.imu_json(sample)), seq, True)]

    def _encode_processing(self, item: QueuedProcessing) -> list:
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

    def _encode_inference(self, item: QueuedInference) -> list:
        index, time_ns, log_time, fused = item.index, item.time_ns, item.log_time, item.fused
        out = [
            (
                T.CNN,
                log_time,
                time_ns,
                T.encode_json(T.cnn_json(index, time_ns, item.probs)),
                index,
                False,
            )
        ]
        if fused:
            msg = T.fused_json(index, time_ns, fused)
            out.append((T.FUSED, log_time, time_ns, T.encode_json(msg), index, False))
        return out

    def _encode_features(self, item: QueuedFeatures) -> list:
        index, time_ns = item.index, item.time_ns
        return [
            (
                T.FEATURES,
                self._log_time(index, time_ns),
                time_ns,
                T.encode_json(T.features_json(index, time_ns, item.features)),
                index,
                False,
            )
        ]

    def _encode_truth(self, item: QueuedTruth) -> list:
        log_time = self._log_time(item.index, item.time_ns)
        return encode_truth(item.index, item.time_ns, log_time, item.truth)

    def _take_encoded_frame(self, item: QueuedEncodedFrame) -> list:
        self._remember(item.index, item.time_ns, item.log_time)
        return item.messages

    def _encode_message(self, item: QueuedMessage) -> list:
        if item.topic not in self._declared:
            raise ValueError(f"{item.topic}: not declared")
        data = T.encode_json(item.message)
        return [(item.topic, item.log_time, item.time_ns, data, 0, False)]

    def _encode_device_event(self, item: QueuedDeviceEvent) -> list:
        entry = T.event_json(item.event)
        t = entry["time_ns"]
        return [(T.EVENTS, t, t, T.encode_json(entry), 0, False)]

    _ENCODERS = {
        QueuedFrame: _encode_depth_frame,
        QueuedImuSample: _encode_imu_sample,
        QueuedProcessing: _encode_processing,
        QueuedInference: _encode_inference,
        QueuedFeatures: _encode_features,
        QueuedTruth: _encode_truth,
        QueuedEncodedFrame: _take_encoded_frame,
        QueuedDeviceEvent: _encode_device_event,
        QueuedMessage: _encode_message,
    }


# ---- encoders: one frame's data -> [(topic, log_time, publish_time, bytes, sequence, sensor)]
# Pure, so another process can run them (replay's reader).


def encode_depth(frame, t: int, log_time: int, gray: bool = False) -> list:
    depth = frame.range_mm  # a recording's own millimetres when replayed: exactly kept
    if depth is None:
        depth = T.range_mm(frame.xyz, frame.confidence)
    out = [
        (
            T.DEPTH,
            log_time,
            t,
            T.raw_image(depth, t, "16UC1").SerializeToString(),
            frame.index,
            True,
        ),
        (
            T.CONFIDENCE,
            log_time,
            t,
            T.raw_image(np.asarray(frame.confidence, np.uint8), t, "mono8").SerializeToString(),
            frame.index,
            True,
        ),
    ]
    if gray and frame.gray is not None:
        out.append(
            (
                T.GRAY,
                log_time,
                t,
                T.raw_image(np.asarray(frame.gray).astype("<u2"), t, "16UC1").SerializeToString(),
                frame.index,
                True,
            )
        )
    return out


def encode_processed(
    index: int,
    time_ns: int,
    log_time: int,
    cloud,
    image,
    quaternion,
    flag: str,
    voxel_m: float = CLOUD_VOXEL_M,
    max_points: int = CLOUD_MAX_POINTS,
) -> list:
    points = np.asarray(cloud, dtype=np.float32).reshape(-1, 3)
    n = len(points)
    if voxel_m > 0 and n:
        # One point per 2 cm voxel: steps, ramps and curbs stay plain in Foxglove at a
        # quarter of the bytes (0.12 MB/s at 45 fps, a 1 cm voxel 0.27: the difference
        # between meeting the 2.5 MB/s budget or not). The cloud is derived data (depth,
        # /tf and the preprocessing parameters rebuild it); the depth is kept exactly.
        cells = np.floor(points / voxel_m).astype(np.int64) + (1 << 20)
        key = (cells[:, 0] << 42) | (cells[:, 1] << 21) | cells[:, 2]  # one int per voxel
        _, first = np.unique(key, return_index=True)
        points = points[np.sort(first)]
    if len(points) > max_points:  # decimated evenly
        points = points[np.linspace(0, len(points) - 1, max_points).astype(int)]
    image_u8 = T.binary_image_u8(image)
    oriented = quaternion is not None and bool(np.all(np.isfinite(quaternion)))
    out = [
        (
            T.CLOUD,
            log_time,
            time_ns,
            T.cloud_message(points, time_ns).SerializeToString(),
            index,
            False,
        ),
        (
            T.BINARY_IMAGE,
            log_time,
            time_ns,
            T.raw_image(image_u8, time_ns, "mono8", frame_id="").SerializeToString(),
            index,
            False,
        ),
        (
            T.PREPROCESS,
            log_time,
            time_ns,
            T.encode_json(T.preprocess_json(index, time_ns, flag, oriented, n, len(points))),
            index,
            False,
        ),
    ]
    if oriented:
        out.append(
            (
                T.TF,
                log_time,
                time_ns,
                T.transform_message(quaternion, time_ns).SerializeToString(),
                index,
                False,
            )
        )
    return out


def encode_truth(index: int, time_ns: int, log_time: int, truth: dict) -> list:
    return [
        (
            T.TRUTH,
            log_time,
            time_ns,
            T.encode_json(T.truth_json(index, time_ns, truth)),
            index,
            False,
        )
    ]


# ---- benchmark ----------------------------------------------------------------------------
