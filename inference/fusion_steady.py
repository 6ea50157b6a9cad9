"""The steady fusion methods (inference.fusion): a fixed-lag-1 smoother built to switch
once per terrain change, and its variants with gait, hysteresis and terrain-geometry cues.
Their design is in inference.fusion_design."""

from __future__ import annotations

import math
from collections import deque

from devices.frames import MODES
from inference.errors import InferenceError
from inference.fusion_base import FusionOutput, Stream, probability_row
from inference.fusion_design import (
    GAIT_LEAVE,
    GAIT_PHASE_SD,
    GAIT_RATE_FRAMES,
    GEOMETRY_EVIDENCE,
    GEOMETRY_HYSTERESIS,
    GEOMETRY_SHOWN,
    HYSTERESIS,
    MARGINS,
    N_MODES,
    SLOPE_HOLD_FRAMES,
    STEADY_EVIDENCE,
    STEADY_STAY,
    steady_transition,
    validate_transition,
)


class SteadyFusion(Stream):
    """The fixed-lag-1 smoother p(z_{t-1} | x_1..x_t) of an HMM built to switch
    once per terrain change (delay 1 frame).

    The HMM: `steady_transition(stay)` (the paper's rules, a stay from walking) and the
    CNN's probabilities raised to `evidence` as the emission likelihood (see the design
    notes in inference.fusion_design). Frame t-1 is decided when frame t arrives: alpha_{t-1} (the
    filter) times T e_t (one frame of look-ahead), normalised; `flush` decides the last
    frame by its filter. Pure-Python floats, unrolled: one update in a few microseconds.
    """

    takes_elevation = False  # push takes the frame's camera elevation too
    uses_gait = False  # ...and needs it (GaitSteadyFusion)

    def __init__(self, stay: float = STEADY_STAY, evidence: float = STEADY_EVIDENCE):
        if not 0.0 < evidence <= 1.0:
            raise InferenceError(f"steady: evidence must be in (0, 1], got {evidence}")
        super().__init__(None)
        self.delay_frames = 1
        self.stay, self.evidence = float(stay), float(evidence)
        self.transition = validate_transition(steady_transition(self.stay), "steady transition")
        self._rows = tuple(tuple(r) for r in self.transition.tolist())
        self._alpha: tuple[float, ...] | None = None  # the filter at the newest frame

    def _reset_state(self) -> None:
        self._alpha = None

    def push(self, probabilities) -> FusionOutput | None:
        return self._update(probabilities, self._rows)

    def _update(self, probabilities, rows) -> FusionOutput | None:
        """One frame with `rows`, the transition from the last frame to this one."""
        self._check_open()
        b = self.evidence
        e0, e1, e2, e3, e4 = (x**b for x in probability_row(probabilities))
        t = self._frame
        self._frame = t + 1
        r0, r1, r2, r3, r4 = rows
        last = self._alpha
        if last is None:
            q = (e0, e1, e2, e3, e4)
        else:
            a0, a1, a2, a3, a4 = last
            q = (
                (a0 * r0[0] + a1 * r1[0] + a2 * r2[0] + a3 * r3[0] + a4 * r4[0]) * e0,
                (a0 * r0[1] + a1 * r1[1] + a2 * r2[1] + a3 * r3[1] + a4 * r4[1]) * e1,
                (a0 * r0[2] + a1 * r1[2] + a2 * r2[2] + a3 * r3[2] + a4 * r4[2]) * e2,
                (a0 * r0[3] + a1 * r1[3] + a2 * r2[3] + a3 * r3[3] + a4 * r4[3]) * e3,
                (a0 * r0[4] + a1 * r1[4] + a2 * r2[4] + a3 * r3[4] + a4 * r4[4]) * e4,
            )
        z = q[0] + q[1] + q[2] + q[3] + q[4]
        if not z > 0.0:  # every mode ruled out (underflow): start again from this frame
            z = e0 + e1 + e2 + e3 + e4
            q = (e0, e1, e2, e3, e4)
        self._alpha = (q[0] / z, q[1] / z, q[2] / z, q[3] / z, q[4] / z)
        if last is None:
            return None
        # frame t-1 with one frame of look-ahead: alpha_{t-1} * (T e_t)
        g = (
            a0 * (r0[0] * e0 + r0[1] * e1 + r0[2] * e2 + r0[3] * e3 + r0[4] * e4),
            a1 * (r1[0] * e0 + r1[1] * e1 + r1[2] * e2 + r1[3] * e3 + r1[4] * e4),
            a2 * (r2[0] * e0 + r2[1] * e1 + r2[2] * e2 + r2[3] * e3 + r2[4] * e4),
            a3 * (r3[0] * e0 + r3[1] * e1 + r3[2] * e2 + r3[3] * e3 + r3[4] * e4),
            a4 * (r4[0] * e0 + r4[1] * e1 + r4[2] * e2 + r4[3] * e3 + r4[4] * e4),
        )
        zg = g[0] + g[1] + g[2] + g[3] + g[4]
        g = (g[0] / zg, g[1] / zg, g[2] / zg, g[3] / zg, g[4] / zg) if zg > 0.0 else last
        return FusionOutput(t - 1, g.index(max(g)), t - 1, g)

    def flush(self) -> list[FusionOutput]:
        if self._flushed:
            return []
        self._flushed = True
        if self._alpha is None:
            return []
        a = self._alpha
        return [FusionOutput(self._frame - 1, a.index(max(a)), self._frame - 1, a)]


class GaitPhase:
    """The gait phase in which terrain changes show, frame by frame from the camera's
    elevation (its optical axis above the horizon, degrees; it follows the thigh): the
    camera pitching up by more than GAIT_PHASE_SD running standard deviations of its
    frame-to-frame change (over about GAIT_RATE_FRAMES frames), as the thigh swings
    forward and the view reaches ahead."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self._last = math.nan
        self._var = 1.0  # deg^2 a frame: a start that a second of walking replaces

    def update(self, elevation_deg: float) -> bool | None:
        """Whether this frame is in the phase; None without a change to tell (no
        elevation now, or none before)."""
        change = elevation_deg - self._last
        if elevation_deg == elevation_deg:  # not NaN
            self._last = elevation_deg
        if change != change:
            return None
        self._var += (change * change - self._var) / GAIT_RATE_FRAMES
        return change >= GAIT_PHASE_SD * math.sqrt(self._var)


def gait_phases(elevation_deg) -> list[bool | None]:
    """GaitPhase over a sequence of frames' camera elevations."""
    phase = GaitPhase()
    return [phase.update(float(e)) for e in elevation_deg]


class GaitSteadyFusion(SteadyFusion):
    """Steady whose chance of leaving a mode follows the gait phase.

    `push(probabilities, elevation_deg)`: the camera's optical axis above the horizon at
    the frame (inference.preprocess). In GaitPhase (the camera pitching up) leaving a mode
    is GAIT_LEAVE[0] times as likely as steady's average, otherwise GAIT_LEAVE[1] times
    (see the design notes there). Without an elevation (no IMU orientation) the frame uses
    steady's own transition.
    """

    takes_elevation = uses_gait = True

    def __init__(self, stay: float = STEADY_STAY, evidence: float = STEADY_EVIDENCE):
        super().__init__(stay, evidence)
        leave = 1.0 - self.stay
        self._phase_rows = tuple(
            tuple(tuple(r) for r in steady_transition(1.0 - leave * g).tolist()) for g in GAIT_LEAVE
        )
        self._phase = GaitPhase()

    def _reset_state(self) -> None:
        super()._reset_state()
        self._phase.reset()

    def push(self, probabilities, elevation_deg: float | None = None) -> FusionOutput | None:
        rows = self._rows
        in_phase = self._phase.update(math.nan if elevation_deg is None else float(elevation_deg))
        if in_phase is not None:
            rows = self._phase_rows[0 if in_phase else 1]
        return self._update(probabilities, rows)


class HysteresisFusion(SteadyFusion):
    """Steady's posterior, with a switch margin (delay 1 frame).

    The first decision is steady's. After it, the decision moves from stairs or a ramp to
    level ground only when level ground's posterior (steady's, for the decided frame)
    reaches `hysteresis`; otherwise it holds. Every other switch is steady's.
    `probabilities` stay steady's posterior, so a display shows what the switch waits for.
    `flush` applies the same rule to the last frame.
    """

    def __init__(
        self,
        stay: float = STEADY_STAY,
        evidence: float = STEADY_EVIDENCE,
        hysteresis: float = HYSTERESIS,
    ):
        if not 0.0 <= hysteresis < 1.0:
            raise InferenceError(f"hysteresis: margin must be in [0, 1), got {hysteresis}")
        super().__init__(stay, evidence)
        self.hysteresis = float(hysteresis)
        self._held = -1  # the last decision; -1 before the first

    def _reset_state(self) -> None:
        super()._reset_state()
        self._held = -1

    def _hold(self, out: FusionOutput) -> FusionOutput:
        g, d = out.probabilities, out.decision
        held = self._held
        if held < 0 or d != 0 or held == 0 or self._may_leave(held, g[d]):  # 0: level ground
            held = self._held = d
        out.decision = held
        return out

    def _may_leave(self, held: int, level_posterior: float) -> bool:
        """Whether the decision leaves stairs or a ramp, `held`, for level ground."""
        return level_posterior >= self.hysteresis

    def push(self, probabilities) -> FusionOutput | None:
        out = self._update(probabilities, self._rows)
        return None if out is None else self._hold(out)

    def flush(self) -> list[FusionOutput]:
        return [self._hold(out) for out in super().flush()]


class MarginFusion(HysteresisFusion):
    """Steady's posterior, every switch at a margin by the mode switched to (delay 1).

    The first decision is steady's. After it, the decision moves to another mode only when
    that mode's posterior (steady's, for the decided frame, with `evidence`) reaches
    `margins[mode]`: higher into level ground, which a classifier reads most often where it
    is not (an object's flat face, a ramp's misread), than into stairs or a ramp (the
    design in inference.fusion_design: MARGINS). HysteresisFusion is the case of a margin
    into level ground alone; `probabilities` and `flush` are its.
    """

    def __init__(
        self,
        stay: float = STEADY_STAY,
        evidence: float = STEADY_EVIDENCE,
        margins=MARGINS,
    ):
        if len(margins) != N_MODES or not all(0.0 <= m < 1.0 for m in margins):
            raise InferenceError(f"margins: expected {N_MODES} numbers in [0, 1), got {margins}")
        super().__init__(stay, evidence, hysteresis=margins[0])
        self.margins = tuple(float(m) for m in margins)

    def _hold(self, out: FusionOutput) -> FusionOutput:
        g, d = out.probabilities, out.decision
        if self._held < 0 or (d != self._held and g[d] >= self.margins[d]):
            self._held = d
        out.decision = self._held
        return out


class GeometryFusion(HysteresisFusion):
    """HysteresisFusion with the terrain features as a second
    observation of each frame (delay 1 frame).

    After each push, `see_geometry(mode)` gives the mode the frame's features show (index
    into MODES, -1: unknown; inference.features.shown_mode): the filter of that frame is
    multiplied by GEOMETRY_SHOWN's column for it, raised to `geometry_evidence`. The frame
    is decided at the next push, so its decision weighs both its CNN output and its
    geometry; the live pipeline computes the features after the push because they take
    the decision as a hint. A frame without `see_geometry` counts as unknown geometry never
    seen (no update). The switch margin is `hysteresis` (GEOMETRY_HYSTERESIS).
    """

    uses_geometry = True

    def __init__(
        self,
        stay: float = STEADY_STAY,
        evidence: float = STEADY_EVIDENCE,
        hysteresis: float = GEOMETRY_HYSTERESIS,
        geometry_evidence: float = GEOMETRY_EVIDENCE,
    ):
        if not 0.0 < geometry_evidence <= 1.0:
            raise InferenceError(f"geometry evidence must be in (0, 1], got {geometry_evidence}")
        super().__init__(stay, evidence, hysteresis)
        self.geometry_evidence = float(geometry_evidence)
        # per shown mode (the last: unknown), the likelihood of each terrain
        self._shown = tuple(
            tuple(GEOMETRY_SHOWN[mode][g] ** self.geometry_evidence for mode in range(N_MODES))
            for g in range(N_MODES + 1)
        )

    def see_geometry(self, mode: int, ahead: int = -1) -> None:
        """The mode the newest pushed frame's terrain features show (-1: unknown); `ahead`
        (the ground ahead's mode, SlopeFusion's cue) is not used."""
        a = self._alpha
        if a is None or self._flushed:
            return
        w = self._shown[mode if 0 <= mode < N_MODES else N_MODES]
        q = (a[0] * w[0], a[1] * w[1], a[2] * w[2], a[3] * w[3], a[4] * w[4])
        z = q[0] + q[1] + q[2] + q[3] + q[4]
        self._alpha = (q[0] / z, q[1] / z, q[2] / z, q[3] / z, q[4] / z)


class SlopeFusion(HysteresisFusion):
    """Steady, holding a ramp down while the ground ahead still slopes
    down (delay 1 frame).

    After each push, `see_geometry(mode, ahead)` gives the mode the ground AHEAD_M ahead
    shows by its slope (index into MODES, -1: not seen; inference.features.ground_ahead;
    `mode`, the features' own reading, is not used). The decision leaves a ramp for level
    ground only when level ground's posterior reaches `hysteresis` (as in
    HysteresisFusion), and a ramp down only once the ground ahead has not shown a ramp
    down in any of the last SLOPE_HOLD_FRAMES frames up to the decided one. Every other
    switch, leaving stairs included, is steady's.
    """

    uses_geometry = True
    _RAMPS = (MODES.index("UR"), MODES.index("DR"))
    _HELD = MODES.index("DR")  # held by the ground ahead

    def __init__(
        self,
        stay: float = STEADY_STAY,
        evidence: float = STEADY_EVIDENCE,
        hysteresis: float = HYSTERESIS,
        hold_frames: int = SLOPE_HOLD_FRAMES,
    ):
        if int(hold_frames) != hold_frames or hold_frames < 1:
            raise InferenceError(f"slope: hold frames must be >= 1, got {hold_frames}")
        super().__init__(stay, evidence, hysteresis)
        self.hold_frames = int(hold_frames)
        self._ahead: deque[int] = deque(maxlen=self.hold_frames)

    def _reset_state(self) -> None:
        super()._reset_state()
        self._ahead.clear()

    def see_geometry(self, mode: int, ahead: int = -1) -> None:
        """The newest pushed frame's terrain: what its features show (`mode`, not used)
        and the mode the ground ahead shows by its slope (`ahead`, -1: not seen)."""
        if not self._flushed:
            self._ahead.append(ahead)

    def _may_leave(self, held: int, level_posterior: float) -> bool:
        if held not in self._RAMPS:
            return True
        if held == self._HELD and held in self._ahead:
            return False
        return level_posterior >= self.hysteresis
