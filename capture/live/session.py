"""A data-collection session: devices in; pipeline, recording and UI snapshots out.

Threads: one reads the IMU into the orientation track (and the recorder); one reads camera
frames, records each at once (raw data and labels first, whatever the pipeline does) and
hands the newest to the pipeline thread; the recorder writes on its own thread. Nothing here
waits on the UI or the disk: the UI pulls `snapshot()` at its own pace and sends commands
(`set_label`, `add_marker`, `start_recording`, ...) that only touch memory and queues.
"""

from __future__ import annotations

import collections
import gc
import logging
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from capture import config as config_mod
from capture.errors import CaptureError, ConfigError
from capture.live.alarms import AlarmState, TrialAlarms
from capture.live.devices import close_devices, devices_metadata, open_devices, stream_periods
from capture.live.handover import FrameInbox, Streak
from capture.live.labels import LabelBook
from capture.live.pipeline import (
    CNN_THREADS,
    IMU_LATE_S,
    FrameResult,
    OrientationTrack,
    Pipeline,
    build_pipeline,
    record_decisions,
    record_truth,
    software_metadata,
)
from capture.live.timeline import FrameTimeline, TimelineEntry
from capture.live.trials import (
    SubjectInfo,
    trial_attachments,
    trial_file,
    trial_metadata,
)
from capture.recording.labels import UNDO, LabelChange
from capture.recording.sink import Sink
from devices import clock
from devices.base import DeviceEvent, DeviceState, DeviceStatus
from devices.clock import now_ns
from devices.frames import DepthFrame
from devices.scheduling import NORMAL_PRIORITY, realtime_priority
from inference.errors import InferenceError
from inference.gait import GaitDetector
from inference.preprocess import camera_orientation

if TYPE_CHECKING:  # the writer's imports take a second: Recorder is imported when it records
    from capture.recording.writer import RecorderStats

log = logging.getLogger(__name__)

SWITCH_INTERVAL_S = 0.0005


@dataclass
class Snapshot:
    """Everything the UI shows, copied out under the lock: the UI never touches threads."""

    time_ns: int
    running: bool
    camera: DeviceStatus | None
    imu: DeviceStatus | None
    sync: dict
    label: str | None
    latest: FrameResult | None
    timeline: list[TimelineEntry]
    events: list[DeviceEvent]
    recording: RecorderStats | None
    recording_started_ns: int | None
    frames: int
    latency_ms: dict
    switches_last_minute: int | None = None  # final fused decision changes (timeline.SWITCHES_S)
    walker_mode: str | None = None  # mock devices: the walker's locomotion mode, to key
    alarms: AlarmState | None = None  # gaps this trial, and what the operator must see now
    stale_frames: int = 0  # frames of this (or the last) trial left undecided: stale IMU
    fusion_method: str = ""  # the method behind the fused decisions ("": not known)
    cadence_spm: float | None = None  # steps a minute from the IMU's gait events (None: still)
    steps: int | None = None  # steps this trial (or this session): two a stride of the thigh


HOST_STALL_NS = 1_000_000_000  # the monitor (every 0.2 s) not run for this long: a host stall

# Threads carrying raw data in: the rig's reader, the IMU driver's and this session's
# camera and IMU threads (the IMU's share one name).
INTAKE_THREADS = ("walkcap-rig-reader", "walkcap-imu", "walkcap-camera")


class Session:
    """Open devices, run the pipeline, record trials, serve snapshots and commands."""

    def __init__(
        self,
        config: config_mod.Config,
        *,
        camera=None,
        imu=None,
        classifier=None,
        auto_label: bool = False,
    ) -> None:
        self.config = config
        self._camera = camera
        self._imu = imu
        self._classifier = classifier
        self.auto_label = auto_label
        self.track = OrientationTrack()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._recorder = None
        self._recording_started_ns: int | None = None
        self.labels = LabelBook()
        self.timeline = FrameTimeline()
        self._events: collections.deque[DeviceEvent] = collections.deque(maxlen=200)
        self._taps: tuple[Sink, ...] = ()  # live outputs beside the recorder (LSL, Foxglove)
        self._sync_errors: collections.deque[float] = collections.deque(maxlen=5000)
        self.gait = GaitDetector()  # on the IMU thread: /gait, the cadence and the steps
        self._strides_at_start = 0  # heel contacts before the trial in progress
        self._gait_failed = False
        self._last_truth_mode: str | None = None
        self._walker_mode: str | None = None
        self._inbox = FrameInbox()
        self._failures = Streak("pipeline", "error", "the pipeline failed on it")
        self._behind = Streak("pipeline", "behind", "the pipeline fell behind")
        self.pipeline: Pipeline | None = None
        self.pipeline_priority = NORMAL_PRIORITY  # how the pipeline thread is scheduled
        self.intake_scheduling = NORMAL_PRIORITY  # how the intake threads and writer are
        self.model_metadata: dict = {}
        self.finished = threading.Event()  # the camera ran out of frames (end of a mock course)
        self.trial_notice = ""  # why the last recording has another trial number than asked
        self.trial: SubjectInfo | None = None  # the form of the recording in progress
        self.alarms = TrialAlarms(config.session.recordings, stream_periods(config))

    # ---- life cycle -------------------------------------------------------------------

    def start(self) -> None:
        """Load the model, open both devices and start the threads."""
        from inference.model import load_classifier

        cfg = self.config
        if not 0 <= cfg.session.realtime_priority <= 99:
            raise ConfigError(
                f"session.realtime_priority: 1-99, or 0 for normal scheduling; "
                f"got {cfg.session.realtime_priority}"
            )
        if self._classifier is None:
            self._classifier = load_classifier(cfg.model.path or None, threads=CNN_THREADS)
        self.model_metadata = dict(getattr(self._classifier, "metadata", {}) or {})
        self.pipeline = build_pipeline(cfg, self._classifier)
        # First calls are slow (torch's lazy set-up, numpy caches, the recorder's schema
        # modules): pay for them before the camera runs, not in the first frames of a trial.
        try:
            for _ in range(3):
                self._classifier.predict(np.zeros((100, 100), np.uint8))
        except Exception as e:  # refused before any device opens, as a model file is
            raise InferenceError(f"the classifier fails on a blank image: {e}") from None
        from inference import compiled

        compiled.warm()  # the compiled kernels loaded (compiled, on a fresh machine's first run)
        import capture.recording.writer  # noqa: F401  (mcap, protobuf: a second of imports)

        # The pipeline thread gives the GIL up hundreds of times a frame (numpy, torch) and
        # each time may wait a whole switch interval behind the IMU's or the recorder's
        # Python code to get it back: at the default 5 ms that puts several frames' worth
        # of wait on the p99 latency of a few ms of work. A 0.5 ms interval bounds that wait
        # (process-wide).
        sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL_S))
        # A full garbage collection walks every object of torch, Open3D and the UI: tens of
        # ms with every thread stopped, a few times a minute (dropped frames, the p99). Objects
        # alive now live for the session: freeze them out of the collector's walks (until
        # stop()).
        gc.collect()
        gc.freeze()
        if self._camera is None or self._imu is None:
            self._camera, self._imu = open_devices(cfg, self._camera, self._imu)
        try:
            self._imu.start()
            self._camera.start()
        except BaseException:
            close_devices(self._camera, self._imu)
            raise
        # As fast as the pipeline runs (a mock camera not in real time): every frame waits
        # for its classification; in real time the pipeline takes the newest frame.
        self._inbox.blocking = cfg.camera.backend == "mock" and not cfg.simulator.realtime
        self._inbox.size = cfg.camera.buffer_frames
        self._spawn(self._imu_loop, "imu")
        self._spawn(self._frame_loop, "camera")
        pipeline = self._spawn(self._pipeline_loop, "pipeline")
        self.pipeline_priority = realtime_priority(
            pipeline.native_id, cfg.session.realtime_priority
        )
        # The threads that carry raw data in (the devices' readers, this session's intake)
        # and the recorder's writer run one step above the pipeline: what is derived from
        # the data never starves the data itself. They sleep between items.
        for thread in threading.enumerate():
            if thread.name in INTAKE_THREADS:
                self.intake_scheduling = realtime_priority(thread.native_id, self.intake_priority)
        self._spawn(self._monitor_loop, "monitor")

    @property
    def intake_priority(self) -> int:
        """SCHED_FIFO priority of the threads carrying raw data (0: normal scheduling)."""
        pipeline = self.config.session.realtime_priority
        return min(99, pipeline + 1) if pipeline > 0 else 0

    def _spawn(self, target, name: str) -> threading.Thread:
        t = threading.Thread(target=target, name=f"walkcap-{name}", daemon=True)
        t.start()
        self._threads.append(t)
        return t

    def stop(self):
        """Stop the threads and devices; finalise a recording in progress. Idempotent."""
        self._stop.set()
        self._inbox.close()
        for t in self._threads:
            t.join(timeout=3.0)
        self._threads.clear()
        stats = self.stop_recording() if self._recorder is not None else None
        close_devices(self._camera, self._imu)
        gc.unfreeze()  # what the session held may be collected again (the UI runs on)
        return stats

    def __enter__(self) -> Session:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    # ---- threads ----------------------------------------------------------------------

    def _imu_loop(self) -> None:
        while not self._stop.is_set():
            sample = self._imu.recv(0.1)
            if sample is None:
                continue
            t = sample.time_ns if sample.time_ns is not None else sample.host_time_ns
            # the device's count and time, and the recorder's log time
            self.alarms.sample("imu", sample.packet_counter, t, sample.host_time_ns)
            if sample.quaternion is not None:
                self.track.add(t, sample.quaternion, sample.rate_of_turn)
            truth = getattr(self._imu, "true_time_ns", None)
            if truth is not None and sample.sample_time_fine is not None:
                self._sync_errors.append(abs(t - truth(sample.sample_time_fine)) * 1e-6)
            gait = self._gait_events(sample)
            pipeline = self.pipeline
            for event in gait:  # to a fusion that acts at steps (the pipeline thread's)
                if pipeline is not None:
                    pipeline.see_gait(event, sample.host_time_ns)
            for out in self._outputs():
                out.write_imu(sample)
                for event in gait:  # known at this sample's receipt
                    out.write_gait(event, sample.host_time_ns)

    def _gait_events(self, sample) -> list:
        """The detector's events at this sample; a fault in it costs the steps, never the
        IMU's samples (said once)."""
        try:
            return self.gait.push(sample)
        except Exception:
            if not self._gait_failed:
                self._gait_failed = True
                log.exception("gait detector")
            return []

    def _frame_loop(self) -> None:
        """Camera frames in: each recorded at once, then handed to the pipeline thread."""
        while not self._stop.is_set():
            frame = self._camera.recv(0.1)
            if frame is None:
                if self._camera_finished():
                    self.finished.set()
                continue
            recorder = self.record_frame(frame)
            skipped = self._inbox.put((frame, recorder))
            t = frame.device_time_ns
            if skipped is not None:
                self._report(self._behind.fail(t, f"frame {skipped[0].index}"))
            else:
                self._report(self._behind.ok(t))

    def _pipeline_loop(self) -> None:
        # On stop, the frames the camera thread handed over last are classified too, so
        # that a trial's last recorded frames have their decisions like the others.
        camera = next(t for t in self._threads if t.name == "walkcap-camera")
        while not (self._stop.is_set() and not camera.is_alive()):
            item = self._inbox.take(0.1)
            if item is not None:
                self.classify_frame(*item)
        deadline = now_ns() + 1_000_000_000  # a slow classifier must not hold the stop up
        while now_ns() < deadline and (item := self._inbox.take(0.0)) is not None:
            self.classify_frame(*item)

    def _camera_finished(self) -> bool:
        status = self._camera.status()
        return status.state == DeviceState.STOPPED and not self._stop.is_set()

    def _monitor_loop(self) -> None:
        last = now_ns()
        while not self._stop.wait(0.2):
            t = now_ns()
            if t - last > HOST_STALL_NS:  # this loop wakes every 0.2 s: the host stalled
                stall_s = clock.seconds(t - last)
                self._event(
                    DeviceEvent(
                        t,
                        "host",
                        "stall",
                        f"the computer stalled for {stall_s:.2f} s (no walkcap thread ran): "
                        "what the devices kept meanwhile is recorded, the rest is a gap",
                        {"gap_s": stall_s, "gap_start_ns": last, "gap_end_ns": t},
                    )
                )
            last = t
            for device in (self._camera, self._imu):
                for event in device.poll_events():
                    self._event(event)

    def _event(self, event: DeviceEvent) -> None:
        with self._lock:
            self._events.append(event)
        for out in self._outputs():
            out.write_event(event)

    def _outputs(self) -> tuple[Sink, ...]:
        """Where the session's data goes: the recorder (while recording), then the taps."""
        rec = self._recorder
        return self._taps if rec is None else (rec, *self._taps)

    def add_event(self, event: DeviceEvent) -> None:
        """An event from beside the devices (an LSL peer, a lab tool): shown and recorded."""
        self._event(event)

    def active_recorder(self):
        """The recorder of the trial being recorded, or None between trials."""
        return self._recorder

    def add_tap(self, tap: Sink) -> None:
        """A live output beside the recorder: it gets the recorder's write_* calls (frames,
        IMU samples, labels, events) whether or not a trial is recording (see Sink)."""
        self._taps = (*self._taps, tap)

    def remove_tap(self, tap: Sink) -> None:
        self._taps = tuple(t for t in self._taps if t is not tap)

    # ---- per frame --------------------------------------------------------------------

    def record_frame(self, frame: DepthFrame) -> Sink | None:
        """The raw frame, its truth and an automatic label: written before any processing.
        Returns the recorder it went to (None between trials)."""
        t = frame.device_time_ns
        # the walker's locomotion mode, what an operator keys (the image's mode leads it)
        truth_mode = frame.truth.get("locomotion_mode") if frame.truth else None
        self._walker_mode = truth_mode
        if self.auto_label and truth_mode and truth_mode != self._last_truth_mode:
            self.set_label(truth_mode, source="simulator", time_ns=t)
        self._last_truth_mode = truth_mode
        self.alarms.sample("camera", frame.index, t, frame.host_time_ns)  # as the file has it
        rec = self._recorder
        for out in self._outputs():
            out.write_frame(frame, t)
            if frame.truth:
                record_truth(out, frame.index, t, frame.truth)
        return rec

    def classify_frame(self, frame: DepthFrame, recorder: Sink | None = None) -> FrameResult | None:
        """Preprocess, classify, fuse; the results recorded (into `recorder`, the one the
        raw frame went to, if it still records) and published. A failure (a classifier that
        raises or returns NaN) is one event for a run of failed frames."""
        t = frame.device_time_ns
        outputs = (
            (recorder, *self._taps)
            if recorder is not None and recorder is self._recorder
            else self._taps
        )
        # interpolated, or carried on by the rate of turn; too far from a sample: stale
        bound_ns = int(self.pipeline.params.max_orientation_age_ms * 1e6)
        quaternion, age_ns = self.track.fresh_at(t, bound_ns, IMU_LATE_S)
        pre = None
        try:
            pre = self.pipeline.prepare(frame, quaternion, age_ns)
            result = self.pipeline.process(frame, quaternion, t, prepared=pre)
        except Exception as e:  # one bad frame (or a broken model) must not end the session
            log.debug("frame %d", frame.index, exc_info=True)
            self._report(self._failures.fail(t, f"frame {frame.index}: {e}"), say=True)
            if pre is not None:
                q = camera_orientation(quaternion, self.pipeline.mounting)
                for out in outputs:
                    out.write_processed(
                        frame.index, t, frame.host_time_ns, pre.cloud, pre.image, q, pre.flag
                    )
            return None
        self._report(self._failures.ok(t))
        for out in outputs:
            out.write_processed(
                result.index,
                result.time_ns,
                result.host_time_ns,
                result.cloud,
                result.image,
                result.orientation,
                result.flag,
            )
            record_decisions(out, result)
        truth_mode = frame.truth.get("mode") if frame.truth else None
        votes = getattr(self.pipeline.fusion, "votes", False)
        self.timeline.publish(result, self.labels.label, truth_mode, votes)
        return result

    def _report(self, event: DeviceEvent | None, say: bool = False) -> None:
        if event is not None:
            if say:  # the start of a run, once: the rest is counted in the events
                log.warning("%s: %s", event.device, event.message)
            self._event(event)

    def add_latency_sink(self, sink: Callable[[float], None]) -> None:
        """Call `sink(ms)` with every frame's pipeline latency, in frame order.

        It runs on the pipeline thread, under the lock that counts the frame, so a sink
        sees exactly the frames a snapshot counts. It must be quick and must not call back
        into the session.
        """
        self.timeline.add_latency_sink(sink)

    @property
    def rig_pid(self) -> int | None:
        """The mock rig's process id when the devices run in it, else None."""
        rig = getattr(self._camera, "rig", None)
        return getattr(rig, "pid", None)

    # ---- commands (from the UI or the CLI) --------------------------------------------

    def set_label(
        self, mode: str, source: str = "operator", time_ns: int | None = None
    ) -> LabelChange:
        """The true mode from now on. Stamped here, at the key press, not at the next frame."""
        change = self.labels.change(mode, source, now_ns() if time_ns is None else time_ns)
        for out in self._outputs():
            out.write_label(change.time_ns, mode, source)
        return change

    def undo_label(self) -> LabelChange | None:
        """Take back the last change: the mode before it applies again from now on."""
        undo = self.labels.undo(now_ns())
        if undo is None:
            return None
        change, undone = undo
        for out in self._outputs():
            out.write_label(change.time_ns, change.mode, f"{UNDO}:{undone.mode}")
        return change

    def add_marker(self, note: str = "", time_ns: int | None = None) -> None:
        """A marker at `time_ns` (the key press; default now), with the operator's note."""
        self._event(
            DeviceEvent(
                now_ns() if time_ns is None else time_ns, "operator", "marker", note or "marker"
            )
        )

    def recent_sync_ms(self, samples: int = 100) -> dict:
        """The IMU-to-frame sync error of the last `samples` IMU samples (p50, p99 in ms):
        what the clock fit achieves now, without its first seconds of settling."""
        recent = list(self._sync_errors)[-samples:]
        if not recent:
            return {}
        return {"p50_ms": float(np.median(recent)), "p99_ms": float(np.percentile(recent, 99))}

    def inject(self, device: str, fault: str, **kw) -> None:
        """A fault of a mock device, for drills and tests ("imu", "disconnect", seconds=2)."""
        target = self._imu if device == "imu" else self._camera
        if getattr(target, "backend", "") != "mock" or not hasattr(target, "inject"):
            raise CaptureError(f"faults can be injected into mock devices only, not {device}")
        target.inject(fault, **kw)

    @property
    def label(self) -> str | None:
        return self.labels.label

    @property
    def recording(self) -> bool:
        return self._recorder is not None

    def start_recording(
        self, info: SubjectInfo, existing: str = "next", folder: str | Path | None = None
    ) -> Path:
        """One MCAP file per trial (capture.live.trials.trial_file: named from the form and
        the time; `existing` "next", "error" or "overwrite" for a trial with files already,
        and `trial_notice` says when the trial number changed). `folder` is this trial's
        only (a remote `filename`'s root); by default the configured recordings folder."""
        from capture.recording.writer import Recorder

        info.validate()
        if self._recorder is not None:
            raise CaptureError("already recording")
        self.trial_notice = ""
        target = trial_file(
            Path(self.config.session.recordings if folder is None else folder), info, existing
        )
        self.trial_notice = target.notice
        software = software_metadata(
            self.config,
            self.pipeline,
            pipeline_priority=self.pipeline_priority,
            intake_priority=self.intake_scheduling,
        )
        devices = devices_metadata(self.config, self._camera, self._imu)
        recorder = Recorder(
            target.path,
            metadata=trial_metadata(self.config, target, devices, software),
            attachments=trial_attachments(self.config, self.model_metadata),
            priority=self.intake_priority,
        )
        recorder.start()
        self.alarms.recordings = target.path.parent  # the trial's folder
        self.alarms.new_trial()
        self.timeline.new_trial()
        self._recorder = recorder
        self.trial = target.info
        self._recording_started_ns = now_ns()
        self._strides_at_start = self.gait.heel_contacts
        label = self.labels.label
        if label is not None:  # the mode in force when the trial starts
            recorder.write_label(self._recording_started_ns, label, "start")
        return target.path

    def stop_recording(self):
        for streak in (self._failures, self._behind):  # a run still going: its count
            self._report(streak.ok(now_ns(), final=True))
        rec, self._recorder = self._recorder, None
        self._recording_started_ns = None
        self.alarms.end_trial()
        return rec.close() if rec is not None else None

    # ---- what the UI reads ------------------------------------------------------------

    def snapshot(self) -> Snapshot:
        with self._lock:
            events = list(self._events)
            sync = np.asarray(self._sync_errors) if self._sync_errors else None
        published = self.timeline.published()
        snap = Snapshot(
            time_ns=now_ns(),
            running=not self._stop.is_set(),
            camera=self._camera.status() if self._camera else None,
            imu=self._imu.status() if self._imu else None,
            sync={},
            label=self.labels.label,
            latest=published.latest,
            timeline=published.timeline,
            switches_last_minute=published.switches_last_minute,
            walker_mode=self._walker_mode,
            events=events,
            recording=None,
            recording_started_ns=self._recording_started_ns,
            frames=published.frames,
            stale_frames=published.stale_frames,
            latency_ms=published.latency_ms,
            fusion_method=self.pipeline.fusion.method if self.pipeline else "",
            cadence_spm=self.gait.cadence_spm(),
            steps=2 * (self.gait.heel_contacts - self._strides_at_start),
        )
        if sync is not None:
            snap.sync = {"p50_ms": float(np.median(sync)), "p99_ms": float(np.percentile(sync, 99))}
        rec = self._recorder
        snap.recording = rec.stats() if rec is not None else None
        snap.alarms = self.alarms.state(snap.time_ns, snap.recording, snap.events)
        return snap
