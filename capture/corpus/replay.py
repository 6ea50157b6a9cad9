"""Replay: the pipeline run again on a recording's depth and IMU, into a new recording.

Deterministic: frames in order, each with the IMU samples recorded up to just after its
time in the orientation track, exactly as the live session would have had them. The
original file is only read.

As fast as possible (`speed=None`), the work is split over two processes, since one
Python process cannot use a second core: a reader process decodes the frames, levels and
preprocesses them and encodes what the new recording keeps of them (depth, cloud, image,
orientation, truth); this one classifies them in batches, fuses, measures the terrain and
records (its main thread shares the interpreter with the threads that receive the frames
and write the file: the two processes' shares of a frame's CPU time are about even). The
IMU is read in one pass and kept in compact columns. While the reader process starts,
this one prepares the first frames itself. The frames are classified in batches of BATCH
from the first frame on, whatever the reader process has sent so far: the CNN's float
results depend on the batch's size, and fixed batches give the same file on every run.
Paced replays (`speed=X`), and replays that are one task of a corpus job
(`reader_process=False`: the cluster has given each task one core), run in this process
alone.
"""

from __future__ import annotations

import array
import dataclasses
import os
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


_INTS = ("host_time_ns", "time_ns", "packet_counter", "sample_time_fine", "status_word")
_VECTORS = (("quaternion", 4), ("acceleration", 3), ("rate_of_turn", 3))


class ImuColumns:
    """IMU samples kept as columns, about 130 bytes a sample (an ImuSample object takes
    nearly 800: a two-hour trial's samples would take over half a GB). A sample that does
    not fit the columns (a value of another type or shape, extra outputs) is kept whole."""

    def __init__(self) -> None:
        self._ints = [array.array("q") for _ in _INTS]
        self._vectors = [array.array("d") for _ in _VECTORS]
        self._present = [bytearray() for _ in _INTS + _VECTORS]
        self._whole: dict[int, ImuSample] = {}
        self._n = 0

    def add(self, s: ImuSample) -> None:
        ints = [getattr(s, name) for name in _INTS]
        vectors = [getattr(s, name) for name, _ in _VECTORS]
        fits = not s.extra and all(v is None or type(v) is int for v in ints)
        fits = fits and all(v is None or v.shape == (k,) for v, (_, k) in zip(vectors, _VECTORS))
        if not fits:
            self._whole[self._n] = s
            ints, vectors = [None] * len(_INTS), [None] * len(_VECTORS)
        for column, present, v in zip(self._ints, self._present, ints):
            column.append(0 if v is None else v)
            present.append(v is not None)
        for (_, k), column, present, v in zip(
            _VECTORS, self._vectors, self._present[len(_INTS) :], vectors
        ):
            column.extend((np.nan,) * k if v is None else v.tolist())
            present.append(v is not None)
        self._n += 1

    def __len__(self) -> int:
        return self._n

    def column(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(values, present) of a field over the samples that fit the columns."""
        if name in _INTS:
            k = _INTS.index(name)
            values = np.frombuffer(self._ints[k], dtype=np.int64)
        else:
            k = [n for n, _ in _VECTORS].index(name)
            values = np.frombuffer(self._vectors[k], dtype=np.float64).reshape(-1, _VECTORS[k][1])
            k += len(_INTS)
        return values, np.frombuffer(self._present[k], dtype=bool)

    def whole(self) -> dict[int, ImuSample]:
        """The samples kept whole, by their position."""
        return self._whole

    def sample(self, i: int) -> ImuSample:
        """Sample `i` (in the order added), the same as the one added."""
        whole = self._whole.get(i)
        if whole is not None:
            return whole
        values = {
            name: int(c[i]) if p[i] else None
            for name, c, p in zip(_INTS, self._ints, self._present)
        }
        for k, (name, size) in enumerate(_VECTORS):
            here = self._present[len(_INTS) + k][i]
            c = self._vectors[k]
            values[name] = np.array(c[i * size : (i + 1) * size]) if here else None
        return ImuSample(**values)

    @property
    def nbytes(self) -> int:
        columns = (*self._ints, *self._vectors, *self._present)
        return sum(len(c) * (c.itemsize if isinstance(c, array.array) else 1) for c in columns)


@dataclass
class RecordedImu:
    """What replay keeps of a recording's IMU from one pass, in compact arrays.
    `samples`: in file order; `order`: their positions sorted by sample time (stable);
    `times_ns`: their sample times in that order; `orientations`: (times ns, quaternions
    N x 4, rates of turn N x 3, NaN where absent) of the samples that carry an
    orientation, in that order: what the orientation track needs, compact to hand over."""

    samples: ImuColumns
    order: np.ndarray
    times_ns: np.ndarray
    orientations: tuple[np.ndarray, np.ndarray, np.ndarray]

    def in_order(self) -> Iterator[ImuSample]:
        """The samples in sample-time order."""
        for i in self.order:
            yield self.samples.sample(int(i))


def recorded_compact(rec) -> tuple[RecordedImu, list[dict], list[dict]]:
    """The recording's IMU (as RecordedImu), labels and events: one pass."""
    samples = ImuColumns()
    labels, events = [], []
    for m in rec.messages([T.IMU, T.LABELS, T.EVENTS]):
        if m.topic == T.IMU:
            samples.add(imu_sample(m.data))
        else:
            (labels if m.topic == T.LABELS else events).append(m.data)
    t, has_t = samples.column("time_ns")
    host, _ = samples.column("host_time_ns")
    quats, has_q = samples.column("quaternion")
    rates, has_rate = samples.column("rate_of_turn")
    t, quats, rates = np.where(has_t, t, host), quats.copy(), rates.copy()
    has_q = has_q.copy()
    rates[~has_rate] = np.nan
    for i, s in samples.whole().items():
        t[i] = _sample_time(s)
        has_q[i] = s.quaternion is not None
        if has_q[i]:
            quats[i] = s.quaternion
            rates[i] = s.rate_of_turn if s.rate_of_turn is not None else np.nan
    order = np.argsort(t, kind="stable")
    kept = order[has_q[order]]
    return (
        RecordedImu(samples, order, t[order], (t[kept], quats[kept], rates[kept])),
        labels,
        events,
    )


def _sample_time(s: ImuSample) -> int:
    return s.time_ns if s.time_ns is not None else s.host_time_ns


def prepared_frames(
    source: str | Path, params, mounting, imu_orientations=None, skip: int = 0
) -> Iterator[tuple[DepthFrame, np.ndarray | None, object]]:
    """(frame, orientation, Preprocessed) for every recorded frame, in order, after the
    first `skip`, preprocessed with `params` (a PreprocessConfig) and the camera's
    `mounting`. `imu_orientations`: RecordedImu.orientations of the recording, if already read."""
    from capture.recording.reader import depth_frames, open_recording
    from inference.preprocess import preprocess

    if imu_orientations is None:
        imu_orientations = recorded_compact(open_recording(source))[0].orientations
    times, quats, rates = imu_orientations
    track = OrientationTrack(span_s=5.0)
    i = 0
    for k, frame in enumerate(depth_frames(source)):
        if k < skip:  # decoded for nothing: a skipped frame costs its decoding only
            continue
        t = frame.device_time_ns
        while i < len(times) and times[i] <= t + IMU_LOOKAHEAD_NS:
            track.add(int(times[i]), quats[i], rates[i] if np.isfinite(rates[i, 0]) else None)
            i += 1
        q, age_ns = track.at(t)
        level = q if q is not None else np.full(4, np.nan)
        yield frame, q, preprocess(frame.xyz, frame.confidence, level, params, age_ns, mounting)


class _ReaderProcess:
    """prepared_frames() run in a child process, read back in order. A thread here takes
    the frames off the socket as they come: the socket holds about one frame, so without
    it the reader would stop while this process classifies a batch, and the two would
    take turns instead of working at once. The child says when it is ready (`ready`) and
    is then told how many frames to skip (`start_at`): those this process has done itself
    meanwhile."""

    AHEAD = 64  # frames received and not yet taken (~10 MB)

    def __init__(self, source: Path, params, mounting) -> None:
        from devices.child import Child

        self._child = Child("capture.corpus.replay:_serve_prepared", str(source), params, mounting)
        self._received: queue.Queue = queue.Queue(maxsize=self.AHEAD)
        self._closed = threading.Event()
        self.ready = threading.Event()  # set at the child's first message
        self._receiver = threading.Thread(
            target=self._receive, name="walkcap-replay-receiver", daemon=True
        )

    def start(self, imu_orientations) -> None:
        """The IMU's orientations, read meanwhile in this process: frames start coming."""
        self._child.conn.send(imu_orientations)
        self._receiver.start()

    def _receive(self) -> None:
        conn = self._child.conn
        while not self._closed.is_set():
            try:
                message = conn.recv()
            except (EOFError, OSError):
                message = ("error", "replay: the frame reader process ended unexpectedly")
            except Exception as e:  # never leave the consumer waiting for nothing
                message = ("error", f"replay: unreadable data from the frame reader ({e})")
            if not self.ready.is_set():  # or it failed before it was: nothing more to wait for
                self.ready.set()
            if message[0] == "ready":
                continue
            while not self._closed.is_set():
                try:
                    self._received.put(message, timeout=0.2)
                    break
                except queue.Full:
                    continue
            if message[0] != "frame":
                return

    def start_at(self, skip: int) -> None:
        """Frames from number `skip` on (the child waits for this after `ready`)."""
        try:
            self._child.conn.send(skip)
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
    from capture.recording.encode import encode_depth  # noqa: F401
    from capture.recording.reader import depth_frames  # noqa: F401  (imported while the host reads)

    try:
        imu_orientations = conn.recv()
        conn.send(("ready",))
        skip = conn.recv()
        for frame, q, pre in prepared_frames(source, params, mounting, imu_orientations, skip):
            conn.send(("frame", _encoded(frame, q, pre)))
        conn.send(("end",))
    except (BrokenPipeError, ConnectionResetError, EOFError):
        pass  # the replay was stopped
    except CaptureError as e:
        conn.send(("error", str(e)))
    except Exception as e:  # a corrupt file: one message on the other side
        conn.send(("error", f"{source}: {type(e).__name__}: {e}"))


def _encoded(frame: DepthFrame, q, pre):
    """What the recording needs of a frame that fusion does not change, encoded (in the
    reader process when replaying fast); the frame and its Preprocessed go on without
    their bulky arrays. The rays come with the source's attachments."""
    from capture.recording.encode import encode_depth, encode_processed, encode_truth

    t, log_time = frame.device_time_ns, frame.host_time_ns
    messages = encode_depth(frame, t, log_time) + encode_processed(
        frame.index, t, log_time, pre.cloud, pre.image, q, pre.flag
    )
    if frame.truth:
        messages += encode_truth(frame.index, t, log_time, frame.truth)
    none = np.zeros((0, 0), np.uint8)
    slim = dataclasses.replace(
        frame, xyz=np.zeros((0, 0, 3), np.float32), confidence=none, gray=none, range_mm=None
    )
    return slim, q, dataclasses.replace(pre, cloud=np.zeros((0, 3), np.float32)), messages


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
    fast = not speed
    # the reader process starts first: its imports overlap with reading the IMU here
    frames_in = _ReaderProcess(source, params, mounting) if fast and reader_process else None
    try:
        imu, labels, events = recorded_compact(rec)
        imu_orientations = imu.orientations
        if frames_in is not None:
            frames_in.start(imu_orientations)
            blocks = _head_start(source, params, mounting, imu_orientations, frames_in)
        else:  # one by one, in this process
            blocks = (
                [_encoded(frame, q, pre)]
                for frame, q, pre in prepared_frames(source, params, mounting, imu_orientations)
            )
        if fast:
            blocks = _fixed_batches(blocks, BATCH)
        job = _ReplayJob(source, rec, output, config, params, mounting, speed, classifier, progress)
        return _replay(job, blocks, (imu, labels, events))
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


def _head_start(source, params, mounting, imu_orientations, frames_in: _ReaderProcess):
    """Blocks of frames: prepared here, one at a time, until the reader process is ready
    (a Python that imports numpy, mcap and protobuf first: waiting for it would cost a
    noticeable part of a short recording's replay); then the reader's batches, from the
    next frame on."""
    done = 0
    if not frames_in.ready.is_set():
        own = prepared_frames(source, params, mounting, imu_orientations)
        try:
            for frame, q, pre in own:
                yield [_encoded(frame, q, pre)]
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


def _replay(job: _ReplayJob, blocks, recorded_streams) -> ReplayReport:
    from capture.recording.chunks import ZSTD_LEVEL_FAST
    from capture.recording.gait import read_gait
    from capture.recording.writer import Recorder
    from inference import features  # noqa: F401  (imported now, not in the first frame's time)
    from inference.gait import GaitDetector
    from inference.model import load_classifier

    classifier = job.classifier or load_classifier(
        job.config.model.path or None, threads=CNN_THREADS
    )
    pipeline = build_pipeline(job.config, classifier, job.params, job.mounting)

    imu, labels, events = recorded_streams

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
    imu_times, imu_samples = imu.times_ns, imu.in_order()
    gait = GaitDetector()  # /gait recomputed from the IMU, as live

    def write_imu(sample) -> None:
        recorder.write_imu(sample)
        for event in gait.push(sample):
            recorder.write_gait(event, sample.host_time_ns)
            pipeline.see_gait(event, sample.host_time_ns)  # as live

    i_imu = 0
    frames = 0
    first_t = last_t = None
    wall0 = time.monotonic()
    try:
        for lab in labels:
            recorder.write_label(int(lab["time_ns"]), lab.get("mode", ""), lab.get("source", ""))
        for ev in events:
            recorder.write_event(dict(ev))
        for event in read_gait(job.rec, source="simulator").events():  # the truth, as recorded
            recorder.write_gait(event)
        for block in blocks:
            probs = (
                batch(np.stack([pre.image for _, _, pre, _ in block]))
                if batch is not None
                else [classifier.predict(pre.image) for _, _, pre, _ in block]
            )
            for (frame, q, pre, encoded), p in zip(block, probs):
                t = frame.device_time_ns
                first_t = t if first_t is None else first_t
                last_t = t
                if job.speed:  # recorded pace, scaled
                    wait = clock.seconds(t - first_t) / job.speed - (time.monotonic() - wall0)
                    if wait > 0:
                        time.sleep(wait)
                while i_imu < len(imu_times) and imu_times[i_imu] <= t + IMU_LOOKAHEAD_NS:
                    write_imu(next(imu_samples))
                    i_imu += 1
                result = pipeline.process(frame, q, t, prepared=pre, probabilities=p)
                recorder.write_encoded(frame.index, t, frame.host_time_ns, encoded)
                record_decisions(recorder, result, frame.host_time_ns)
                frames += 1
                if job.progress is not None:
                    job.progress(frames)
        for s in imu_samples:
            write_imu(s)
    finally:
        stats = recorder.close()
    taken = time.monotonic() - wall0
    recorded = clock.seconds(last_t - first_t) if frames > 1 else 0.0
    return ReplayReport(str(job.source), str(job.output), frames, recorded, taken, stats)


def replay_file(source: str, config, output: str) -> ReplayReport:
    """One recording's replay as a task of a corpus job (capture.corpus.jobs): as fast as
    possible in this process, the same file as `replay` writes."""
    report = replay(source, config, output=output, reader_process=False)
    if report.stats.state == "failed":
        raise CaptureError(f"{output}: {report.stats.message}")
    return report
