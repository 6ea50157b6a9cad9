"""The fusion that acts at steps (inference.fusion's "steady+steps"): steady+hysteresis
whose decision changes only around a gait event of the instrumented leg, as a powered
prosthesis changes its mode (Simon et al. 2017: at a heel contact or toe off, 90 ms on).
Its design is in inference.fusion_design (STEP_*)."""

from __future__ import annotations

from inference.errors import InferenceError
from inference.fusion_base import FusionOutput
from inference.fusion_design import (
    HYSTERESIS,
    STEADY_EVIDENCE,
    STEADY_STAY,
    STEP_HOLD_FRAMES,
    STEP_STALL_FRAMES,
    STEP_WINDOW_FRAMES,
)
from inference.fusion_steady import HysteresisFusion

GAIT_EVENTS = ("heel_contact", "toe_off")  # devices.frames.GAIT_EVENTS


class StepFusion(HysteresisFusion):
    """Steady+hysteresis, switching only in a window after a gait event (delay 1 frame).

    `see_gait(event)` hands it a heel contact or toe off as the detector reports it (before
    the next frame's push). Steady+hysteresis proposes a decision for each frame; the
    decision moves to a proposed mode only when (1) the proposal has held for the last
    `hold_frames` decided frames, a run of misreads shorter than that never switches, and
    (2) a gait event came within the last `window_frames` frames: a mode changes at a step,
    never mid-stance. Without any gait event for `stall_frames` frames (standing, turning on
    the spot, an IMU gap or no detector), (2) is waived, so the method never freezes on a
    mode: it then switches as steady+hysteresis with the hold. The first decision is
    steady's; `probabilities` stay steady's posterior. `flush` applies the same rule.
    """

    uses_steps = True

    def __init__(
        self,
        stay: float = STEADY_STAY,
        evidence: float = STEADY_EVIDENCE,
        hysteresis: float = HYSTERESIS,
        hold_frames: int = STEP_HOLD_FRAMES,
        window_frames: int = STEP_WINDOW_FRAMES,
        stall_frames: int = STEP_STALL_FRAMES,
    ):
        for name, value, low in (
            ("hold frames", hold_frames, 1),
            ("window frames", window_frames, 1),
            ("stall frames", stall_frames, 1),
        ):
            if int(value) != value or value < low:
                raise InferenceError(f"steps: {name} must be an integer >= {low}, got {value}")
        super().__init__(stay, evidence, hysteresis)
        self.hold_frames = int(hold_frames)
        self.window_frames = int(window_frames)
        self.stall_frames = int(stall_frames)
        self._reset_steps()

    def _reset_steps(self) -> None:
        self._proposed = -1  # steady+hysteresis's decision of the last decided frame
        self._run = 0  # frames it has held
        self._since_event = self.stall_frames  # decided frames since the last gait event
        self._event_pending = False  # an event came since the last decided frame

    def _reset_state(self) -> None:
        super()._reset_state()
        self._reset_steps()

    def see_gait(self, event: str) -> None:
        """A heel contact or toe off of the instrumented leg, just detected."""
        if event in GAIT_EVENTS and not self._flushed:
            self._event_pending = True

    def _gate(self, out: FusionOutput) -> FusionOutput:
        g, d = out.probabilities, out.decision
        held = self._held
        # steady+hysteresis's proposal: leaving stairs or a ramp for level ground needs
        # level ground's posterior at the margin
        proposed = d if held < 0 or d != 0 or held == 0 or self._may_leave(held, g[d]) else held
        self._run = self._run + 1 if proposed == self._proposed else 1
        self._proposed = proposed
        if self._event_pending:
            self._since_event = 0
            self._event_pending = False
        else:
            self._since_event += 1
        if held < 0:
            self._held = proposed
        elif proposed != held and self._run >= self.hold_frames:
            at_step = self._since_event < self.window_frames
            if at_step or self._since_event >= self.stall_frames:
                self._held = proposed
        out.decision = self._held
        return out

    def push(self, probabilities) -> FusionOutput | None:
        out = self._update(probabilities, self._rows)
        return None if out is None else self._gate(out)

    def flush(self) -> list[FusionOutput]:
        if self._flushed:
            return []
        return [self._gate(out) for out in super(HysteresisFusion, self).flush()]
