"""When the instrumented leg's next step lands on the terrain ahead: the step clock from the
thigh IMU's gait events, and the distance to the next terrain from the terrain features'
edges, followed as the walker closes in (inference.fusion_steps times its changes by them).

A prosthesis needs the new mode at the heel contact of the first step on the new terrain
and the old one at the heel contact before. The camera sees the change one or two strides
ahead; which heel contact is the first on the new terrain follows from where the terrain
changes (an edge of inference.features, seen from the camera) and where the hip will be at
the next step's mid-stance (the foot under the hip: the step's terrain). The edge is fixed
in the world and the walker closes in on it, so its distances from the hip over the last
frames lie on a line whose slope is the walking speed: a line through most of them (a few
are a later riser, an edge the noise moved, an object in view) gives both.

Pure: the fusion feeds the events and the frames in, as the live pipeline and eval do.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from inference.fusion_design import (
    STEP_CAMERA_FORWARD_M,
    STEP_SPEED_MPS,
    STEP_SWING_SHARE,
    STEP_THIGH_M,
    STEP_TRACK_INLIER_M,
    STEP_TRACK_MIN_POINTS,
    STEP_TRACK_MIN_SPAN_S,
    STEP_TRACK_S,
)

HEEL_CONTACT, TOE_OFF = "heel_contact", "toe_off"  # devices.frames.GAIT_EVENTS
_RATE = 0.3  # the running means of the stride and the swing: about the last 3 strides


def hip_offset_m(flexion_deg: float) -> float:
    """How far ahead of the hip the camera is, horizontally, at a thigh flexion (degrees,
    positive lifting the knee): it sits STEP_THIGH_M down the thigh from the hip and
    STEP_CAMERA_FORWARD_M in front of it."""
    f = math.radians(flexion_deg)
    return STEP_THIGH_M * math.sin(f) + STEP_CAMERA_FORWARD_M * math.cos(f)


@dataclass(frozen=True)
class EdgeFit:
    """An edge followed over frames: its distance ahead of the hip at `time_s`, the walking
    speed that closes it, and how many of the measurements agree."""

    distance_m: float
    speed_mps: float
    inliers: int


class EdgeTrack:
    """The recent distances (m, ahead of the hip) of one kind of edge, with their times."""

    def __init__(self, span_s: float = STEP_TRACK_S) -> None:
        self.span_s = span_s
        self._points: deque[tuple[float, float]] = deque()

    def add(self, time_s: float, distance_m: float) -> None:
        self._points.append((time_s, distance_m))
        self.forget(time_s)

    def forget(self, now_s: float) -> None:
        while self._points and now_s - self._points[0][0] > self.span_s:
            self._points.popleft()

    def clear(self) -> None:
        self._points.clear()

    def __len__(self) -> int:
        return len(self._points)

    def last(self) -> tuple[float, float] | None:
        return self._points[-1] if self._points else None

    def fit(self, now_s: float, speeds=(0.3, 1.8)) -> EdgeFit | None:
        """The line through most measurements (within STEP_TRACK_INLIER_M), over at least
        STEP_TRACK_MIN_SPAN_S and STEP_TRACK_MIN_POINTS points, with a walking speed in
        `speeds`: the edge's distance at `now_s`. None: no such line."""
        pts = list(self._points)
        best: tuple[tuple[int, float], float, float] | None = None
        lo, hi = speeds
        for i in range(len(pts)):
            ti, di = pts[i]
            for j in range(i + 1, len(pts)):
                tj, dj = pts[j]
                if tj - ti < STEP_TRACK_MIN_SPAN_S / 2:
                    continue
                v = (di - dj) / (tj - ti)
                if not lo <= v <= hi:
                    continue
                at_now = dj - v * (now_s - tj)
                inside = [
                    (t, abs(d - v * (now_s - t) - at_now))
                    for t, d in pts
                    if abs(d - v * (now_s - t) - at_now) <= STEP_TRACK_INLIER_M
                ]
                span = max(t for t, _ in inside) - min(t for t, _ in inside)
                if len(inside) < STEP_TRACK_MIN_POINTS or span < STEP_TRACK_MIN_SPAN_S:
                    continue
                score = (len(inside), -sum(r for _, r in inside))
                if best is None or score > best[0]:
                    best = (score, at_now, v)
        if best is None:
            return None
        return EdgeFit(best[1], best[2], best[0][0])


class StepClock:
    """The instrumented leg's step rhythm from the detector's events: when its next heel
    contact comes, the stride, whether it walks."""

    def __init__(self, stride_s: float, stall_s: float) -> None:
        self.stride_s = stride_s
        self.stall_s = stall_s
        self.swing = STEP_SWING_SHARE  # of a stride, toe off to heel contact
        self.heel_contact_s: float | None = None
        self.toe_off_s: float | None = None

    def see(self, event: str, time_s: float) -> None:
        if event == HEEL_CONTACT:
            last = self.heel_contact_s
            if last is not None and 0 < time_s - last < self.stall_s:
                stride = time_s - last
                off = self.toe_off_s
                if off is not None and last < off < time_s:
                    self.swing += ((time_s - off) / stride - self.swing) * _RATE
                self.stride_s += (stride - self.stride_s) * _RATE
            self.heel_contact_s = time_s
        elif event == TOE_OFF:
            self.toe_off_s = time_s

    def walking(self, now_s: float) -> bool:
        return self.heel_contact_s is not None and now_s - self.heel_contact_s < self.stall_s

    def next_heel_contact(self, now_s: float) -> float:
        """When the next heel contact comes: a swing after the last toe off while the foot
        swings, a stride after the last heel contact otherwise; `now_s` when that is past
        (it lands any moment: the detector reports a heel contact within a few
        hundredths of a second)."""
        last, off = self.heel_contact_s, self.toe_off_s
        if last is None:
            return now_s
        if off is not None and off > last:
            due = off + self.swing * self.stride_s
        else:
            due = last + self.stride_s
        return max(due, now_s)


def speed_or(fit: EdgeFit | None, last_speed: float | None) -> float:
    """The walking speed to extrapolate with: the fit's, else the last one fitted, else a
    walker's usual STEP_SPEED_MPS."""
    if fit is not None:
        return fit.speed_mps
    return last_speed if last_speed is not None else STEP_SPEED_MPS
