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
    STEP_ELEVATION,
    STEP_ELEVATION_REF_DEG,
    STEP_HOLD_FRAMES,
    STEP_OFFSET,
    STEP_STALL_FRAMES,
    STEP_STRIDE_FRAMES,
)
from inference.fusion_steady import HysteresisFusion

HEEL_CONTACT = "heel_contact"  # devices.frames.GAIT_EVENTS[0]
_STRIDE_RATE = 0.3  # the stride's running mean: about the last 3 strides


class StepFusion(HysteresisFusion):
    """Steady+hysteresis whose changes are timed to the walker's steps (delay 1 frame).

    The camera sees a terrain change ahead of the foot: steady+hysteresis's decision (the
    proposal) changes some way before the foot lands on the new terrain, by a distance
    that depends on the terrains (how far ahead each shows in the image). The decision
    must change after the heel contact of the step before the transition step, so that
    it holds there the old mode and at the toe off and the heel contact that follow the
    new one. So when a proposal has held `hold_frames` decided frames, it is scheduled: the
    heel contact nearest to `offset[old][new]` strides after it (the stride: the running
    mean of the intervals between heel contacts, in frames) is the step before the
    transition; the decision changes as that heel contact is handed over, or at once when
    it is the last one, already passed. The camera's elevation at the proposed frame
    shifts it: the higher the camera looks, the farther ahead the change it shows
    (`elevation` strides a degree above `elevation_ref_deg`). A proposal that goes back
    before its heel contact is dropped: a run of misreads shorter than the wait never
    switches. Without a heel contact for `stall_frames` frames (standing, an IMU gap, no
    detector) a proposal switches on its hold alone, so the method never freezes on a
    mode.

    `push(probabilities, elevation_deg)`: the camera's optical axis above the horizon at
    the frame (inference.preprocess); without a finite one (None, NaN: no IMU
    orientation, a score file) the frame counts as at `elevation_ref_deg`. `see_gait(event)`: a gait
    event just detected (before the next frame's push); only heel contacts time the steps.
    `probabilities` stay steady's posterior.
    """

    uses_steps = True
    takes_elevation = True  # the timing of a change; without one, the reference's

    def __init__(
        self,
        stay: float = STEADY_STAY,
        evidence: float = STEADY_EVIDENCE,
        hysteresis: float = HYSTERESIS,
        hold_frames: int = STEP_HOLD_FRAMES,
        stall_frames: int = STEP_STALL_FRAMES,
        offset=STEP_OFFSET,
        elevation: float = STEP_ELEVATION,
        elevation_ref_deg: float = STEP_ELEVATION_REF_DEG,
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
        self.elevation, self.elevation_ref_deg = float(elevation), float(elevation_ref_deg)
        self._reset_steps()

    def _reset_steps(self) -> None:
        self._proposed = -1  # steady+hysteresis's decision of the last decided frame
        self._run = 0  # decided frames it has held
        self._decided = 0  # decided frames so far
        self._last_hc = -1  # the decided frame at which the last heel contact came; -1: none
        self._stride = float(STEP_STRIDE_FRAMES)
        self._hc_pending = False  # a heel contact came since the last decided frame
        self._pending = -1  # the mode scheduled, -1: none
        self._left = 0  # heel contacts until it switches
        self._elevation = math.nan  # the camera's at the newest frame pushed
        self._decided_elevation = math.nan  # ...at the frame being decided (one before)

    def _reset_state(self) -> None:
        super()._reset_state()
        self._reset_steps()

    def see_gait(self, event: str) -> None:
        """A heel contact or toe off of the instrumented leg, just detected."""
        if event == HEEL_CONTACT and not self._flushed:
            self._hc_pending = True

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
            if self._pending >= 0:
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
            if not walking:
                self._held = proposed
                self._pending = -1
            elif self._pending != proposed:  # schedule it at a heel contact
                phase = (n - self._last_hc) / self._stride  # strides since the last one
                left = self._heel_contacts_to_wait(held, proposed, phase)
                if left <= 0:
                    self._held = proposed
                    self._pending = -1
                else:
                    self._pending, self._left = proposed, left
        out.decision = self._held
        return out

    def _heel_contacts_to_wait(self, held: int, proposed: int, phase: float) -> int:
        """How many heel contacts a change from `held` to `proposed` waits for, proposed
        `phase` strides after the last heel contact, at the decided frame's elevation (0
        or fewer: at once)."""
        shift = self.offset[held][proposed]
        if math.isfinite(self._decided_elevation):
            shift += self.elevation * (self._decided_elevation - self.elevation_ref_deg)
        return round(phase + shift)

    def push(self, probabilities, elevation_deg: float | None = None) -> FusionOutput | None:
        elevation = math.nan if elevation_deg is None else float(elevation_deg)
        out = self._update(probabilities, self._rows)  # raises before any state moves
        # a push decides the frame before it: its elevation is the previous push's
        self._decided_elevation, self._elevation = self._elevation, elevation
        return None if out is None else self._gate(out)

    def flush(self) -> list[FusionOutput]:
        if self._flushed:
            return []
        self._decided_elevation = self._elevation  # the last frame pushed
        return [self._gate(out) for out in super(HysteresisFusion, self).flush()]
