"""The terrain-walk simulator: what a leg-worn ToF camera sees while its wearer walks a course.

`Simulator(course).render(t)` gives the depth frame at t seconds into the walk, with the
ground truth in `frame.truth`:
- "mode": the terrain the classifier's 100 x 100 image shows, as a person labelling that
  image would name it (the paper's reference: "labeled manually based on the captured
  binary images"). The frame's rays are cast without the error images drawn in (a foot, an
  occlusion or blur hides the terrain, it does not change it), leveled with the true
  orientation, kept in the classifier's corridor (|y| <= 5 cm, up to 2.5 m ahead) and
  cropped as the authors rasterise: 0.99 m forward from the nearest point, then 0.99 m up
  from the lowest point left. The mode whose terrain fills most of the image's 1 cm
  columns is the truth ("view_share": its share of the columns holding terrain). An image
  holding no terrain (sky, walls only) takes the segment a look-ahead distance in front of
  the camera (LOOKAHEAD_M per terrain under the camera, blended over 1 m), what the walk
  leads into.
- "locomotion_mode": the walker's own mode, the terrain under its hip. It leads the image's
  mode by the look-ahead of the camera: near a transition the image already shows the
  next terrain while the walker is still on the last.
- "camera_pose": camera -> world, 4x4 nested list; "thigh_quaternion": [w, x, y, z],
  IMU (thigh) -> world, without sensor noise; "segment": index of the segment the image
  truth names (the look-ahead segment, or the nearest segment of that mode in view);
  "error": "" or the kind of error image ("swing_blur", "sky", "foot", "occlusion",
  "object");
  "gait" (added by whoever knows the frame before, the mock camera and `walkcap synth`): the
  GaitEvents of the walk since the frame before (`gait_truth`), source "simulator", each
  with the mode of the terrain under that foot.

Every frame is a pure function of (course, walker parameters, seed, t): deterministic.
"""

from __future__ import annotations

import numpy as np

from devices import clock
from devices.errors import DeviceConfigError
from devices.frames import MODES, CameraGeometry, DepthFrame, GaitEvent
from devices.simulator.course import Course, make_course
from devices.simulator.render import (
    NOTHING,
    Hits,
    TerrainScene,
    ToFParams,
    ToFSensor,
    blend_swing,
    draw_foot,
    draw_object,
    draw_occlusion,
)
from devices.simulator.walk import GRID_M, Walk, smooth

# Look-ahead (m) of the truth rule's fallback per terrain under the camera (module doc).
LOOKAHEAD_M = {"LG": 0.75, "US": 0.7, "DS": 1.1, "UR": 0.75, "DR": 0.6}
# The classifier's image (inference.preprocess defaults): a corridor 0.1 m wide, 2.5 m
# ahead and -2..1 m high around the camera; 100 cells of 1 cm, the minimum in cell 1.
CORRIDOR_M, IMAGE_FORWARD_M, IMAGE_BELOW_M, IMAGE_ABOVE_M = 0.1, 2.5, 2.0, 1.0
CELL_M, IMAGE_CELLS = 0.01, 100
FILL_CELLS = 8  # gaps between a terrain's points it still covers (_covered)


# The walker's parameters that a [simulator] section sets (devices.config.SimulatorConfig).
WALKER_KEYS = ("speed_mps", "cadence_spm", "camera_height_m", "camera_tilt_deg")


def draw_walker(rng: np.random.Generator) -> dict:
    """A walker of its own (WALKER_KEYS): subjects and mountings differ in speed, cadence,
    thigh length and strap angle."""
    return {
        "speed_mps": float(rng.uniform(0.85, 1.35)),
        "cadence_spm": float(rng.uniform(90.0, 120.0)),
        "camera_height_m": float(rng.uniform(0.48, 0.62)),
        "camera_tilt_deg": float(rng.uniform(28.0, 42.0)),
    }


class Simulator:
    def __init__(
        self,
        course: Course,
        *,
        geometry: CameraGeometry = CameraGeometry(),
        seed: int = 0,
        error_rate: float | None = None,
        cast_threads: int = 0,
        fps: float = 15.0,
        **walker,
    ) -> None:
        """`fps`: the camera's frame rate, which picks its use case and so its depth noise;
        `error_rate` scales the error images' rates (devices.simulator.walk's, which differ
        indoors and outdoors; default 1);
        `cast_threads`: threads per ray cast (0: all cores); `walker`: the Walk's
        parameters (speed_mps, cadence_spm, camera_height_m, camera_tilt_deg,
        camera_forward_m: the camera's distance in front of the thigh's axis, events: an
        ErrorEvent list that replaces the error images' random schedule, e.g. [] for none)."""
        if error_rate is None:
            error_rate = 1.0
        self.course = course
        self.geometry = geometry
        self.seed = seed
        self.walk = Walk(course, error_rate=error_rate, seed=seed, **walker)
        self.sensor = ToFSensor(geometry, ToFParams.for_course(course, fps), seed)
        self.scene = TerrainScene(course, self.sensor.rays_cam, cast_threads)
        x = np.arange(-1.0, course.length_m + 1.0, GRID_M)
        ahead = np.array([LOOKAHEAD_M[m] for m in course.modes])[course.segment_index(x)]
        self._lookahead = (x, smooth(ahead, 1.0))

    @classmethod
    def from_config(
        cls,
        config,
        geometry: CameraGeometry | None = None,
        cast_threads: int = 0,
        fps: float = 15.0,
    ) -> Simulator:
        """From a devices.config.SimulatorConfig (course preset, seed, walker, camera)."""
        try:
            course = make_course(config.course, config.seed)
            return cls(
                course,
                geometry=geometry or CameraGeometry(),
                seed=config.seed,
                cast_threads=cast_threads,
                fps=fps,
                **{k: getattr(config, k) for k in WALKER_KEYS},
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

    def image_truth(self, hits: Hits, pose: np.ndarray) -> tuple[int, float]:
        """(segment, share of the image's terrain columns) of the terrain the classifier's
        image shows, from a cast without error images (module doc)."""
        seen = (hits.label != NOTHING) & (hits.t <= self.geometry.max_range_m)
        rotation = pose[:3, :3]
        axis = pose[:3, 2]
        if np.hypot(axis[0], axis[1]) < 0.2:  # looking straight down: the image's top
            axis = -pose[:3, 1]
        heading = np.arctan2(axis[1], axis[0])
        c, s = np.cos(heading), np.sin(heading)
        # Camera -> point along the heading (x), across it (y) and up (z). Across first, on
        # every ray: the corridor keeps about one ray in twenty.
        across = rotation.T @ np.array([-s, c, 0.0])
        t = np.where(seen, hits.t, np.float32(0.0))
        y = t * (self.sensor.rays_cam @ across)
        near = np.flatnonzero(seen & (np.abs(y) <= CORRIDOR_M / 2))
        rays, t = self.sensor.rays_cam[near].astype(np.float64), t[near, None]
        offset = t * (rays @ rotation.T)  # world frame
        x = offset[:, 0] * c + offset[:, 1] * s
        z = offset[:, 2]
        inside = (x >= 0) & (x <= IMAGE_FORWARD_M) & (z >= -IMAGE_BELOW_M) & (z <= IMAGE_ABOVE_M)
        x, z, label = x[inside], z[inside], hits.label[near][inside]
        along = pose[0, 3] + offset[inside, 0]  # course position of each point
        if len(x):  # the authors' crop: x first, then z from the lowest point left
            col = np.floor((x - x.min()) / CELL_M).astype(np.int64) + 1
            keep = col < IMAGE_CELLS
            col, z, label, world_x = col[keep], z[keep], label[keep], along[keep]
            keep = np.floor((z - z.min()) / CELL_M) + 1 < IMAGE_CELLS
            col, label, world_x = col[keep], label[keep], world_x[keep]
            terrain = label >= 0
            col, label, world_x = col[terrain], label[terrain], world_x[terrain]
        if not len(x) or not len(col):
            return self.lookahead_segment(0.0, pose), 0.0
        counts = np.array([_covered(col[label == m]) for m in range(len(MODES))])
        mode = int(np.argmax(counts))
        share = float(counts[mode] / counts.sum())
        # the segment: the look-ahead one when it has that mode, else the nearest in view
        ahead = self.lookahead_segment(0.0, pose)
        if MODES.index(self.course.segments[ahead].mode) == mode:
            return ahead, share
        segments = self.course.segment_index(world_x[label == mode])
        # a riser lies on its segment's start: rounding may put it on the one before
        named = [i for i in np.unique(segments) if self.course.segments[i].mode == MODES[mode]]
        return (int(named[0]) if named else ahead), share

    def truth_at(self, t_s: float) -> tuple[int, float]:
        """image_truth of the frame at t_s: (segment, share), without rendering it."""
        pose = self.walk.camera_pose(t_s)
        return self.image_truth(self.scene.cast(pose), pose)

    def locomotion_mode(self, t_s: float) -> str:
        """The walker's own mode at t_s: the terrain under its hip."""
        return self.course.mode_at(float(self.walk.position(t_s)))

    def gait_truth(self, t0_s: float, t1_s: float, t1_ns: int) -> list[GaitEvent]:
        """The walk's gait events with t0_s < time <= t1_s (walk seconds), stamped on the
        clock that reads t1_ns at t1_s (a frame's device time), with the mode of the
        terrain under that foot."""
        return [
            GaitEvent(t1_ns - clock.to_ns(t1_s - t), event, "simulator", self.course.mode_at(x))
            for t, event, x in self.walk.gait_events(t0_s, t1_s)
        ]

    def render(self, t_s: float, index: int = 0) -> DepthFrame:
        """The frame at t_s seconds into the walk; times are t_s on the walk's own clock."""
        quaternion, pose = self.walk.pose(t_s)
        rng = np.random.default_rng([self.seed, int(round(max(t_s, 0.0) * 1e6))])
        hits = self.scene.cast(pose)
        segment, view_share = self.image_truth(hits, pose)
        mode = self.course.segments[segment].mode
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
            elif event.kind == "object":  # above the ground the camera looks at
                ground = float(self.course.height_at(np.array([pose[0, 3] + 0.4]))[0])
                draw_object(hits, self.sensor.rays_cam, pose, ground, event.strength, shape_rng)
        xyz, confidence, gray = self.sensor.apply(hits, rng, noise_scale)
        truth = {
            "mode": mode,
            "view_share": view_share,
            "locomotion_mode": self.locomotion_mode(t_s),
            "camera_pose": pose.tolist(),
            "thigh_quaternion": quaternion.tolist(),
            "segment": segment,
            "error": event.kind if event is not None else "",
        }
        t_ns = clock.to_ns(t_s)
        return DepthFrame(index, t_ns, t_ns, xyz, confidence, gray, self.geometry, truth)


def _covered(columns: np.ndarray) -> int:
    """Image columns a terrain covers: the ones its points fall in, and gaps of less than
    FILL_CELLS between them (far terrain's pixel rows land a few centimetres apart, which
    the image's noise fills; an occluded stretch behind a nosing stays a gap)."""
    cells = np.unique(columns)
    if not len(cells):
        return 0
    gaps = np.diff(cells)
    return int(len(cells) + np.sum(np.where(gaps <= FILL_CELLS, gaps - 1, 0)))
