"""The fusion that acts at steps (inference.fusion's "steady+steps"): steady+hysteresis
whose decision changes at the heel contact of the instrumented leg after which the foot
swings onto the new terrain, as a powered prosthesis changes its mode at a gait event
(Simon et al. 2017). Its design is in inference.fusion_design (STEP_*)."""

from __future__ import annotations

import math

from inference.errors import InferenceError
from inference.fusion_base import FusionOutput
from inference.fusion_design import (
    HYSTERESIS,
    N_MODES,
    STEADY_EVIDENCE,
    STEADY_STAY,
    STEP_EDGE,
    STEP_HOLD_FRAMES,
    STEP_MID_STANCE,
    STEP_OFFSET,
    STEP_STAIRS_EXIT_M,
    STEP_STALL_FRAMES,
    STEP_STRIDE_FRAMES,
)
from inference.fusion_steady import HysteresisFusion
from inference.step_timing import (
    HEEL_CONTACT,
    EdgeTrack,
    StepClock,
    hip_offset_m,
    speed_or,
)

_STRIDE_RATE = 0.3  # the stride's running mean: about the last 3 strides
_FPS = 15.0  # frame times when none are given: the paper's camera
LEVEL, STAIRS = 0, (1, 2)  # mode indices (MODES): level ground, stairs up and down


class StepFusion(HysteresisFusion):
    """Steady+hysteresis whose changes are timed to the walker's steps (delay 1 frame).

    The camera sees a terrain change ahead of the foot: steady+hysteresis's decision (the
    proposal) changes some way before the foot lands on the new terrain. The decision
    must change after the heel contact of the last step on the old terrain, so that it
    holds the old mode there and the new one at the toe off and the heel contact that
    follow. So a proposal that has held `hold_frames` decided frames waits for that step:

    - by the terrain ahead, when the frames show it (`see_frame`: the thigh's flexion and
      the terrain features' edges, inference.features.terrain_edges): the new mode's edge
      is followed over the frames (inference.step_timing), and the decision changes as
      soon as the hip will have passed it at the next step's mid-stance, a quarter stride
      after its heel contact (the step clock: the detector's heel contacts and toe offs,
      `see_gait`);
    - else by the stride's phase: the heel contact nearest to `offset[old][new]` strides
      after the proposal, the offsets set on design recordings for how far ahead each
      terrain shows in the image.

    A proposal that goes back first is dropped: a run of misreads shorter than the wait
    never switches. Without a heel contact for `stall_frames` frames (standing, an IMU gap,
    no detector) a proposal switches on its hold alone, so the method never freezes.

    `push(probabilities, time_s=None)`: the frame's time on any clock shared with the
    events (None: frames at 15 fps, the phase schedule only). `see_gait(event, time_s)`: a
    gait event just detected, before the next push; only heel contacts time the phase
    schedule. `see_frame(flexion_deg, edges)`: after a push, the pushed frame's thigh
    flexion (degrees, None unknown) and edges (kind -> metres ahead of the camera, None
    where not seen). `probabilities` stay steady's posterior.
    """

    uses_steps = True

    def __init__(
        self,
        stay: float = STEADY_STAY,
        evidence: float = STEADY_EVIDENCE,
        hysteresis: float = HYSTERESIS,
        hold_frames: int = STEP_HOLD_FRAMES,
        stall_frames: int = STEP_STALL_FRAMES,
        offset=STEP_OFFSET,
    ):
        for name, value in (("hold frames", hold_frames), ("stall frames", stall_frames)):
            if int(value) != value or value < 1:
                raise InferenceError(f"steps: {name} must be an integer >= 1, got {value}")
        if len(offset) != N_MODES or any(len(row) != N_MODES for row in offset):
            raise InferenceError(f"steps: expected {N_MODES} rows of {N_MODES} offsets")
        super().__init__(stay, evidence, hysteresis)
        self.hold_frames = int(hold_frames)
        self.stall_frames = int(stall_frames)
        self.offset = tuple(tuple(float(x) for x in row) for row in offset)
        self._reset_steps()

    def _reset_steps(self) -> None:
        self._proposed = -1  # steady+hysteresis's decision of the last decided frame
        self._run = 0  # decided frames it has held
        self._decided = 0  # decided frames so far
        self._last_hc = -1  # the decided frame at which the last heel contact came; -1: none
        self._stride = float(STEP_STRIDE_FRAMES)
        self._hc_pending = False  # a heel contact came since the last decided frame
        self._pending = -1  # the mode scheduled, -1: none
        self._left = 0  # heel contacts until it switches (the phase schedule)
        self._now: float | None = None  # the pushed frame's time, s
        self._clock = StepClock(STEP_STRIDE_FRAMES / _FPS, self.stall_frames / _FPS)
        self._tracks = {kind: EdgeTrack() for kind in set(STEP_EDGE)}
        self._speed: float | None = None  # the last walking speed an edge's line gave

    def _reset_state(self) -> None:
        super()._reset_state()
        self._reset_steps()

    def see_gait(self, event: str, time_s: float | None = None) -> None:
        """A heel contact or toe off of the instrumented leg, just detected."""
        if self._flushed:
            return
        if event == HEEL_CONTACT:
            self._hc_pending = True
        if time_s is not None:
            self._clock.see(event, float(time_s))

    def see_frame(self, flexion_deg: float | None, edges) -> None:
        """The last pushed frame's thigh flexion and the edges its terrain features show."""
        now = self._now
        if now is None or flexion_deg is None or not math.isfinite(flexion_deg) or not edges:
            return
        offset = hip_offset_m(flexion_deg)
        for kind, track in self._tracks.items():
            x = edges.get(kind)
            if x is not None and math.isfinite(x):
                track.add(now, x + offset, self._speed)

    def _edge_distance(self, held: int, new: int, now: float) -> tuple[float, float] | None:
        """(distance the hip has to the new mode's start, walking speed) from the edge
        followed over the frames; None when no frame showed it."""
        track = self._tracks[STEP_EDGE[new]]
        track.forget(now)
        fit = track.fit(now)
        speed = speed_or(fit, self._speed)
        if fit is not None:
            self._speed = fit.speed_mps
            distance = fit.distance_m
        else:
            last = track.last()
            if last is None:
                return None
            distance = last[1] - speed * (now - last[0])
        if new == LEVEL and held in STAIRS:
            distance += STEP_STAIRS_EXIT_M
        return distance, speed

    def _reached(self, held: int, new: int) -> bool | None:
        """Whether the next step lands on the new terrain (None: the frames cannot tell)."""
        now = self._now
        if now is None:
            return None
        edge = self._edge_distance(held, new, now)
        if edge is None:
            return None
        distance, speed = edge
        clock = self._clock
        landing = clock.next_heel_contact(now) + STEP_MID_STANCE * clock.stride_s
        return speed * (landing - now) >= distance

    def _gate(self, out: FusionOutput) -> FusionOutput:
        g, d = out.probabilities, out.decision
        held = self._held
        n = self._decided
        self._decided = n + 1
        if self._hc_pending:  # the steps: the stride, and a scheduled change falls due
            self._hc_pending = False
            if self._last_hc >= 0 and n - self._last_hc < self.stall_frames:
                self._stride += (n - self._last_hc - self._stride) * _STRIDE_RATE
            self._last_hc = n
            if self._pending >= 0 and self._left > 0:
                self._left -= 1
                if self._left <= 0:
                    held = self._held = self._pending
                    self._pending = -1
        # steady+hysteresis's proposal: leaving stairs or a ramp for level ground needs
        # level ground's posterior at the margin
        proposed = d if held < 0 or d != 0 or held == 0 or self._may_leave(held, g[d]) else held
        self._run = self._run + 1 if proposed == self._proposed else 1
        self._proposed = proposed
        walking = self._last_hc >= 0 and n - self._last_hc < self.stall_frames
        if self._pending >= 0 and not walking:  # the steps stopped: no heel contact to wait for
            held = self._held = self._pending
            self._pending = -1
        if held < 0:
            self._held = proposed
        elif proposed == held:
            self._pending = -1  # the proposal went back: nothing to change
        elif self._run >= self.hold_frames:
            reached = self._reached(held, proposed) if walking else None
            if not walking or reached:
                self._held = proposed
                self._pending = -1
            elif reached is False:
                self._pending, self._left = proposed, 0  # the terrain ahead times it
            elif self._pending != proposed or self._left <= 0:  # at a heel contact
                phase = (n - self._last_hc) / self._stride  # strides since the last one
                left = round(phase + self.offset[held][proposed])
                if left <= 0:
                    self._held = proposed
                    self._pending = -1
                else:
                    self._pending, self._left = proposed, left
        out.decision = self._held
        return out

    def push(self, probabilities, time_s: float | None = None) -> FusionOutput | None:
        if time_s is not None:
            self._now = float(time_s)
        out = self._update(probabilities, self._rows)
        return None if out is None else self._gate(out)

    def flush(self) -> list[FusionOutput]:
        if self._flushed:
            return []
        return [self._gate(out) for out in super(HysteresisFusion, self).flush()]
