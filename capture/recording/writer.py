"""The Recorder: one MCAP file per trial, written on its own thread, never blocking capture.

Callers (the session's threads) hand data to `write_*` (the Sink interface); each call only
puts a reference into a bounded queue (capture.recording.write_queue) and returns. The
writer thread encodes (capture.recording.encode) and writes zstd chunks (level 5; replays
level 1, see ZSTD_LEVEL_FAST) through a ChunkWriter (capture.recording.chunks), closing a
chunk at least every `chunk_interval_s`, by the wall clock and by the data's own time span
(so replayed or synthetic data is chunked the same way), then fsyncs.
A kill loses at most the open chunk: about a second. If the queue is full the item is
dropped, counted, and the count written to /events at the next chunk: never silently.

Labels and operator markers never go through the bounded queue: they are first appended
to the journal beside the file (fsync'ed, capture.recording.journal), then to a small unbounded
queue that the writer drains first.

A write error (disk full, device gone) stops the recording cleanly: the file is cut back
to the end of the last complete chunk, the state becomes "failed" with a one-line message,
and what was written stays readable (capture.recording.reader reads unfinished files; `walkcap
recover` rebuilds the index).
"""

from __future__ import annotations

import collections
import errno
import logging
import os
import queue
import threading
import time
import uuid
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path

import numpy as np

from capture import __version__
from capture.errors import CaptureError
from capture.recording import topics as T
from capture.recording.chunks import ZSTD_LEVEL, ChunkWriter, TrackedFile, set_zstd_level
from capture.recording.encode import CLOUD_MAX_POINTS, CLOUD_VOXEL_M, Encoded
from capture.recording.journal import Journal, fsync_directory, journal_path
from capture.recording.metadata import RecordingRecord, as_dicts
from capture.recording.sink import Sink
from capture.recording.write_queue import (
    STOP,
    QueuedDeviceEvent,
    QueuedEncodedFrame,
    QueuedFeatures,
    QueuedFrame,
    QueuedGait,
    QueuedImuSample,
    QueuedInference,
    QueuedItem,
    QueuedMessage,
    QueuedProcessing,
    QueuedRecorded,
    QueuedTruth,
    WriteQueue,
)
from devices import clock
from devices.clock import now_ns
from devices.scheduling import NORMAL_PRIORITY, realtime_priority

log = logging.getLogger(__name__)

_OPERATOR_KINDS = ("marker", "note")


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


class Recorder(Sink):
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
        self._closing = False  # close() began: what comes now is after the trial's end
        self._lock = threading.Lock()
        self._dropped: collections.Counter = collections.Counter()
        self._reported_drops: collections.Counter = collections.Counter()
        self._reported_shed: collections.Counter = collections.Counter()
        self._labels = 0
        self._declared: dict[str, T.Topic] = {}  # topics beyond walkcap's own
        self._file: TrackedFile | None = None
        self._chunks: ChunkWriter | None = None  # the writer thread's, once started
        self._journal: Journal | None = None
        self._thread: threading.Thread | None = None

    # ---- life cycle (caller's thread) ---------------------------------------------------

    def start(self) -> None:
        """Create the file and its journal, write header, metadata and attachments, start."""
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
        self._file = TrackedFile(fd)
        try:
            self._journal = Journal(self.journal_path)
            self._chunks = ChunkWriter(
                self._file,
                self.path,
                chunk_interval_s=self._chunk_interval_s,
                gray=self._gray,
                cloud_voxel_m=self._cloud_voxel_m,
                cloud_max_points=self._cloud_max_points,
                declared=self._declared,
            )
            created = self._chunks.start(self._recording_metadata(), self._attachments)
            fsync_directory(folder)
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
        recording = RecordingRecord.build(
            id=self.id,
            **{T.METADATA_VALUES_KEY: T.METADATA_VALUES},
            format_version=T.FORMAT_VERSION,
            writer=f"walkcap {__version__}",
            clock="session clock: time.monotonic_ns of the recording host",
            unix_offset_ns=unix_offset,  # add to a log time for Unix time
            chunk_interval_s=self._chunk_interval_s,
            depth="range along each pixel's ray in mm (16UC1) x attachment "
            f"{T.RAYS_ATTACHMENT} = xyz; within 0.5 mm",
            cloud_quantum_m=T.CLOUD_QUANTUM_M,
            cloud_max_points=self._cloud_max_points,
            cloud_voxel_m=self._cloud_voxel_m,
            journal=self.journal_path.name,
            topics={name: topic.description for name, topic in T.TOPICS.items()},
        )
        return {**self._metadata, **as_dicts(recording)}

    def close(self) -> RecorderStats:
        """Write what is queued, finalise the file (summary and index), return the stats."""
        self._closing = True
        self._accepting = False
        thread = self._thread
        if thread is not None:
            while thread.is_alive():
                try:
                    self._queue.put(STOP, timeout=0.2)
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
        chunks = self._chunks
        span, rate = 0.0, 0.0
        if chunks is not None and chunks.first_ns is not None and chunks.last_ns is not None:
            span = clock.seconds(chunks.last_ns - chunks.first_ns)
        growth = list(chunks.growth) if chunks is not None else []
        if len(growth) > 1 and growth[-1][0] > growth[0][0]:
            rate = (growth[-1][1] - growth[0][1]) / (growth[-1][0] - growth[0][0])
        return RecorderStats(
            path=str(self.path),
            state=self._state,
            message=self._message,
            bytes_written=self._file.position if self._file is not None else 0,
            messages=chunks.messages if chunks is not None else 0,
            dropped=sum(dropped.values()),
            dropped_by_kind=dropped,
            shed=sum(shed.values()),
            shed_by_kind=shed,
            queue_depth=self._queue.qsize(),
            queue_size=self._queue_size,
            labels=self._labels,
            chunks=chunks.chunks if chunks is not None else 0,
            errors=chunks.errors if chunks is not None else 0,
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
        # Lost from the trial: a full queue or a failed file. An item that arrives once the
        # trial is closing (the last frame's results, the streams going on) is after its end.
        if self._state in (RecorderState.RECORDING, RecorderState.FAILED) and not self._closing:
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

    def write_gait(self, event, log_time_ns: int | None = None) -> None:
        self._put(QueuedGait(event, log_time_ns))

    def write_encoded(
        self, frame_index: int, time_ns: int, log_time_ns: int, messages: list[Encoded]
    ) -> None:
        """One frame's messages encoded elsewhere (encode_depth, encode_cloud,
        encode_preprocessing, encode_truth: replay's reader process and host), written as
        given. The camera's rays must be
        among the attachments: no depth frame passes here to take them from."""
        self._put(QueuedEncodedFrame(frame_index, time_ns, log_time_ns, messages))

    def write_recorded(self, messages: list[Encoded]) -> None:
        """Messages of another recording, copied as they are (their topics, times and
        bytes): what replay does not change, written without encoding it again."""
        self._put(QueuedRecorded(messages))

    def declare_topic(self, topic: str, schema: dict, description: str) -> None:
        """A JSON topic beyond walkcap's own (another device's LSL stream), with its JSON
        Schema; declared before its first write_message."""
        if topic in T.TOPICS:
            raise CaptureError(f"{topic} is one of walkcap's own topics")
        self._declared[topic] = T.json_topic(topic, schema, description)

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
        set_zstd_level(self._zstd_level)  # every chunk is compressed on this thread
        chunks = self._chunks
        try:
            while True:
                self._drain_priority()
                try:
                    item = self._queue.get(timeout=chunks.seconds_to_flush())
                except queue.Empty:
                    item = None
                if item is STOP:
                    break
                if item is not None:
                    chunks.write(item)
                if chunks.flush_due():
                    self._flush()
            self._finish()
        except BaseException as e:  # a write error must end in a clean, readable file
            self._fail(e)

    def _drain_priority(self) -> None:
        while self._priority:
            topic, entry = self._priority.popleft()
            self._chunks.add_json(topic, entry["time_ns"], entry)

    def _flush(self) -> None:
        self._report_drops()
        self._drain_priority()
        self._chunks.flush()

    def _finish(self) -> None:
        self._flush()  # the last chunk first: a file cut during finish() still has it
        end = {
            "messages": self._chunks.messages,
            "chunks": self._chunks.chunks,
            "dropped": sum(self._dropped.values()),
            "shed": sum(self._queue.shed.values()),
            "errors": self._chunks.errors,
            "labels": self._labels,
            "closed_unix_time_ns": time.time_ns(),
        }
        self._chunks.finish(end)
        self._state = RecorderState.STOPPED

    def _fail(self, e: BaseException) -> None:
        chunks = self._chunks
        seconds = 0.0
        if chunks.first_ns is not None:
            seconds = clock.seconds(chunks.last_ns - chunks.first_ns)
        self._accepting = False
        self._set_failed(_failure_message(e, self.path, seconds))
        log.error("recording %s: %s", self.path, self._message, exc_info=not isinstance(e, OSError))
        chunks.cut()
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
        self._chunks.add_json(T.EVENTS, t, event)
