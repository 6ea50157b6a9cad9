"""Per-frame pipeline: orientation at the frame's time -> image -> CNN -> fusion -> features.

No threads and no I/O here: the live session, replay and the benchmarks run the same code.
"""

from __future__ import annotations

import collections
import dataclasses
import threading
from dataclasses import dataclass, field

import numpy as np

from capture.recording.sink import Sink
from devices.clock import now_ns, seconds, to_ns
from devices.frames import MODES, DepthFrame
from devices.rotations import quat_multiply, quat_slerp
from inference import level_tilt
from inference.errors import InferenceError
from inference.fusion import FusionOutput
from inference.level_tilt import TiltEstimate
from inference.preprocess import camera_orientation

# One torch thread for the per-frame CNN: the pipeline shares the cores with the devices and
# the recorder, and torch's thread pool spinning against them costs far more than it gains.
CNN_THREADS = 1
# How far past the newest IMU sample its rate of turn carries the orientation (a few sample
# periods); beyond that the sample is held, and the frame's orientation is stale.
EXTRAPOLATE_NS = 50_000_000
# How long a frame may wait for IMU samples that are late (a busy host), not missing.
IMU_LATE_S = 0.2


class OrientationTrack:
    """Recent IMU orientations on the session clock, interpolated at any time inside them.

    Thread-safe: the IMU thread adds, the pipeline thread reads.
    """

    def __init__(self, span_s: float = 3.0, clock=now_ns) -> None:
        self._clock = clock
        self._added_ns: int | None = None  # when the newest sample came in, host clock
        self._times: collections.deque[int] = collections.deque()
        self._quats: collections.deque[np.ndarray] = collections.deque()
        self._span_ns = to_ns(span_s)
        self._rate: np.ndarray | None = None  # body rate of turn at the newest sample, rad/s
        self._lock = threading.Lock()
        self._new = threading.Condition(self._lock)

    def add(
        self, time_ns: int, quaternion: np.ndarray, rate_of_turn: np.ndarray | None = None
    ) -> None:
        with self._new:
            if self._times and time_ns <= self._times[-1]:
                return  # out of order or repeated: the clock estimator already smooths
            self._added_ns = self._clock()
            self._times.append(time_ns)
            self._quats.append(np.asarray(quaternion, dtype=np.float64))
            self._rate = (
                None if rate_of_turn is None else np.asarray(rate_of_turn, dtype=np.float64)
            )
            while self._times and time_ns - self._times[0] > self._span_ns:
                self._times.popleft()
                self._quats.popleft()
            self._new.notify_all()

    def wait_until(self, time_ns: int, timeout_s: float) -> bool:
        """Wait until a sample at or after `time_ns` arrived (so we interpolate, not hold)."""
        with self._new:
            return self._new.wait_for(
                lambda: bool(self._times) and self._times[-1] >= time_ns, timeout_s
            )

    def at(self, time_ns: int) -> tuple[np.ndarray | None, int]:
        """Orientation at `time_ns` and the distance (ns) to the nearest sample used.

        Between two samples: slerp. Just after the newest: rotated on by its rate of turn
        (a frame need not wait for the next IMU sample). Otherwise the nearest sample held.
        """
        with self._lock:
            if not self._times:
                return None, 0
            times = self._times
            if time_ns >= times[-1]:
                ahead_ns = time_ns - times[-1]
                q = self._quats[-1]
                if self._rate is not None and ahead_ns <= EXTRAPOLATE_NS:
                    q = quat_multiply(q, _rotation(self._rate * ahead_ns * 1e-9))
                return q, ahead_ns
            if time_ns <= times[0]:
                return self._quats[0], times[0] - time_ns
            # the track is short (a few hundred samples): bisect on a list copy is cheap
            i = _bisect(times, time_ns)
            t0, t1 = times[i - 1], times[i]
            w = (time_ns - t0) / (t1 - t0)
            q = quat_slerp(self._quats[i - 1], self._quats[i], w)
            return q, min(time_ns - t0, t1 - time_ns)

    def fresh_at(
        self, time_ns: int, max_age_ns: int, late_s: float
    ) -> tuple[np.ndarray | None, int]:
        """at(), after waiting for the IMU when it is late rather than gone: while samples
        keep coming (one came in within `late_s`), wait up to `late_s` for one within
        `max_age_ns` of `time_ns`. A busy host delays the IMU thread; an unplugged IMU
        sends nothing, and a frame then waits at most once `late_s`."""
        q, age = self.at(time_ns)
        if age <= max_age_ns:
            return q, age
        with self._new:
            if not self._times or time_ns <= self._times[-1] or self._added_ns is None:
                return q, age  # before the first sample, or inside the track: a real gap
            left_s = seconds(self._added_ns + to_ns(late_s) - self._clock())
            if left_s <= 0:
                return q, age  # silent for longer than a late IMU would be
            wanted = time_ns - max_age_ns
            self._new.wait_for(lambda: self._times[-1] >= wanted, left_s)
        return self.at(time_ns)


def _rotation(rotation_vector: np.ndarray) -> np.ndarray:
    """Quaternion of a rotation by |v| radians about v."""
    angle = float(np.linalg.norm(rotation_vector))
    if angle < 1e-12:
        return np.array([1.0, 0.0, 0.0, 0.0])
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * rotation_vector / angle])


def _bisect(times: collections.deque[int], t: int) -> int:
    lo, hi = 0, len(times)
    while lo < hi:
        mid = (lo + hi) // 2
        if times[mid] < t:
            lo = mid + 1
        else:
            hi = mid
    return lo


@dataclass
class FrameResult:
    """What the pipeline made of one frame."""

    index: int
    time_ns: int  # the frame's sample time, session clock
    host_time_ns: int  # receive time, session clock
    orientation: np.ndarray | None  # the camera's: camera -> leveled world (/tf)
    image: np.ndarray  # 100 x 100 uint8 0/1
    cloud: np.ndarray  # N x 3 float32, leveled
    profile: np.ndarray  # M x 2 float32 (forward, height)
    flag: str  # "" or why the image is empty
    probabilities: np.ndarray  # CNN softmax, 5
    cnn_decision: int
    fused: FusionOutput | None  # refers to an earlier frame
    features: dict = field(default_factory=dict)
    done_ns: int = 0  # when the fused decision was ready

    @property
    def decided(self) -> bool:
        """False for a frame left undecided (stale or bad orientation): no CNN output, and
        the fusion held, not fed."""
        return self.cnn_decision >= 0

    @property
    def latency_ms(self) -> float:
        return (self.done_ns - self.host_time_ns) * 1e-6

    def fused_dict(self) -> dict:
        """The fused output as recorded on /inference/fused (empty before the first)."""
        f = self.fused
        if f is None:
            return {}
        return {
            "frame_index": f.frame,
            "decision": MODES[f.decision] if f.decision is not None else None,
            "posterior": list(f.probabilities) if f.probabilities is not None else None,
            "posterior_frame_index": f.posterior_frame,
            "voted": MODES[f.voted] if f.voted is not None else None,
            "voted_frame_index": f.voted_frame,
        }


class Pipeline:
    """Preprocess -> classify -> fuse -> features, one frame at a time."""

    def __init__(self, params, classifier, fusion, mounting=None) -> None:
        """params: an inference.config.PreprocessConfig; mounting: the camera on the IMU
        (devices.config.MountingConfig; None: the nominal one)."""
        from inference.preprocess import NOMINAL_MOUNTING

        self.params = params
        self.mounting = mounting if mounting is not None else NOMINAL_MOUNTING
        self.classifier = classifier
        self.fusion = fusion
        # fusion counts pushes; decisions name camera frames: remember which is which
        self._pushed = 0
        self._frame_of_push: dict[int, int] = {}
        # gait events for a fusion that acts at steps, from the IMU's thread: a deque's
        # append and popleft are atomic, so the two threads share it without a lock
        self._gait: collections.deque = collections.deque(maxlen=256)
        # the IMU's tilt error, learned on level ground, off every reported slope
        self.tilt = TiltEstimate()

    def see_gait(self, event, known_ns: int | None = None) -> None:
        """A gait event (devices.frames.GaitEvent) from the detector, on any thread, and when
        it was known (the receipt of the IMU sample that revealed it; default: its time):
        a fusion that acts at steps (`uses_steps`) gets it before the first frame pushed at
        or after that, as `eval` hands it the recorded events (their log time)."""
        if getattr(self.fusion, "uses_steps", False):
            at = event.time_ns if known_ns is None else max(event.time_ns, known_ns)
            self._gait.append((at, event.event))

    def _hand_gait(self, time_ns: int) -> None:
        """The queued gait events known by the frame's time, in order, to the fusion."""
        gait = self._gait
        while gait and gait[0][0] <= time_ns:
            self.fusion.see_gait(gait.popleft()[1])

    def prepare(
        self, frame: DepthFrame, quaternion: np.ndarray | None, orientation_age_ns: int = 0
    ):
        """The preprocessing step alone (inference.preprocess.Preprocessed);
        `orientation_age_ns` as OrientationTrack.at() returns it."""
        from inference.preprocess import preprocess

        if quaternion is None:
            quaternion = np.full(4, np.nan)
        return preprocess(
            frame.xyz, frame.confidence, quaternion, self.params, orientation_age_ns, self.mounting
        )

    def process(
        self,
        frame: DepthFrame,
        quaternion: np.ndarray | None,
        time_ns: int | None = None,
        *,
        prepared=None,
        probabilities: np.ndarray | None = None,
        orientation_age_ns: int = 0,
        fit=None,
    ) -> FrameResult:
        """The whole frame; `prepared`, `probabilities` and `fit` (the profile's
        inference.features.fit_profile) when worked out ahead (replay preprocesses and fits
        in another process and classifies in batches).

        A frame whose orientation is stale or bad (inference.preprocess.UNDECIDED) gets no
        decision: the CNN does not see it and the fusion holds (it is not fed), so nothing
        is decided on a wrongly levelled cloud.
        """
        from inference.features import ground_ahead, shown_mode, terrain_features
        from inference.preprocess import UNDECIDED

        if quaternion is None:
            quaternion = np.full(4, np.nan)
        if prepared is None:
            prepared = self.prepare(frame, quaternion, orientation_age_ns)
        pre = prepared
        if pre.flag in UNDECIDED:
            # no image to trust: no CNN output, and the fusion is not fed (it holds)
            tilt_offset = 0.0
            probs, cnn, fused, feats, done_ns = (
                np.full(len(MODES), np.nan),
                -1,
                None,
                None,
                now_ns(),
            )
        else:
            probs = np.asarray(
                probabilities if probabilities is not None else self.classifier.predict(pre.image),
                dtype=np.float64,
            )
            if probs.shape != (len(MODES),) or not np.all(np.isfinite(probs)):
                # before the fusion: one NaN would stay in the HMM's state for good
                raise InferenceError(f"the classifier's output is not finite: {probs.tolist()}")
            cnn = int(np.argmax(probs))
            if self._gait:
                self._hand_gait(frame.device_time_ns if time_ns is None else time_ns)
            fused = self._push(frame.index, probs, pre.elevation_deg)
            done_ns = now_ns()  # the decision is out; features: display, recording, geometry cue
            hint = MODES[
                fused.decision if fused is not None and fused.decision is not None else cnn
            ]
            feats = (
                terrain_features(pre.profile, hint, self.params.max_forward_m, fit=fit)
                if pre.ok
                else None
            )
            tilt_offset = self.tilt.offset_deg
            if feats is not None:
                # corrected by what earlier frames taught, then taught by this one
                raw = feats.slope_deg
                feats.slope_deg = level_tilt.correct(self.tilt, raw)
                decided = (
                    MODES[fused.decision]
                    if fused is not None and fused.decision is not None
                    else None
                )
                self.tilt = level_tilt.update(
                    self.tilt,
                    decided,
                    feats.kind,
                    raw,
                    frame.device_time_ns if time_ns is None else time_ns,
                )
            if getattr(self.fusion, "uses_geometry", False):  # decides this frame next push
                if feats is None:
                    self.fusion.see_geometry(-1, -1)
                else:
                    self.fusion.see_geometry(
                        shown_mode(feats.kind, feats.direction), ground_ahead(feats.ahead_slope_deg)
                    )
        return FrameResult(
            index=frame.index,
            time_ns=frame.device_time_ns if time_ns is None else time_ns,
            host_time_ns=frame.host_time_ns,
            orientation=camera_orientation(quaternion, self.mounting),
            image=pre.image,
            cloud=pre.cloud,
            profile=pre.profile,
            flag=pre.flag,
            probabilities=probs,
            cnn_decision=cnn,
            fused=fused,
            features=_features_dict(feats, tilt_offset),
            done_ns=done_ns,
        )

    def _push(
        self, frame_index: int, probs: np.ndarray, elevation_deg: float = float("nan")
    ) -> FusionOutput | None:
        """Push to the fusion (with the camera's elevation, for a fusion that takes it: gait
        cues, the timing of steps); its output with push numbers turned into frame
        indices."""
        self._frame_of_push[self._pushed] = frame_index
        self._frame_of_push.pop(self._pushed - 256, None)
        self._pushed += 1
        if getattr(self.fusion, "takes_elevation", False):
            out = self.fusion.push(probs, elevation_deg)
        else:
            out = self.fusion.push(probs)
        if out is None:
            return None
        frame_of = self._frame_of_push.get
        return dataclasses.replace(
            out,
            frame=frame_of(out.frame) if out.frame is not None else None,
            posterior_frame=frame_of(out.posterior_frame)
            if out.posterior_frame is not None
            else None,
            voted_frame=frame_of(out.voted_frame) if out.voted_frame is not None else None,
        )


def record_result(
    recorder: Sink, frame: DepthFrame, r: FrameResult, decided_ns: int | None = None
) -> None:
    """Everything one frame produced, onto the recorder's topics (non-blocking writes).

    `decided_ns`: log time of the inference; live, when the decision was ready; offline
    (replay, synth) the frame's own receive time, so the file stays on one timeline.
    """
    recorder.write_frame(frame, r.time_ns)
    recorder.write_processed(
        r.index, r.time_ns, r.host_time_ns, r.cloud, r.image, r.orientation, r.flag
    )
    record_decisions(recorder, r, decided_ns)
    if frame.truth:
        record_truth(recorder, r.index, r.time_ns, frame.truth)


def record_truth(recorder: Sink, index: int, time_ns: int, truth: dict) -> None:
    """A frame's simulator truth onto /sim/truth, and the gait events it carries (the
    simulator's, since the frame before) onto /sim/gait."""
    gait = truth.get("gait") or ()
    if gait:
        truth = {k: v for k, v in truth.items() if k != "gait"}
    recorder.write_truth(index, time_ns, truth)
    for event in gait:
        recorder.write_gait(event)


def record_decisions(recorder: Sink, r: FrameResult, decided_ns: int | None = None) -> None:
    """The CNN, fused and terrain outputs of a frame (record_result without the sensor data);
    nothing for an undecided frame (its flag on /camera/preprocess says why)."""
    if not r.decided:
        return
    recorder.write_inference(
        r.index,
        r.time_ns,
        r.done_ns if decided_ns is None else decided_ns,
        r.probabilities,
        r.fused_dict(),
    )
    if r.features:
        recorder.write_features(r.index, r.time_ns, r.features)


def build_pipeline(config, classifier, params=None, mounting=None) -> Pipeline:
    """The pipeline `config` (capture.config.Config) describes, around `classifier`: its
    preprocessing and mounting (`params`, `mounting` when worked out already) and a fresh
    fusion. Copies: the pipeline keeps the parameters it started with."""
    return Pipeline(
        dataclasses.replace(params if params is not None else config.preprocess),
        classifier,
        config.fusion.make(),
        dataclasses.replace(mounting if mounting is not None else config.mounting),
    )


def software_metadata(config, pipeline: Pipeline | None, **extra) -> dict:
    """The "software" metadata record: which walkcap, model, fusion and preprocessing made a
    recording's decisions (None: no pipeline built yet); `extra` entries added (scheduling,
    what a replay replays)."""
    from capture import __version__
    from capture.recording.metadata import SoftwareRecord
    from capture.recording.topics import jsonable
    from inference.preprocess import metadata as preprocess_metadata

    f = config.fusion
    preprocess = preprocess_metadata(pipeline.params, pipeline.mounting) if pipeline else {}
    return SoftwareRecord.build(
        walkcap_version=__version__,
        model_path=config.model.path or "bundled",
        model_hash=model_hash(pipeline.classifier if pipeline else None),
        fusion_method=f.method,
        fusion_window=f.window,
        fusion_vote_delay=f.vote_delay,
        fusion_transition=jsonable(f.transition),
        preprocess=jsonable(preprocess),
        **extra,
    ).to_dict()


def model_hash(classifier) -> str:
    """The weights' SHA-256 from the model's metadata: which model made these decisions."""
    return str((getattr(classifier, "metadata", None) or {}).get("weights_sha256", ""))


def _features_dict(feats, tilt_offset_deg: float = 0.0) -> dict:
    if feats is None:
        return {}
    values = ((f.name, getattr(feats, f.name)) for f in dataclasses.fields(feats))
    # the scalars only; asdict() would deep-copy the segment list first
    out = {k: v for k, v in values if v is None or isinstance(v, (int, float, str, bool))}
    out["tilt_offset_deg"] = tilt_offset_deg  # taken off slope_deg (inference.level_tilt)
    return out
