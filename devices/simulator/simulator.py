"""The terrain-walk simulator: what a leg-worn ToF camera sees while its wearer walks a course.

`Simulator(course).render(t)` gives the depth frame at t seconds into the walk, with the
ground truth in `frame.truth`:
- "mode": the mode of the terrain the camera looks at. Every 1/30 s of the walk (VOTE_DT_S,
  whatever the frame rate) votes for the course segment covering most (> half) of the
  terrain seen in the central image columns (the classifier's corridor) within 1 m of the
  nearest visible point (and 2.5 m of the camera, the image's crop), measured as the
  classifier's binary image shows it: 1 cm columns along the forward distance, not pixels
  (the near terrain has many more pixels per metre; counting pixels would switch the truth
  up to a second after the image is mostly the new terrain). Cast without the error
  images drawn in (a foot, an occlusion or
  blur hides the terrain, it does not change it); a moment whose corridor is less than
  MIN_SEEN_SHARE terrain (sky, walls) votes for the fallback, the segment a look-ahead
  distance in front of the camera (LOOKAHEAD_M per terrain under the camera, blended over
  1 m: where the 1 m window lies on average). The truth is the sequence of segments
  that never goes back (the camera only moves forward) and disagrees with the fewest
  votes (`switch_once`): the mode switches once per transition, where the view has
  mostly moved on to the new terrain, not at a single glance ahead nor back and forth
  while the swinging thigh looks back at the old one - as an operator would key it.
- "view_mode": the mode covering most (1 cm columns, as above) of the terrain actually
  seen in the central image columns of this very frame's window; "" when no terrain
  is seen; "view_share": the share of that terrain that has the true mode. They differ
  from "mode" only around transitions, on frames glancing at the other terrain, and on
  frames seeing no terrain.
- "camera_pose": camera -> world, 4x4 nested list; "thigh_quaternion": [w, x, y, z],
  IMU (thigh) -> world, without sensor noise; "segment": index of the mode's segment;
  "error": "" or the kind of error image ("swing_blur", "sky", "foot", "occlusion").

Every frame is a pure function of (course, walker parameters, seed, t): deterministic.
"""

from __future__ import annotations

import numpy as np

from devices.errors import DeviceConfigError
from devices.frames import MODES, CameraGeometry, DepthFrame
from devices.simulator.course import Course, make_course
from devices.simulator.render import (
    TerrainScene,
    ToFParams,
    ToFSensor,
    blend_swing,
    draw_foot,
    draw_occlusion,
)
from devices.simulator.walk import GRID_M, Walk, smooth

# Look-ahead (m) of the truth rule's fallback per terrain under the camera (module doc).
LOOKAHEAD_M = {"LG": 0.75, "US": 0.7, "DS": 1.1, "UR": 0.75, "DR": 0.6}
CORRIDOR_PX = 9  # half-width of the central columns (~0.1 m at 1 m, the classifier's corridor)
VOTE_DT_S = 1 / 30  # the truth rule's time step, independent of the frame rate asked for
MIN_SEEN_SHARE = 0.25  # share of the corridor that must be terrain for a moment to vote
OUTDOOR_ERROR_RATE = 1.6  # error images outdoors relative to indoors
# The classifier's image (inference.preprocess): 1 cm columns over 1 m from the nearest
# corridor point, cropped 2.5 m ahead of the camera (PreprocessParams.max_forward_m).
CELL_M, IMAGE_M, IMAGE_FORWARD_M = 0.01, 1.0, 2.5


class Simulator:
    def __init__(
        self,
        course: Course,
        *,
        geometry: CameraGeometry = CameraGeometry(),
        speed_mps: float = 1.1,
        cadence_spm: float = 105.0,
        camera_height_m: float = 0.55,
        camera_tilt_deg: float = 35.0,
        seed: int = 0,
        camera_offset_m: float = 0.07,
        error_rate: float | None = None,
        events=None,
        cast_threads: int = 0,
    ) -> None:
        """`camera_offset_m`: the camera's distance in front of the thigh's axis;
        `error_rate` scales the error images (default 1 indoors, 1.6 outdoors); `events`
        (ErrorEvent list) replaces their random schedule, e.g. [] for none; `cast_threads`:
        threads per ray cast (0: all cores)."""
        if error_rate is None:
            error_rate = OUTDOOR_ERROR_RATE if course.outdoor else 1.0
        self.course = course
        self.geometry = geometry
        self.seed = seed
        self.walk = Walk(
            course,
            speed_mps=speed_mps,
            cadence_spm=cadence_spm,
            camera_height_m=camera_height_m,
            camera_tilt_deg=camera_tilt_deg,
            camera_forward_m=camera_offset_m,
            error_rate=error_rate,
            seed=seed,
            events=events,
        )
        self.sensor = ToFSensor(geometry, ToFParams.for_course(course), seed)
        self.scene = TerrainScene(course, self.sensor.rays_cam, cast_threads)
        c = int(round(geometry.cx))
        cols = np.arange(max(0, c - CORRIDOR_PX), min(geometry.width, c + CORRIDOR_PX + 1))
        self._corridor = (np.arange(geometry.height)[:, None] * geometry.width + cols).ravel()
        x = np.arange(-1.0, course.length_m + 1.0, GRID_M)
        ahead = np.array([LOOKAHEAD_M[m] for m in course.modes])[course.segment_index(x)]
        self._lookahead = (x, smooth(ahead, 1.0))
        self._corridor_scene = TerrainScene(course, self.sensor.rays_cam[self._corridor])
        self._truth: np.ndarray | None = None  # truth segment per VOTE_DT_S, when first asked

    @classmethod
    def from_config(
        cls, config, geometry: CameraGeometry | None = None, cast_threads: int = 0
    ) -> Simulator:
        """From a devices.config.SimulatorConfig (course preset, seed, walker, camera)."""
        try:
            course = make_course(config.course, config.seed)
            return cls(
                course,
                geometry=geometry or CameraGeometry(),
                speed_mps=config.speed_mps,
                cadence_spm=config.cadence_spm,
                camera_height_m=config.camera_height_m,
                camera_tilt_deg=config.camera_tilt_deg,
                seed=config.seed,
                cast_threads=cast_threads,
            )
        except ValueError as e:
            raise DeviceConfigError(f"simulator: {e}") from None

    @property
    def duration_s(self) -> float:
        return self.walk.duration_s

    def thigh_quaternion(self, t_s: float) -> np.ndarray:
        """IMU (thigh) -> world orientation at t_s, [w, x, y, z], without sensor noise."""
        return self.walk.thigh_quaternion(t_s)

    def camera_pose(self, t_s: float) -> np.ndarray:
        return self.walk.camera_pose(t_s)

    def lookahead_m(self, x: float) -> float:
        """Look-ahead of the truth rule for a camera at course position x."""
        return float(np.interp(x, *self._lookahead))

    def lookahead_segment(self, t_s: float, pose: np.ndarray | None = None) -> int:
        """The fallback: the segment a look-ahead distance in front of the camera at t_s."""
        x = (self.walk.camera_pose(t_s) if pose is None else pose)[0, 3]
        return int(self.course.segment_index(x + self.lookahead_m(x)))

    def view_segment(self, t_s: float) -> int | None:
        """The segment covering most of the terrain in the corridor window at t_s (no error
        image drawn in); None when no segment has a majority; the look-ahead segment when
        under MIN_SEEN_SHARE of the corridor is terrain."""
        pose = self.walk.camera_pose(t_s)
        hits = self._corridor_scene.cast(pose)
        seen = (hits.label >= 0) & (hits.t <= self.geometry.max_range_m)
        if seen.mean() < MIN_SEEN_SHARE:
            return self.lookahead_segment(t_s, pose)
        rays = self.sensor.rays_cam[self._corridor[seen]]
        forward = hits.t[seen] * (rays @ pose[0, :3])
        window = _image_window(forward)
        counts = _cover(
            pose[0, 3] + forward[window],
            forward[window],
            self.course.segment_index,
            len(self.course.segments),
        )
        best = int(np.argmax(counts))
        return best if counts[best] * 2 > counts.sum() else None

    def truth_segment(self, t_s: float, pose: np.ndarray | None = None) -> int:
        """Index of the segment whose mode is the ground truth at t_s (see module doc).
        `pose` is accepted for compatibility; the rule depends on t_s only."""
        if self._truth is None:  # the whole walk's votes, once
            n = int(np.floor(self.duration_s / VOTE_DT_S)) + 1
            votes = [self.view_segment(k * VOTE_DT_S) for k in range(n)]
            self._truth = switch_once(votes, len(self.course.segments))
        k = int(np.clip(np.floor(t_s / VOTE_DT_S + 1e-9), 0, len(self._truth) - 1))
        return int(self._truth[k])

    def render(self, t_s: float, index: int = 0) -> DepthFrame:
        """The frame at t_s seconds into the walk; times are t_s on the walk's own clock."""
        quaternion, pose = self.walk.pose(t_s)
        rng = np.random.default_rng([self.seed, int(round(max(t_s, 0.0) * 1e6))])
        hits = self.scene.cast(pose)
        segment = self.truth_segment(t_s, pose)
        mode = self.course.segments[segment].mode
        view_mode, view_share = self._view(hits, pose, mode)
        event = self.walk.event_at(t_s)
        noise_scale = 1.0
        if event is not None:
            shape_rng = np.random.default_rng(event.seed)  # one shape for the whole event
            if event.kind == "swing_blur":
                delta = self.walk.flexion_rate(t_s) * (0.05 + 0.05 * event.strength)
                other = self.scene.cast(self.walk.camera_pose(t_s, extra_flexion=delta))
                hits = blend_swing(hits, other, rng)
                noise_scale = 2.0
            elif event.kind == "foot":
                progress = (t_s - event.t0) / (event.t1 - event.t0)
                draw_foot(hits, self.geometry, progress, event.strength, shape_rng)
            elif event.kind == "occlusion":
                draw_occlusion(hits, self.sensor.rays_cam, self.geometry, event.strength, shape_rng)
        xyz, confidence, gray = self.sensor.apply(hits, rng, noise_scale)
        truth = {
            "mode": mode,
            "view_mode": view_mode,
            "view_share": view_share,
            "camera_pose": pose.tolist(),
            "thigh_quaternion": quaternion.tolist(),
            "segment": segment,
            "error": event.kind if event is not None else "",
        }
        t_ns = int(round(t_s * 1e9))
        return DepthFrame(index, t_ns, t_ns, xyz, confidence, gray, self.geometry, truth)

    def _view(self, hits, pose: np.ndarray, mode: str) -> tuple[str, float]:
        """(mode seen most, share of the true mode) in the classifier's corridor window."""
        label = hits.label[self._corridor]
        t = hits.t[self._corridor]
        seen = (label >= 0) & (t <= self.geometry.max_range_m)
        if not seen.any():
            return "", 0.0
        forward = t[seen] * (self.sensor.rays_cam[self._corridor[seen]] @ pose[0, :3])
        window = _image_window(forward)
        counts = _cover(label[seen][window], forward[window], lambda m: m, len(MODES))
        return MODES[int(np.argmax(counts))], float(counts[MODES.index(mode)] / counts.sum())


def _image_window(forward: np.ndarray) -> np.ndarray:
    """Mask of the points the classifier's image holds: within IMAGE_M of the nearest one,
    and no farther than IMAGE_FORWARD_M ahead while any point is that near."""
    near = forward <= forward.min() + IMAGE_M
    inside = near & (forward <= IMAGE_FORWARD_M)
    return inside if inside.any() else near


def _cover(keys: np.ndarray, forward: np.ndarray, index, count: int) -> np.ndarray:
    """How much of the image each key (segment or mode) covers: the number of CELL_M
    columns along the forward distance it occupies, as the binary image shows it (a
    column of dense near pixels counts no more than a column of sparse far ones)."""
    ids = np.asarray(index(keys), np.int64)
    cells = np.floor(forward / CELL_M).astype(np.int64)
    cells -= cells.min()
    occupied = np.unique(ids * (int(cells.max()) + 1) + cells) // (int(cells.max()) + 1)
    return np.bincount(occupied, minlength=count)


def switch_once(votes: list[int | None], segments: int) -> np.ndarray:
    """The non-decreasing segment sequence that disagrees with the fewest votes (None: no
    vote); on a tie the switch comes at the earliest moment. Dynamic programming over
    (moment, segment): cost of the best sequence ending there."""
    n = len(votes)
    cost = np.zeros(segments)
    best_before = np.empty((n, segments), np.int64)  # best previous segment <= s
    index = np.arange(segments)
    for k, vote in enumerate(votes):
        # running minimum over s' <= s, the largest s' on a tie (the earliest switch)
        running = np.minimum.accumulate(cost)
        last_min = np.maximum.accumulate(np.where(cost == running, index, 0))
        best_before[k] = last_min
        cost = running + (0.0 if vote is None else (index != vote))
    path = np.empty(n, np.int64)
    s = int(np.flatnonzero(cost == cost.min())[-1])
    for k in range(n - 1, -1, -1):
        path[k] = s
        s = int(best_before[k][s])
    return path
