"""The walker: where the thigh, and so the IMU and the camera on it, is at any time.

A walker crosses the course at a speed and cadence that the terrain changes (slower on
stairs). The thigh swings with the gait: its flexion angle is mean + amplitude * sin(phase),
8 +- 19 degrees on level ground (-11..+27, within the 35-45 degrees of thigh motion of
normal walking), more flexion going up, less going down, each walker's swing scaled by
0.9-1.1. The amplitude is the simulator's calibration to the paper: the swinging thigh makes
the view glance back at the terrain just left and ahead at the next, so it sets how many
frames near a transition show another mode than the truth's single switch. At 24 degrees
neither the CNN (93.3 %) nor an oracle answering each view's mode (94.4 %) reaches the
paper's 94.8 % indoors; at 19 the oracle scores 96.1 % and the CNN lands in the paper's
regime (README, "Analysis and training"). The IMU
body frame is the thigh's (x forward, y left, z up when standing), so its orientation is
roll, pitch = -flexion, yaw (flexion lifts the knee and tilts the camera up). The camera
sits on the front of the thigh, `camera_height_m` above the ground when standing, tilted
down by `camera_tilt_deg`: camera -> world = thigh -> world @ mounting_matrix(0, tilt, 0).

Error images (the paper: "the camera may capture error images when the leg swings
quickly") are scheduled per stride at the gait phase where they happen:
- swing_blur: at peak angular velocity; the image mixes two poses (ToF motion artefacts);
- sky: a high knee lift (extra 25-35 degrees of flexion) at peak flexion;
- foot: the other foot passing in front of the camera at full extension;
- occlusion: something close in front of the lens (a hand, a bag, a passer-by), any time;
- object: something close ahead whose flat face fills the view (the other thigh, a bag, a
  door, a person passing), any time: it looks like a terrain that is not there.

Gait events of the instrumented leg (the thigh that carries the sensors) follow its swing:
heel contact 5 % of a stride after the thigh's peak flexion (it peaks late in swing and
extends a little before the foot lands; a high knee lift moves the peak, and the contact
with it), toe off STANCE_SHARE of a stride after the stride's own contact (stance takes
about 60 % of the cycle, swing 40 %: Perry and Burnfield, Gait Analysis, 2010; a knee lift
leaves that rhythm). Each carries the mode of the terrain under that foot: the foot lands
where the hip is at mid-stance (a quarter stride after heel contact, the stance leg under
the hip) and stays put until toe off. A walk starts in mid-swing (phase 0) from standing
and ends where a stride ends; no event falls outside it.

Everything is precomputed on a 1 cm grid along the course at construction, so any time
can be asked in any order (the camera and the IMU emulator ask independently), and the
same seed gives the same walk.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from devices.rotations import mounting_matrix, quat_from_euler
from devices.simulator.course import Course

# Per mode: speed factor, cadence factor, mean flexion (deg), flexion amplitude (deg).
GAIT = {
    "LG": (1.0, 1.0, 8.0, 19.0),
    "US": (0.5, 0.85, 18.0, 18.0),
    "DS": (0.5, 0.85, 2.0, 13.0),
    "UR": (0.9, 0.95, 13.0, 19.0),
    "DR": (0.9, 0.95, 0.0, 16.0),
}
ERROR_KINDS = ("swing_blur", "sky", "foot", "occlusion", "object")
# Per kind: probability per stride indoors and outdoors, gait phase (rad; None = any),
# duration (s). A real classifier's errors (docs/simulator.md, "Classifier errors"): the
# paper's CNN errs on 5.2 % of frames indoors and 9.3 % outdoors, mostly in runs (a vote
# over 3 frames removes only 29-32 % of them), mostly unsure ("the decisions from error
# images are usually less credible"), yet runs that switch Algorithm 1 come 2.8 a minute
# indoors and outdoors (5.65 and 5.76 spurious switches, in and back), and three in four of
# them indoors outlast a filter that needs three sure frames (steady: 4.21 a minute). The
# kinds: swing_blur, sky, foot and occlusion hide the terrain (an unsure read: the run's
# length is the error image's), object shows a terrain that is not there (a sure read).
# The rates are set so that the simulated sessions show those figures (design sessions
# 960000-960011 and 970000-970011); outdoors, sunlight and clutter make more of every
# kind but objects (a person passing is as likely indoors).
ERROR_SCHEDULE = {
    "swing_blur": (0.30, 0.35, 0.0, (0.06, 0.14)),
    "sky": (0.03, 0.06, np.pi / 2, (0.20, 0.35)),
    "foot": (0.15, 0.30, 3 * np.pi / 2, (0.12, 0.28)),
    "occlusion": (0.20, 0.28, None, (0.12, 0.40)),
    "object": (0.12, 0.08, None, (0.20, 0.60)),
}
GRID_M = 0.01
# Gait events on the phase (flexion = mean + amp * sin(phase), peak flexion at pi / 2 but for
# a high knee lift): heel contact 5 % of a stride after peak flexion, toe off 60 % of a
# stride after heel contact.
HEEL_CONTACT_PHASE = np.pi / 2 + 0.05 * 2 * np.pi
STANCE_SHARE = 0.60


# Mid-stance, the hip above the foot: a quarter stride after heel contact, of either leg.
MID_STANCE_PHASE = HEEL_CONTACT_PHASE + np.pi / 2
# The strides over which a walker adjusts its steps to put a foot on the first tread.
APPROACH_M = 1.5
BLEND_M = 0.3  # the stride's rate changes over this much either side of the stairs


def stairs_footing(course: Course, x: np.ndarray, phase: np.ndarray) -> np.ndarray:
    """The walk's phase along the course (`phase` at positions `x`) with the steps a walker
    takes on stairs: one step a tread, each foot in the middle of its tread (mid-stance, the
    hip above the foot, at the tread's centre), the strides before the stairs lengthened or
    shortened (by at most a quarter stride over APPROACH_M) so that the first foot lands on
    the first tread, never across a riser or a nosing (stair gait places the whole foot on
    each tread). Past the stairs the walk's own rhythm resumes. The stride's rate changes
    smoothly, over BLEND_M either side, so the thigh's rate of turn never jumps."""
    for seg in course.segments:
        if seg.mode not in ("US", "DS") or seg.steps < 1:
            continue
        first = seg.x0 + 0.5 * seg.tread_m  # the centre of the first tread
        last = seg.x0 + (seg.steps - 0.5) * seg.tread_m  # of the floor the stairs lead to
        if first - APPROACH_M <= x[0] or last + BLEND_M >= x[-1]:
            continue
        on = np.clip((x - (first - BLEND_M)) / BLEND_M, 0.0, 1.0) * np.clip(
            (last + BLEND_M - x) / BLEND_M, 0.0, 1.0
        )
        on = on * on * (3 - 2 * on)
        rate = (1 - on) * np.gradient(phase, x) + on * (np.pi / seg.tread_m)
        steps = 0.5 * (rate[1:] + rate[:-1]) * np.diff(x)
        phase = phase[0] + np.concatenate([[0.0], np.cumsum(steps)])
        natural = float(np.interp(first, x, phase))
        # the nearest phase at which a foot is at mid-stance (either leg: every half stride)
        target = MID_STANCE_PHASE + np.pi * np.round((natural - MID_STANCE_PHASE) / np.pi)
        ramp = np.clip((x - (first - APPROACH_M)) / APPROACH_M, 0.0, 1.0)
        phase = phase + (target - natural) * ramp * ramp * (3 - 2 * ramp)
    return phase


@dataclass(frozen=True)
class ErrorEvent:
    kind: str  # one of ERROR_KINDS
    t0: float  # seconds since the start of the walk
    t1: float
    strength: float  # kind-specific size in [0, 1)
    seed: int  # for the event's own random shape


def _euler_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """quat_to_matrix(quat_from_euler(roll, pitch, yaw)) for scalars, without the overhead:
    Rz(yaw) @ Ry(pitch) @ Rx(roll)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def smooth(values: np.ndarray, window_m: float) -> np.ndarray:
    """Moving average over window_m of values sampled every GRID_M (ends held)."""
    n = max(1, int(round(window_m / GRID_M)))
    padded = np.pad(values, (n, n), mode="edge")
    return np.convolve(padded, np.ones(n) / n, mode="same")[n:-n]


class Walk:
    """A walker on a course; every method is a pure function of time (seconds)."""

    def __init__(
        self,
        course: Course,
        *,
        speed_mps: float = 1.1,
        cadence_spm: float = 105.0,
        camera_height_m: float = 0.55,
        camera_tilt_deg: float = 35.0,
        hip_height_m: float = 0.90,
        camera_forward_m: float = 0.07,
        hip_lateral_m: float = -0.10,
        error_rate: float = 1.0,
        seed: int = 0,
        events: list[ErrorEvent] | tuple[ErrorEvent, ...] | None = None,
    ) -> None:
        if not 0.1 < camera_height_m < hip_height_m:
            raise ValueError(
                f"camera height {camera_height_m} m must be between 0.1 m and "
                f"the hip ({hip_height_m} m)"
            )
        if speed_mps <= 0 or cadence_spm <= 0:
            raise ValueError("speed and cadence must be positive")
        self.course = course
        self.camera_tilt_deg = camera_tilt_deg
        self.hip_height_m = hip_height_m
        self.hip_lateral_m = hip_lateral_m
        self.mounting = mounting_matrix(0.0, camera_tilt_deg, 0.0)
        # the camera on the thigh, relative to the hip joint, in the thigh frame
        self.camera_offset = np.array([camera_forward_m, 0.0, camera_height_m - hip_height_m])
        rng = np.random.default_rng([seed, 7, int(course.outdoor)])
        self.amp_scale = float(rng.uniform(0.9, 1.1))
        self.mean_offset = float(np.radians(rng.uniform(-2.0, 2.0)))
        self.roll_offset = float(np.radians(rng.uniform(-2.0, 2.0)))
        self.wander = [
            (float(rng.uniform(5, 12)), float(rng.uniform(0, 2 * np.pi))) for _ in range(2)
        ]

        self.start_x = min(0.5, course.length_m / 4)
        self.end_x = course.length_m - min(1.5, course.length_m / 4)
        x = np.arange(self.start_x, self.end_x + GRID_M / 2, GRID_M)
        params = np.array([GAIT[m] for m in course.modes])[course.segment_index(x)]
        speed = speed_mps * smooth(params[:, 0], 0.6)
        stride_hz = cadence_spm / 120.0 * smooth(params[:, 1], 0.6)
        phase = np.concatenate([[0.0], np.cumsum(2 * np.pi * stride_hz[:-1] * GRID_M / speed[:-1])])
        phase = stairs_footing(course, x, phase)
        # the cadence is the walker's, the steps the footing's: time follows from both
        # (on stairs a tread a step; elsewhere the walker's own speed)
        rate = 0.5 * (stride_hz[1:] + stride_hz[:-1])
        t = np.concatenate([[0.0], np.cumsum(np.diff(phase) / (2 * np.pi * rate))])
        # The walk ends where a stride ends, as it began: the thigh's last pose is its first
        # (a looping course or a camera started again begins the walk anew, and the IMU
        # would feel any jump between the two as a rate of turn of tens of rad/s).
        strides = max(1.0, np.floor(phase[-1] / (2 * np.pi)))
        target = strides * 2 * np.pi
        end = min(len(x) - 1, int(np.searchsorted(phase, target)))
        x, t, phase, params = x[: end + 1], t[: end + 1], phase[: end + 1], params[: end + 1]
        if end > 0 and phase[-1] > target:  # the last point where the stride ends exactly
            f = (target - phase[-2]) / (phase[-1] - phase[-2])
            x, t, phase = x.copy(), t.copy(), phase.copy()
            x[-1] = x[-2] + f * (x[-1] - x[-2])
            t[-1] = t[-2] + f * (t[-1] - t[-2])
            phase[-1] = target
        self.end_x = float(x[-1])
        self._x, self._t, self._phase = x, t, phase
        self._flex_mean = np.radians(smooth(params[:, 2], 0.6)) + self.mean_offset
        self._flex_amp = np.radians(smooth(params[:, 3], 0.6)) * self.amp_scale
        self._ground = smooth(course.height_at(x), 0.6)
        self.duration_s = float(self._t[-1])
        # the heading's slow wander, whole cycles over the walk for the same reason
        self.wander = [
            (self.duration_s / max(1.0, round(self.duration_s / period)), offset)
            for period, offset in self.wander
        ]
        if events is None:
            events = self._schedule_errors(rng, error_rate)
        self.events = tuple(sorted(events, key=lambda e: e.t0))
        self._event_t0 = np.array([e.t0 for e in self.events])
        self._sky = [e for e in self.events if e.kind == "sky"]
        self._gait = self._gait_events()

    def _strides(self) -> int:
        """Whole strides in the walk (it ends where a stride ends: its phase a multiple of
        2 pi, to rounding)."""
        return int(self._phase[-1] / (2 * np.pi) + 1e-6)

    # ---- gait events ----------------------------------------------------------------------

    def _gait_events(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(times s, kinds 0 = heel contact / 1 = toe off, foot positions m), in time order."""
        full = 2 * np.pi
        k = np.arange(self._strides() + 1)
        # each stride's peak flexion, as the thigh moves (a high knee lift moves it), within
        # a quarter stride of the swing's own (phase pi / 2)
        around = np.linspace(-np.pi / 2, np.pi / 2, 121)
        phases = (full * k + np.pi / 2)[:, None] + around[None, :]
        flexion = self.flexion(np.interp(phases, self._phase, self._t))
        peak = phases[np.arange(len(k)), np.argmax(flexion, axis=1)]
        contact = peak + HEEL_CONTACT_PHASE - np.pi / 2
        off = full * k + HEEL_CONTACT_PHASE + STANCE_SHARE * full  # the stride's rhythm
        # mid-stance, the hip above the foot (inside the walk: it ends where a stride ends)
        foot = np.interp(np.interp(contact + full / 4, self._phase, self._t), self._t, self._x)
        times, kinds, feet = [], [], []
        for phases, kind in ((contact, 0), (off, 1)):
            inside = (phases >= 0) & (phases <= self._phase[-1])
            times.append(np.interp(phases[inside], self._phase, self._t))
            kinds.append(np.full(int(inside.sum()), kind))
            feet.append(foot[inside])
        t, kind, x = np.concatenate(times), np.concatenate(kinds), np.concatenate(feet)
        order = np.argsort(t, kind="stable")
        return t[order], kind[order], x[order]

    def gait_events(self, t0: float, t1: float) -> list[tuple[float, str, float]]:
        """The instrumented leg's gait events with t0 < time <= t1 (walk seconds): (time,
        "heel_contact" or "toe_off", course position of that foot)."""
        t, kind, x = self._gait
        i, j = np.searchsorted(t, [t0, t1], side="right")
        names = ("heel_contact", "toe_off")
        return [(float(t[n]), names[int(kind[n])], float(x[n])) for n in range(i, j)]

    # ---- scheduling ---------------------------------------------------------------------

    def _schedule_errors(self, rng: np.random.Generator, rate: float):
        strides = self._strides()
        events: list[ErrorEvent] = []
        for k in range(strides):
            for kind in ERROR_KINDS:
                p_in, p_out, phase, (d0, d1) = ERROR_SCHEDULE[kind]
                if rng.random() >= (p_out if self.course.outdoor else p_in) * rate:
                    continue
                at = rng.uniform(0, 2 * np.pi) if phase is None else phase + rng.normal(0, 0.3)
                tc = float(np.interp(2 * np.pi * k + at, self._phase, self._t))
                d = float(rng.uniform(d0, d1))
                ev = ErrorEvent(
                    kind, tc - d / 2, tc + d / 2, float(rng.random()), int(rng.integers(2**31))
                )
                if (
                    ev.t0 > 0
                    and ev.t1 < self.duration_s
                    and not any(ev.t0 < e.t1 and e.t0 < ev.t1 for e in events)
                ):
                    events.append(ev)
        return sorted(events, key=lambda e: e.t0)

    def event_at(self, t: float) -> ErrorEvent | None:
        i = int(np.searchsorted(self._event_t0, t, side="right")) - 1
        if i >= 0 and t < self.events[i].t1:
            return self.events[i]
        return None

    # ---- kinematics (scalar or array t; np.interp holds the ends, so t is clamped) --------

    def _clamp(self, t):
        return np.interp(t, (0.0, self.duration_s), (0.0, self.duration_s))

    def position(self, t):
        """Hip position along the course (m)."""
        return np.interp(t, self._t, self._x)

    def phase(self, t):
        return np.interp(t, self._t, self._phase)

    def flexion(self, t):
        """Thigh flexion (rad): positive lifts the knee forward and the camera up."""
        flex = np.interp(t, self._t, self._flex_mean) + np.interp(
            t, self._t, self._flex_amp
        ) * np.sin(self.phase(t))
        for e in self._sky:  # a high knee lift: a smooth bump of 25-35 degrees
            u = np.interp(t, (e.t0, e.t1), (0.0, 1.0))
            flex = flex + np.radians(25 + 10 * e.strength) * np.sin(np.pi * u) ** 2
        return flex

    def thigh_angles(self, t):
        """(roll, pitch, yaw) of the thigh in radians; pitch = -flexion."""
        t = self._clamp(t)
        phi = self.phase(t)
        roll = self.roll_offset + np.radians(2.0) * np.sin(phi + 1.2)
        yaw = np.radians(3.0) * np.sin(phi + 0.3)
        for period, offset in self.wander:
            yaw = yaw + np.radians(1.0) * np.sin(2 * np.pi * t / period + offset)
        return roll, -self.flexion(t), yaw

    def thigh_quaternion(self, t) -> np.ndarray:
        """Thigh (IMU body) -> world orientation, [w, x, y, z] (shape (..., 4))."""
        q = quat_from_euler(*self.thigh_angles(t))
        return np.moveaxis(q, 0, -1)

    def flexion_rate(self, t: float, dt: float = 0.005) -> float:
        return float((self.flexion(t + dt) - self.flexion(t - dt)) / (2 * dt))

    def hip_position(self, t: float) -> np.ndarray:
        t = self._clamp(t)
        x = np.interp(t, self._t, self._x)
        phi = self.phase(t)
        ground = np.interp(t, self._t, self._ground)
        return np.array(
            [
                x,
                self.hip_lateral_m + 0.015 * np.sin(phi),
                ground + self.hip_height_m + 0.01 * np.cos(2 * phi),
            ]
        )

    def pose(self, t: float, extra_flexion: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """(thigh quaternion [w, x, y, z], camera -> world 4x4) at t; `extra_flexion` (rad)
        gives a pose the thigh swings through a moment later."""
        roll, pitch, yaw = (float(a) for a in self.thigh_angles(t))
        pitch -= extra_flexion
        q = quat_from_euler(roll, pitch, yaw)
        thigh = _euler_matrix(roll, pitch, yaw)
        pose = np.eye(4)
        pose[:3, :3] = thigh @ self.mounting
        pose[:3, 3] = self.hip_position(t) + thigh @ self.camera_offset
        return q, pose

    def camera_pose(self, t: float, extra_flexion: float = 0.0) -> np.ndarray:
        """Camera -> world as a 4x4 matrix (rotation and position)."""
        return self.pose(t, extra_flexion)[1]
