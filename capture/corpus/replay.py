"""Replay: the pipeline run again on a recording's depth and IMU, into a new recording.

Deterministic: frames in order, each with the IMU samples recorded up to just after its
time in the orientation track, exactly as the live session would have had them. The
original file is only read, in one pass: the frames, the IMU samples (handed out in
sample-time order, SampleOrder), labels, events and the simulator's gait events come
from the same chunks, each decompressed once. What replay does not change (depth,
confidence, truth, IMU samples, the simulator's gait events, labels, events) is written
as recorded: the messages' bytes themselves when the file is of the current format.

As fast as possible (`speed=None`), the work is split over two processes, since one
Python process cannot use a second core: a reader process reads the file, levels and
preprocesses the frames, thins and encodes their clouds, fits each frame's profile (the
terrain features' hint-free part) and runs the gait detector on the IMU samples, sending
each step from a thread of its own; this one classifies the frames in batches, fuses,
classifies the fitted terrain under the fused decision, encodes the image, preprocessing
record and orientation, and records (its main thread shares the interpreter with the
threads that receive the frames and write the file). The reader process starts on the
frames as soon as it is ready, while this one loads the model; should this one come to
the frames first, it prepares them itself until the reader process is ready. The frames
are classified in batches of BATCH from the first frame on, whatever the reader process
has sent so far: the CNN's float results depend on the batch's size, and fixed batches
give the same file on every run. Paced replays (`speed=X`), and
replays that are one task of a corpus job (`reader_process=False`: the cluster has given
each task one core), run in this process alone.
"""

from __future__ import annotations

import collections
import dataclasses
import heapq
import os
import pickle
import queue
import socket
import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from capture.errors import CaptureError
from capture.live.pipeline import (
    CNN_THREADS,
    OrientationTrack,
    build_pipeline,
    record_decisions,
    software_metadata,
)
from capture.recording import topics as T
from capture.recording.lineage import REPLAY, derivation
from capture.recording.metadata import (
    CameraRecord,
    DerivationRecord,
    DevicesRecord,
    SessionRecord,
    SoftwareRecord,
)
from capture.recording.reader import imu_sample
from devices import clock
from devices.frames import DepthFrame, ImuSample

IMU_LOOKAHEAD_NS = 20_000_000  # samples recorded up to this long after a frame may be used
BATCH = 16  # frames classified at once when replaying as fast as possible


@dataclass
class ReplayReport:
    source: str
    output: str
    frames: int
    seconds_recorded: float
    seconds_taken: float
    stats: object  # RecorderStats of the new file

    @property
    def speedup(self) -> float:
        return (
            self.seconds_recorded / self.seconds_taken if self.seconds_taken > 0 else float("inf")
        )


def default_output(source: Path, folder: Path | None = None) -> Path:
    folder = folder or source.parent
    stem = source.stem
    k = 1
    while True:
        out = folder / f"{stem}.replay{'' if k == 1 else k}.mcap"
        if not out.exists():
            return out
        k += 1


class ImuOrderError(CaptureError):
    """An IMU sample lies later in the file than SampleOrder's horizon allows: the replay
    reads every sample's time first and starts again."""


class SampleOrder:
    """The IMU samples of one pass over a recording, handed out in sample-time order (ties:
    file order): the order a sort of every sample gives. A frame takes the samples up to
    its time plus IMU_LOOKAHEAD_NS.

    Samples are logged in near time order, so the pass need not read them all first: a
    frame is `ready` once the pass has read messages logged HORIZON_NS past its time. A
    sample read after later ones were handed out raises ImuOrderError (a host that
    delivered it seconds late). Given `times` (every sample's time, sorted: imu_times), a
    frame waits instead until every sample up to its time has been read, however late
    the file holds it."""

    HORIZON_NS = 2_000_000_000

    def __init__(self, times: np.ndarray | None = None) -> None:
        self._times = times
        self._heap: list = []
        self._read = 0  # samples added
        self._taken = 0  # samples handed out
        self._taken_to: int | None = None  # every sample up to this time is handed out
        self._newest_log: int | None = None  # the latest log time the pass has read
        self._ended = False

    def add(self, time_ns: int, item) -> None:
        if self._times is None and self._taken_to is not None and time_ns <= self._taken_to:
            raise ImuOrderError(f"an IMU sample at {time_ns} ns lies after later ones")
        heapq.heappush(self._heap, (time_ns, self._read, item))
        self._read += 1

    def read_to(self, log_time_ns: int) -> None:
        """The pass has read a message logged at `log_time_ns`."""
        if self._newest_log is None or log_time_ns > self._newest_log:
            self._newest_log = log_time_ns

    def end(self) -> None:
        """The pass has read the whole file."""
        self._ended = True

    def ready(self, upto_ns: int) -> bool:
        """Whether every sample up to `upto_ns` has been read."""
        if self._ended:
            return True
        if self._times is not None:
            due = int(np.searchsorted(self._times, upto_ns, side="right"))
            return self._taken + sum(1 for t, _, _ in self._heap if t <= upto_ns) >= due
        return self._newest_log is not None and self._newest_log >= upto_ns + self.HORIZON_NS

    def take(self, upto_ns: int | None = None) -> list:
        """The samples up to `upto_ns` (None: all that are left) in order."""
        heap, out = self._heap, []
        while heap and (upto_ns is None or heap[0][0] <= upto_ns):
            out.append(heapq.heappop(heap)[2])
        self._taken += len(out)
        if upto_ns is not None and (self._taken_to is None or upto_ns > self._taken_to):
            self._taken_to = upto_ns
        return out


def imu_times(rec) -> np.ndarray:
    """Every IMU sample's time (its sample time, else its arrival), sorted."""
    times = [_sample_time(imu_sample(m.data)) for m in rec.messages([T.IMU])]
    return np.sort(np.asarray(times, dtype=np.int64))


def _sample_time(s: ImuSample) -> int:
    return s.time_ns if s.time_ns is not None else s.host_time_ns


@dataclass(slots=True)
class ReplayStep:
    """One frame as replay's reader hands it on, in frame order: the frame (its bulky
    arrays dropped once encoded), its orientation and Preprocessed (its image and flag),
    the fit of its profile (inference.features.fit_profile, its points dropped: what the
    terrain features need besides the fused decision; None for a frame without features),
    the messages the new file keeps of it that the reader encodes (`messages`: depth,
    confidence, cloud, truth; the host encodes the image, preprocessing record and
    orientation, and puts them before the truth), and what the pass read since the step before: the
    IMU samples due before the frame, in sample-time order (`imu`: (the ImuSample when its
    message is not copied as recorded, else None; its message as recorded; the gait events
    the detector found at it; its receipt), labels and events (their messages' data) and
    the simulator's gait events. The last step has no frame: it carries what comes after
    the last frame."""

    frame: DepthFrame | None
    orientation: np.ndarray | None
    prepared: object | None
    fit: object | None
    messages: list
    imu: list
    labels: list
    events: list
    sim_gait: list


_COPIED = (T.DEPTH, T.CONFIDENCE, T.TRUTH)  # a frame's messages the new file keeps as recorded


def replay_steps(
    source: str | os.PathLike, params, mounting, *, skip: int = 0, times=None
) -> Iterator[ReplayStep]:
    """The recording as ReplaySteps from one pass over it, after the first `skip` steps
    (read for nothing: a skipped step costs its reading only); each frame preprocessed
    with `params` (a PreprocessConfig) and the camera's `mounting`. `times`: imu_times()
    of the file, when a pass without them has raised ImuOrderError."""
    from capture.recording.encode import Encoded
    from capture.recording.reader import FrameAssembler, open_recording
    from capture.recording.versions import needs_upgrade
    from inference.features import fit_profile
    from inference.gait import GaitDetector
    from inference.preprocess import preprocess_ranges

    rec = open_recording(source)
    frames = FrameAssembler(rec, gray=False, points=False)
    rays = frames.rays.astype(np.float32, copy=False)
    # a file of the current format holds its messages as this version encodes them
    as_recorded = not needs_upgrade(rec.format_version)
    order = SampleOrder(times)
    track = OrientationTrack(span_s=5.0)
    gait = GaitDetector()  # /gait recomputed from the IMU, as live
    held: collections.deque = collections.deque()  # frames waiting for their IMU samples
    stored: dict = {}  # (topic, frame index) -> the frame's message as recorded
    news: dict = {"labels": [], "events": [], "sim_gait": []}
    steps = 0

    def step(entry: dict | None) -> ReplayStep | None:
        nonlocal news, steps
        imu = []
        for sample, message in order.take(
            None if entry is None else entry["pub"] + IMU_LOOKAHEAD_NS
        ):
            if sample.quaternion is not None:
                rate = sample.rate_of_turn
                rate = rate if rate is not None and np.isfinite(rate[0]) else None
                track.add(_sample_time(sample), sample.quaternion, rate)
            # the gait detector sees every sample, a skipped step's too, as live
            events = gait.push(sample)
            imu.append((sample if message is None else None, message, events, sample.host_time_ns))
        recorded = [] if entry is None else [stored.pop((t, entry["index"]), None) for t in _COPIED]
        came, news = news, {"labels": [], "events": [], "sim_gait": []}
        steps += 1
        if steps <= skip:
            return None
        if entry is None:
            return ReplayStep(None, None, None, None, [], imu, **came)
        frame = frames.frame(entry)  # device_time_ns: the entry's publish time
        q, age_ns = track.at(frame.device_time_ns)
        level = q if q is not None else np.full(4, np.nan)
        pre = preprocess_ranges(
            frame.range_mm, rays, frame.confidence, level, params, age_ns, mounting
        )
        messages, kept = _frame_messages(frame, pre, recorded if as_recorded else None)
        # the features' hint-free part (Pipeline.process measures features of these frames)
        fit = fit_profile(pre.profile, params.max_forward_m) if pre.ok else None
        slim, slim_pre = _slim(frame, pre, kept)
        return ReplayStep(slim, q, slim_pre, fit and fit.drop_points(), messages, imu, **came)

    def due() -> Iterator[ReplayStep]:
        while held and order.ready(held[0]["pub"] + IMU_LOOKAHEAD_NS):
            out = step(held.popleft())
            if out is not None:
                yield out

    topics = (*frames.topics, T.IMU, T.LABELS, T.EVENTS, T.SIM_GAIT)
    for m, data in rec.stored(t for t in topics if t in rec.topics):
        if m.topic not in (T.LABELS, T.EVENTS):
            # labels and events jump the writer's queue (capture.recording.writer): where
            # they lie in the file says nothing of where the samples logged before them are
            order.read_to(m.log_time_ns)
        if m.topic == T.IMU:
            sample = imu_sample(m.data)
            copy = Encoded(T.IMU, m.log_time_ns, m.publish_time_ns, data, m.sequence)
            order.add(_sample_time(sample), (sample, copy if as_recorded else None))
        elif m.topic == T.LABELS:
            news["labels"].append(m.data)
        elif m.topic == T.EVENTS:
            news["events"].append(m.data)
        elif m.topic == T.SIM_GAIT:
            news["sim_gait"].append(T.gait_from_message(m.data))
        else:
            if m.topic in _COPIED:
                stored[(m.topic, m.sequence)] = Encoded(
                    m.topic, m.log_time_ns, m.publish_time_ns, data, m.sequence
                )
            held.extend(frames.add(m))
        yield from due()
    order.end()
    held.extend(frames.rest())
    yield from due()
    last = step(None)
    if last is not None:
        yield last


def _frame_messages(frame: DepthFrame, pre, recorded: list | None) -> tuple[list, int]:
    """What the new recording keeps of a frame that fusion does not change, but for what
    the host encodes (_replay: image, preprocessing record, orientation; the reader
    process's share of the work is the larger): depth, confidence and truth as `recorded`
    (their messages, None where not in the file; None: encoded again, for a file of an
    older format), and the cloud (its thinning and encoding use compiled kernels, loaded
    in the reader process already); with the number of the cloud's points recorded."""
    from capture.recording.encode import encode_cloud, encode_depth, encode_truth, thin_cloud

    t, log_time = frame.device_time_ns, frame.host_time_ns
    if recorded is None:
        depth = encode_depth(frame, t, log_time)
        truth = encode_truth(frame.index, t, log_time, frame.truth) if frame.truth else []
    else:
        depth, truth = [m for m in recorded[:2] if m is not None], recorded[2:3]
        truth = [m for m in truth if m is not None]
    kept = thin_cloud(pre.cloud)
    return depth + [encode_cloud(frame.index, t, log_time, kept)] + truth, len(kept)


def _with_processed(messages: list, processed: list) -> list:
    """A frame's messages in the order live recording writes them: depth, confidence,
    cloud, then the host's `processed` (image, preprocessing, orientation), then truth."""
    k = next((i for i, m in enumerate(messages) if m.topic == T.TRUTH), len(messages))
    return messages[:k] + processed + messages[k:]


def _slim(frame: DepthFrame, pre, kept: int) -> tuple[DepthFrame, object]:
    """The frame and its Preprocessed without what the host does not use (the reader
    process sends them): the bulky arrays (the rays come with the source's attachments),
    the camera's geometry, the truth, the cloud and the profile (the step's fit stands in
    for it); the cloud's counts, its points and the `kept` of them recorded, in its
    `details` (the host's preprocessing record needs them)."""
    none = np.zeros((0, 0), np.uint8)
    slim = dataclasses.replace(
        frame,
        xyz=np.zeros((0, 0, 3), np.float32),
        confidence=none,
        gray=none,
        range_mm=None,
        geometry=None,
        truth=None,  # its message goes as recorded
    )
    cloud, profile = np.zeros((0, 3), np.float32), np.zeros((0, 2), np.float32)
    details = pre.details | {"cloud_points": len(pre.cloud), "cloud_kept": kept}
    return slim, dataclasses.replace(pre, cloud=cloud, profile=profile, details=details)


class _ReaderProcess:
    """replay_steps() run in a child process, read back in order. A thread here takes
    the steps off the socket as they come: the socket holds about one frame, so without
    it the reader would stop while this process classifies a batch, and the two would
    take turns instead of working at once. The child says when it is ready (`ready`) and
    is then told how many steps to skip (`start_at`): those this process has done itself
    meanwhile, or none when it is ready before this process starts on the frames (this
    one loads the model meanwhile: the child's frames wait here, up to AHEAD)."""

    AHEAD = 64  # frames received and not yet taken (~10 MB)

    def __init__(self, source: Path, params, mounting, times=None) -> None:
        from devices.child import Child

        self._child = Child("capture.corpus.replay:_serve_prepared", str(source), params, mounting)
        self._received: queue.Queue = queue.Queue(maxsize=self.AHEAD)
        self._closed = threading.Event()
        self.ready = threading.Event()  # set at the child's first message
        self.times = times  # as replay_steps takes them
        self._start_lock = threading.Lock()
        self._starter: str | None = None  # who told the child where to start
        self._receiver = threading.Thread(
            target=self._receive, name="walkcap-replay-receiver", daemon=True
        )

    def start(self) -> None:
        """Its messages start coming (`ready` first)."""
        self._receiver.start()

    def _receive(self) -> None:
        conn = self._child.conn
        while not self._closed.is_set():
            try:
                message = _unpacked(conn.recv_bytes())
            except (EOFError, OSError):
                message = ("error", "replay: the frame reader process ended unexpectedly")
            except Exception as e:  # never leave the consumer waiting for nothing
                message = ("error", f"replay: unreadable data from the frame reader ({e})")
            if not self.ready.is_set():  # or it failed before it was: nothing more to wait for
                self.ready.set()
            if message[0] == "ready":
                if self.claim_start("child"):  # nothing done here yet: all from the child
                    self.start_at(0)
                continue
            while not self._closed.is_set():
                try:
                    self._received.put(message, timeout=0.2)
                    break
                except queue.Full:
                    continue
            if message[0] != "frame":
                return

    def claim_start(self, who: str) -> bool:
        """True for the first to claim where the child starts ("child": at its ready, from
        the first step; "host": after the steps this process prepares itself)."""
        with self._start_lock:
            if self._starter is None:
                self._starter = who
            return self._starter == who

    def start_at(self, skip: int) -> None:
        """Steps from number `skip` on (the child waits for this after `ready`)."""
        try:
            self._child.conn.send((skip, self.times))
        except OSError:
            pass  # it has ended: its error, if any, is already queued

    def batches(self, size: int):
        """Lists of up to `size` frames: the first frame received, then those already
        waiting. Classifying what has come rather than waiting for `size` keeps this
        process busy from the first frame on; when it falls behind, batches fill up."""
        batch: list = []
        while True:
            message = self._received.get() if not batch else self._waiting()
            if message is None or message[0] != "frame":
                if batch:
                    yield batch
                    batch = []
                if message is None:
                    continue
                if message[0] == "error":
                    raise CaptureError(message[1])
                if message[0] == "order":
                    raise ImuOrderError("an IMU sample lies late in the file")
                return
            batch.append(message[1])
            if len(batch) == size:
                yield batch
                batch = []

    def _waiting(self):
        try:
            return self._received.get_nowait()
        except queue.Empty:
            return None

    def close(self) -> None:
        self._closed.set()
        # Shut the socket down rather than close it under the receiving thread: its recv
        # returns, and a reader still sending sees the connection break and ends.
        try:
            with socket.socket(fileno=os.dup(self._child.conn.fileno())) as end:
                end.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        if self._receiver.is_alive():
            self._receiver.join(timeout=2.0)
        self._child.end(timeout_s=2.0)


def _serve_prepared(conn, source: str, params, mounting) -> None:
    from capture.recording.encode import encode_processed  # noqa: F401  (imported meanwhile)
    from capture.recording.reader import FrameAssembler  # noqa: F401
    from inference.features import fit_profile  # noqa: F401
    from inference.preprocess import preprocess_ranges  # noqa: F401

    try:
        conn.send_bytes(_packed(("ready",)))
        skip, times = conn.recv()
    except (BrokenPipeError, ConnectionResetError, EOFError):
        return  # the replay was stopped
    outbox = _Outbox(conn)
    try:
        for step in replay_steps(source, params, mounting, skip=skip, times=times):
            if not outbox.put(_packed(("frame", step))):
                return  # the replay was stopped
        outbox.put(_packed(("end",)))
    except ImuOrderError:
        outbox.put(_packed(("order",)))
    except CaptureError as e:
        outbox.put(_packed(("error", str(e))))
    except Exception as e:  # a corrupt file: one message on the other side
        outbox.put(_packed(("error", f"{source}: {type(e).__name__}: {e}")))
    finally:
        outbox.close()


class _Outbox:
    """The reader process's messages sent by a thread of their own, up to AHEAD waiting:
    the socket holds about one frame, and while the other side is slow to take it (its
    threads share one interpreter) the reader goes on with the next frames instead of
    waiting in the send."""

    AHEAD = 32

    def __init__(self, conn) -> None:
        self._conn = conn
        self._queue: queue.Queue = queue.Queue(maxsize=self.AHEAD)
        self._broken = threading.Event()
        self._thread = threading.Thread(target=self._send, name="walkcap-replay-sender")
        self._thread.start()

    def _send(self) -> None:
        while (payload := self._queue.get()) is not None:
            if self._broken.is_set():
                continue  # drain: nobody is listening
            try:
                self._conn.send_bytes(payload)
            except BaseException:  # the replay was stopped (a broken pipe), or worse
                self._broken.set()  # either way nothing more goes out: the reader stops

    def put(self, payload: bytes) -> bool:
        """Queued to send; False once the other side has gone."""
        while not self._broken.is_set():
            try:
                self._queue.put(payload, timeout=0.2)
                return True
            except queue.Full:
                continue
        return False

    def close(self) -> None:
        """Everything queued is sent (or dropped, the other side gone); the thread ends."""
        while self._thread.is_alive():
            try:
                self._queue.put(None, timeout=0.2)
                break
            except queue.Full:
                continue
        self._thread.join()


def _packed(message: tuple) -> bytes:
    """A message of the reader process as it goes over the socket: the length of its
    pickle, the pickle, then the data of a step's messages (depth, confidence, ...: the
    bulk of its bytes) one after the other, outside the pickle: pickling copies bytes
    into its stream and unpickling out of it again, for the best part of a frame's
    transfer. The step's messages are left as (topic, log time, publish time, size,
    sequence)."""
    if message[0] != "frame":
        head = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
        return b"".join((len(head).to_bytes(8, "little"), head))
    step, data = message[1], []

    def bare(m):
        if m is None:
            return None
        data.append(m.data)
        return (m.topic, m.log_time, m.publish_time, len(m.data), m.sequence)

    step.messages = [bare(m) for m in step.messages]
    step.imu = [(sample, bare(m), events, at) for sample, m, events, at in step.imu]
    head = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
    return b"".join((len(head).to_bytes(8, "little"), head, *data))


def _unpacked(payload: bytes) -> tuple:
    """_packed's message again, a step's messages' data views of `payload`."""
    from capture.recording.encode import Encoded

    view = memoryview(payload)
    size = int.from_bytes(view[:8], "little")
    message = pickle.loads(view[8 : 8 + size])
    if message[0] != "frame":
        return message
    step, at = message[1], 8 + size

    def dressed(bare):
        nonlocal at
        if bare is None:
            return None
        topic, log_time, publish_time, size, sequence = bare
        at += size
        return Encoded(topic, log_time, publish_time, view[at - size : at], sequence)

    step.messages = [dressed(m) for m in step.messages]
    step.imu = [(sample, dressed(m), events, t) for sample, m, events, t in step.imu]
    return message


def replay(
    source: str | Path,
    config,
    *,
    output: str | Path | None = None,
    speed: float | None = None,
    classifier=None,
    progress=None,
    reader_process: bool = True,
) -> ReplayReport:
    """Run the pipeline on `source` into `output`. speed None: as fast as possible (with
    a reader process unless `reader_process` is False); else paced at `speed` x the
    recorded rate."""
    from capture.recording.reader import open_recording

    source = Path(source)
    rec = open_recording(source)
    if T.DEPTH not in rec.topics:
        raise CaptureError(f"{source}: no depth frames to replay")
    output = Path(output) if output else default_output(source)
    if output.resolve() == source.resolve():
        raise CaptureError("the replay must go to a new file; the original is never modified")
    # copies: the replay keeps the parameters it started with
    params, mounting = dataclasses.replace(config.preprocess), dataclasses.replace(config.mounting)
    job = _ReplayJob(source, rec, output, config, params, mounting, speed, classifier, progress)
    try:
        return _replay_pass(job, reader_process, None)
    except ImuOrderError:  # a sample held late in the file: every sample's time first
        for partial in (output, output.with_name(output.name + ".journal.jsonl")):
            partial.unlink(missing_ok=True)
        return _replay_pass(job, reader_process, imu_times(rec))


def _replay_pass(job: _ReplayJob, reader_process: bool, times) -> ReplayReport:
    """One replay of the job: its steps from the reader process (fast) or this one."""
    fast = not job.speed
    # the reader process starts first: its imports overlap with loading the model here
    frames_in = (
        _ReaderProcess(job.source, job.params, job.mounting, times)
        if fast and reader_process
        else None
    )
    try:
        if frames_in is not None:
            frames_in.start()
            blocks = _head_start(job.source, job.params, job.mounting, frames_in)
        else:  # one by one, in this process
            blocks = ([s] for s in replay_steps(job.source, job.params, job.mounting, times=times))
        if fast:
            blocks = _fixed_batches(blocks, BATCH)
        return _replay(job, blocks)
    finally:
        if frames_in is not None:
            frames_in.close()


def _fixed_batches(blocks, size: int):
    """The frames of `blocks` regrouped into lists of exactly `size` (the last may be
    shorter), however they came."""
    batch: list = []
    for block in blocks:
        for item in block:
            batch.append(item)
            if len(batch) == size:
                yield batch
                batch = []
    if batch:
        yield batch


def _head_start(source, params, mounting, frames_in: _ReaderProcess):
    """Blocks of steps: the reader process's batches, all of them when it was ready
    before this process came to the frames; else prepared here, one at a time, until it is
    ready (a Python that imports numpy, mcap and protobuf first: waiting for it would cost
    a noticeable part of a short recording's replay), then its batches from the next step
    on."""
    if not frames_in.claim_start("host"):
        yield from frames_in.batches(BATCH)
        return
    done = 0
    if not frames_in.ready.is_set():
        own = replay_steps(source, params, mounting, times=frames_in.times)
        try:
            for step in own:
                yield [step]
                done += 1
                if frames_in.ready.is_set():
                    break
        finally:
            own.close()
    frames_in.start_at(done)
    yield from frames_in.batches(BATCH)


@dataclass(frozen=True)
class _ReplayJob:
    """What one replay runs with: the source and its open recording, the output, the
    configuration and the parameter copies it started with, the pace, the classifier (None:
    the configured model) and the progress callback."""

    source: Path
    rec: object
    output: Path
    config: object
    params: object
    mounting: object
    speed: float | None
    classifier: object
    progress: object


def _replay(job: _ReplayJob, blocks) -> ReplayReport:
    from capture.recording.chunks import ZSTD_LEVEL_FAST
    from capture.recording.encode import encode_preprocessing
    from capture.recording.writer import Recorder
    from inference import features  # noqa: F401  (imported now, not in the first frame's time)
    from inference.model import load_classifier

    classifier = job.classifier or load_classifier(
        job.config.model.path or None, threads=CNN_THREADS
    )
    pipeline = build_pipeline(job.config, classifier, job.params, job.mounting)

    meta = job.rec.meta
    # the source's records kept, in the source's order
    metadata = {
        name: getattr(meta, name).to_dict()
        for name in job.rec.metadata
        if name in (SessionRecord.NAME, DevicesRecord.NAME, CameraRecord.NAME)
    }
    software = SoftwareRecord.from_dict(
        {
            **meta.software.to_dict(),
            **software_metadata(job.config, pipeline),
            "replay_of": job.source.name,
        }
    )
    metadata[software.NAME] = software.to_dict()
    replay_id = str(uuid.uuid4())
    metadata[DerivationRecord.NAME] = derivation(
        job.rec,
        replay_id,
        REPLAY,
        f"replay with model {software.model_hash[:12] or '?'} ({software.model_path})",
        model_hash=software.model_hash,
        model_path=software.model_path,
    )
    attachments = {name: data for name, data in job.rec.attachments.items()}
    recorder = Recorder(
        job.output,
        recording_id=replay_id,
        metadata=metadata,
        attachments=attachments,
        blocking=True,
        zstd_level=ZSTD_LEVEL_FAST,
    )
    recorder.start()
    batch = getattr(classifier, "predict_batch", None)
    sim_gait: list = []  # the walk's truth, written as recorded, in time order

    def recorded(step: ReplayStep) -> None:
        """What the pass read before the step's frame, into the new file."""
        for lab in step.labels:
            recorder.write_label(int(lab["time_ns"]), lab.get("mode", ""), lab.get("source", ""))
        for ev in step.events:
            recorder.write_event(dict(ev))
        sim_gait.extend(step.sim_gait)
        for sample, message, events, received_ns in step.imu:
            if message is None:
                recorder.write_imu(sample)
            else:
                recorder.write_recorded([message])
            for event in events:
                recorder.write_gait(event, received_ns)
                pipeline.see_gait(event, received_ns)  # as live

    frames = 0
    first_t = last_t = None
    wall0 = time.monotonic()
    try:
        for block in blocks:
            images = [s.prepared.image for s in block if s.frame is not None]
            probs = (
                batch(np.stack(images))
                if batch is not None and images
                else [classifier.predict(image) for image in images]
            )
            for step, p in zip((s for s in block if s.frame is not None), probs):
                frame = step.frame
                t = frame.device_time_ns
                first_t = t if first_t is None else first_t
                last_t = t
                if job.speed:  # recorded pace, scaled
                    wait = clock.seconds(t - first_t) / job.speed - (time.monotonic() - wall0)
                    if wait > 0:
                        time.sleep(wait)
                recorded(step)
                result = pipeline.process(
                    frame,
                    step.orientation,
                    t,
                    prepared=step.prepared,
                    probabilities=p,
                    fit=step.fit,
                )
                pre, log_time = step.prepared, frame.host_time_ns
                processed = encode_preprocessing(
                    frame.index,
                    t,
                    log_time,
                    pre.image,
                    result.orientation,
                    pre.flag,
                    pre.details["cloud_points"],
                    pre.details["cloud_kept"],
                )
                messages = _with_processed(step.messages, processed)
                recorder.write_encoded(frame.index, t, log_time, messages)
                record_decisions(recorder, result, frame.host_time_ns)
                frames += 1
                if job.progress is not None:
                    job.progress(frames)
            for step in block:
                if step.frame is None:  # the last: what follows the last frame
                    recorded(step)
        for event in sorted(sim_gait, key=lambda e: e.time_ns):
            recorder.write_gait(event)
    finally:
        stats = recorder.close()
    taken = time.monotonic() - wall0
    recorded_s = clock.seconds(last_t - first_t) if frames > 1 else 0.0
    return ReplayReport(str(job.source), str(job.output), frames, recorded_s, taken, stats)


def replay_file(source: str, config, output: str) -> ReplayReport:
    """One recording's replay as a task of a corpus job (capture.corpus.jobs): as fast as
    possible in this process, the same file as `replay` writes."""
    report = replay(source, config, output=output, reader_process=False)
    if report.stats.state == "failed":
        raise CaptureError(f"{output}: {report.stats.message}")
    return report
