"""Sequential decision fusion: the paper's modified Viterbi update (HMM), voting, baselines.

Zhang et al., "Sequential Decision Fusion for Environmental Classification in Assistive
Walking" (IEEE TNSRE 2019), Algorithm 1 and equation (voting). Every method is a streaming
object: `push` one CNN probability vector per frame (index order `devices.frames.MODES`),
get back what became known with that frame; `flush` at the end of a sequence decides the
frames still waiting for future frames. Offline evaluation runs the same objects, so live
and offline decisions are identical by construction.

Methods (`make_fusion`), with the number of frames each decision waits for:
- "cnn": argmax of each frame's probabilities (delay 0).
- "cnn+voting": mode of the argmax decisions over frames t-l_v..t+l_v (delay l_v).
- "hmm": Algorithm 1; frame t-1 is decided when frame t arrives (delay 1).
- "hmm+voting": mode of the HMM's smooth states over t-l_v..t+l_v (delay 1 + l_v).
- "forward": a standard HMM forward filter, argmax of p(z_t | x_1..x_t) (delay 0).
- "fixed-lag": a standard fixed-lag smoother, argmax of p(z_t | x_1..x_{t+lag}) (delay lag).
- "steady": a fixed-lag-1 smoother designed to switch once per terrain change (delay 1):
  the paper's transition rules with a stay probability from walking, and each frame's
  evidence discounted because the CNN's errors come in runs (`SteadyFusion`).
- "steady+gait": steady with the gait phase from the camera's pitch (the thigh IMU's
  orientation): the terrain in view changes mostly while the thigh pitches the camera
  down, so a change is likelier then and rarer at other phases (`GaitSteadyFusion`; it
  takes the frame's camera elevation with its probabilities).
- "steady+hysteresis": steady's posterior with a switch margin (delay 1): the decision
  leaves stairs or a ramp for level ground only when level ground's posterior reaches
  HYSTERESIS, so a short run of middling misreads (level ground read on a ramp) does not
  switch; every other switch is steady's (`HysteresisFusion`).
- "steady+geometry": steady+hysteresis whose filter also observes each frame's terrain
  features (the mode their geometry shows, after the frame's push: `see_geometry`), so a
  riser or a slope still in view holds stairs or a ramp against a run of level-ground
  misreads (`GeometryFusion`; delay 1).
The standard HMMs use the CNN output as a scaled emission likelihood, as the paper does.

At the ends of a sequence (documented choices, the paper does not say):
- Algorithm 1 initialises p(s_t) = p(x_t|z_t) for the first l_w frames, and its first
  update decides frame l_w-1 (0-based). Frames 0..l_w-2 are decided as argmax p(s_t), i.e.
  the CNN's argmax, still emitted one frame late so the delay is uniform.
- The last frame has no next frame: `flush` decides it as argmax of its smoothed p(s_t).
- Voting windows are cut at both ends of the sequence (fewer votes there).
- A tie in the vote goes to the smallest mode index (LG first), as MATLAB's `mode`.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from inference.errors import InferenceError
from inference.fusion_design import (
    GAIT_LEAVE,
    GAIT_PHASE_SD,
    GAIT_RATE_FRAMES,
    GEOMETRY_EVIDENCE,
    GEOMETRY_HYSTERESIS,
    GEOMETRY_SHOWN,
    HYSTERESIS,
    N_MODES,
    PAPER_TRANSITION,
    STEADY_EVIDENCE,
    STEADY_STAY,
    steady_transition,
    validate_transition,
)

METHODS = (
    "cnn",
    "cnn+voting",
    "hmm",
    "hmm+voting",
    "forward",
    "fixed-lag",
    "steady",
    "steady+gait",
    "steady+hysteresis",
    "steady+geometry",
)

_INF = float("inf")


@dataclass(slots=True)
class FusionOutput:
    """What one push (or flush) made known.

    `frame`/`decision`: the decision of the method's first stage (argmax, HMM smooth state,
    filter, smoother) and the frame it refers to; `push` returns None until the first
    decision exists, so these are set in every pushed output (None only in flush outputs
    that carry nothing but votes).
    `probabilities` (`posterior` as an array): the method's distribution for
    `posterior_frame`. For the HMM that is the smoothed p(s_t) of the newest frame
    (Algorithm 1's second output), one frame after `frame`; for the others, `frame`.
    `voted`/`voted_frame`: the vote, for methods with voting, once its window is complete.
    """

    frame: int | None
    decision: int | None
    posterior_frame: int | None = None
    probabilities: tuple[float, ...] | None = None
    voted: int | None = None
    voted_frame: int | None = None

    @property
    def frame_index(self) -> int | None:  # the name capture's session uses
        return self.frame

    @property
    def voted_frame_index(self) -> int | None:
        return self.voted_frame

    @property
    def posterior(self) -> np.ndarray | None:
        # Built on demand: an array per frame would cost more than the fusion update.
        return None if self.probabilities is None else np.array(self.probabilities)


class Fusion(Protocol):
    """A streaming fusion method (see the module docstring)."""

    method: str
    delay_frames: int  # frames between a frame's arrival and its final decision
    votes: bool  # the final decision is `voted` (else `decision`)

    def push(self, probabilities: np.ndarray | Sequence[float]) -> FusionOutput | None: ...

    def flush(self) -> list[FusionOutput]: ...

    def reset(self) -> None: ...


# ---------------------------------------------------------------------------------------
# streaming methods


def _row(probabilities) -> list[float]:
    """The frame's probabilities as 5 Python floats (the fast path), checked cheaply."""
    e = (
        probabilities.tolist()
        if isinstance(probabilities, np.ndarray)
        else [float(x) for x in probabilities]
    )
    if len(e) != N_MODES:
        raise InferenceError(f"fusion: expected {N_MODES} probabilities, got {len(e)}")
    total = e[0] + e[1] + e[2] + e[3] + e[4]
    if not 0.0 < total < _INF or min(e) < 0.0:
        raise InferenceError(f"fusion: not a probability vector: {e}")
    return e


def _mode(decisions: Iterable[int]) -> int:
    counts = [0] * N_MODES
    for d in decisions:
        counts[d] += 1
    return counts.index(max(counts))  # ties: smallest index, as MATLAB's mode()


class Voter:
    """Voting: the mode of decisions over frames f-l_v..f+l_v, streamed.

    Feed decisions in frame order; the vote for frame f is returned with decision f+l_v.
    """

    def __init__(self, vote_delay: int):
        if vote_delay < 0:
            raise InferenceError(f"vote delay must be >= 0, got {vote_delay}")
        self.vote_delay = vote_delay
        self._recent: deque[int] = deque(maxlen=2 * vote_delay + 1)
        self._next = 0  # the frame of the next decision
        self._unvoted = 0  # the first frame without a vote

    def reset(self) -> None:
        self._recent.clear()
        self._next = self._unvoted = 0

    def push(self, frame: int, decision: int) -> tuple[int, int] | None:
        """(voted frame, vote) once frame - l_v has its full window, else None."""
        if frame != self._next:
            raise InferenceError(f"voting: expected frame {self._next}, got {frame}")
        self._next += 1
        self._recent.append(decision)
        voted_frame = frame - self.vote_delay
        if voted_frame < 0:
            return None
        self._unvoted = voted_frame + 1
        # The deque holds frames max(0, f-l_v)..f+l_v: the window, cut at the start.
        return voted_frame, _mode(self._recent)

    def flush(self) -> list[tuple[int, int]]:
        """Votes of the frames still waiting, over windows cut at the end of the sequence."""
        lv, n = self.vote_delay, self._next
        recent = list(self._recent)
        first = n - len(recent)  # the frame of recent[0]
        votes = [(f, _mode(recent[max(0, f - lv) - first :])) for f in range(self._unvoted, n)]
        self._unvoted = n
        return votes


class _Stream:
    """Frame counting, voting and the end-of-sequence flag shared by every method."""

    method: str
    delay_frames: int

    def __init__(self, vote_delay: int | None):
        self.votes = vote_delay is not None
        self._voter = Voter(vote_delay) if vote_delay is not None else None
        self._frame = 0  # frames pushed so far
        self._flushed = False

    def reset(self) -> None:
        self._frame = 0
        self._flushed = False
        if self._voter is not None:
            self._voter.reset()
        self._reset_state()

    def _reset_state(self) -> None:
        raise NotImplementedError

    def _check_open(self) -> None:
        if self._flushed:
            raise InferenceError(f"{self.method}: the sequence was flushed; reset() first")

    def _vote_outputs(self) -> list[FusionOutput]:
        if self._voter is None:
            return []
        return [FusionOutput(None, None, voted=v, voted_frame=f) for f, v in self._voter.flush()]


class ArgmaxFusion(_Stream):
    """The CNN alone ("cnn"), or with voting ("cnn+voting")."""

    def __init__(self, vote_delay: int | None = None):
        super().__init__(vote_delay)
        self.method = "cnn" if vote_delay is None else "cnn+voting"
        self.delay_frames = vote_delay or 0

    def _reset_state(self) -> None:
        pass

    def push(self, probabilities) -> FusionOutput:
        self._check_open()
        e = _row(probabilities)
        t = self._frame
        self._frame = t + 1
        decision = e.index(max(e))
        out = FusionOutput(t, decision, t, tuple(e))
        if self._voter is not None:
            vote = self._voter.push(t, decision)
            if vote is not None:
                out.voted_frame, out.voted = vote
        return out

    def flush(self) -> list[FusionOutput]:
        if self._flushed:
            return []
        self._flushed = True
        return self._vote_outputs()


class HmmFusion(_Stream):
    """Algorithm 1, the modified Viterbi update, optionally followed by voting.

    Pushing frame t (t >= 1) returns the smooth state s_opt(t-1) (`frame` t-1, `decision`) and the
    normalised p(s_t) (`posterior_frame` t). Pure-Python floats: a 5x5 update is faster
    without numpy's per-call overhead (see `bench_fusion`).
    """

    def __init__(self, window: int = 5, transition=PAPER_TRANSITION, vote_delay: int | None = None):
        if int(window) != window or window < 1:
            raise InferenceError(f"fusion window l_w must be an integer >= 1, got {window}")
        super().__init__(vote_delay)
        self.method = "hmm" if vote_delay is None else "hmm+voting"
        self.delay_frames = 1 + (vote_delay or 0)
        self.window = int(window)
        self.transition = validate_transition(transition)
        self._rows = tuple(tuple(r) for r in self.transition.tolist())
        self._smooth: deque[tuple[float, ...]] = deque(maxlen=self.window)  # p(s_k), last l_w

    def _reset_state(self) -> None:
        self._smooth.clear()

    def push(self, probabilities) -> FusionOutput | None:
        if self._flushed:
            self._check_open()
        e0, e1, e2, e3, e4 = _row(probabilities)
        t = self._frame
        self._frame = t + 1
        smooth = self._smooth
        lw = self.window
        if t < lw:  # initialise: p(s_t) = p(x_t | z_t)
            p = (e0, e1, e2, e3, e4)
            decision = None
            if t > 0:
                last = smooth[-1]
                decision = last.index(max(last))
        else:
            # mean of p(s_k) over k = t-l_w..t-1 (row by row, as numpy's sum(axis=0))
            a0 = a1 = a2 = a3 = a4 = 0.0
            for r in smooth:
                a0 += r[0]
                a1 += r[1]
                a2 += r[2]
                a3 += r[3]
                a4 += r[4]
            pbar = (a0 / lw, a1 / lw, a2 / lw, a3 / lw, a4 / lw)
            # posterior of the last smooth state: pbar_i * sum_j t_ij p(x_t | z_t = j)
            r0, r1, r2, r3, r4 = self._rows
            h = (
                pbar[0] * (r0[0] * e0 + r0[1] * e1 + r0[2] * e2 + r0[3] * e3 + r0[4] * e4),
                pbar[1] * (r1[0] * e0 + r1[1] * e1 + r1[2] * e2 + r1[3] * e3 + r1[4] * e4),
                pbar[2] * (r2[0] * e0 + r2[1] * e1 + r2[2] * e2 + r2[3] * e3 + r2[4] * e4),
                pbar[3] * (r3[0] * e0 + r3[1] * e1 + r3[2] * e2 + r3[3] * e3 + r3[4] * e4),
                pbar[4] * (r4[0] * e0 + r4[1] * e1 + r4[2] * e2 + r4[3] * e3 + r4[4] * e4),
            )
            decision = h.index(max(h))
            # the current smooth state given s_opt(t-1), normalised
            c = pbar[decision]
            r = self._rows[decision]
            q0 = c * r[0] * e0
            q1 = c * r[1] * e1
            q2 = c * r[2] * e2
            q3 = c * r[3] * e3
            q4 = c * r[4] * e4
            z = q0 + q1 + q2 + q3 + q4
            p = (q0 / z, q1 / z, q2 / z, q3 / z, q4 / z)
        smooth.append(p)
        if decision is None:  # frame 0: nothing to decide yet (p(s_0) is the CNN's output)
            return None
        out = FusionOutput(t - 1, decision, t, p)
        if self._voter is not None:
            vote = self._voter.push(t - 1, decision)
            if vote is not None:
                out.voted_frame, out.voted = vote
        return out

    def flush(self) -> list[FusionOutput]:
        """Decide the last frame as argmax of its p(s_t) (it has no next frame), then votes."""
        if self._flushed:
            return []
        self._flushed = True
        outputs = []
        if self._frame > 0:
            last = self._smooth[-1]
            frame, decision = self._frame - 1, last.index(max(last))
            out = FusionOutput(frame, decision)
            if self._voter is not None:
                vote = self._voter.push(frame, decision)
                if vote is not None:
                    out.voted_frame, out.voted = vote
            outputs.append(out)
        return outputs + self._vote_outputs()


class ForwardFilter(_Stream):
    """Standard HMM forward filter: argmax p(z_t | x_1..x_t), uniform prior (delay 0)."""

    def __init__(self, transition=PAPER_TRANSITION):
        super().__init__(None)
        self.method = "forward"
        self.delay_frames = 0
        self.transition = validate_transition(transition)
        self._alpha: np.ndarray | None = None

    def _reset_state(self) -> None:
        self._alpha = None

    def push(self, probabilities) -> FusionOutput:
        self._check_open()
        e = np.array(_row(probabilities))
        t = self._frame
        self._frame = t + 1
        prior = (
            np.full(N_MODES, 1.0 / N_MODES)
            if self._alpha is None
            else self._alpha @ self.transition
        )
        alpha = prior * e
        self._alpha = alpha = alpha / alpha.sum()
        return FusionOutput(t, int(np.argmax(alpha)), t, tuple(alpha.tolist()))

    def flush(self) -> list[FusionOutput]:
        self._flushed = True
        return []


class FixedLagSmoother(_Stream):
    """Standard HMM fixed-lag smoother: argmax p(z_{t-lag} | x_1..x_t) (delay lag).

    `flush` smooths the last frames with the future that exists.
    """

    def __init__(self, transition=PAPER_TRANSITION, lag: int = 1):
        if lag < 0:
            raise InferenceError(f"smoother lag must be >= 0, got {lag}")
        super().__init__(None)
        self.method = "fixed-lag"
        self.lag = self.delay_frames = int(lag)
        self.transition = validate_transition(transition)
        self._alphas: deque[np.ndarray] = deque(maxlen=self.lag + 1)
        self._emissions: deque[np.ndarray] = deque(maxlen=self.lag + 1)

    def _reset_state(self) -> None:
        self._alphas.clear()
        self._emissions.clear()

    def _smoothed(self, back: int) -> np.ndarray:
        """p(z | all pushed frames) for the frame `back` frames before the newest."""
        beta = np.ones(N_MODES)
        for k in range(1, back + 1):  # newest frame first
            beta = self.transition @ (self._emissions[-k] * beta)
            beta /= beta.sum()
        gamma = self._alphas[-1 - back] * beta
        return gamma / gamma.sum()

    def push(self, probabilities) -> FusionOutput | None:
        self._check_open()
        e = np.array(_row(probabilities))
        t = self._frame
        self._frame = t + 1
        prior = (
            np.full(N_MODES, 1.0 / N_MODES)
            if not self._alphas
            else self._alphas[-1] @ self.transition
        )
        alpha = prior * e
        self._alphas.append(alpha / alpha.sum())
        self._emissions.append(e)
        if t < self.lag:
            return None
        gamma = self._smoothed(self.lag)
        return FusionOutput(
            t - self.lag, int(np.argmax(gamma)), t - self.lag, tuple(gamma.tolist())
        )

    def flush(self) -> list[FusionOutput]:
        if self._flushed:
            return []
        self._flushed = True
        outputs = []
        n = self._frame
        for frame in range(max(0, n - self.lag), n):
            gamma = self._smoothed(n - 1 - frame)
            outputs.append(FusionOutput(frame, int(np.argmax(gamma)), frame, tuple(gamma.tolist())))
        return outputs


class SteadyFusion(_Stream):
    """ "steady": the fixed-lag-1 smoother p(z_{t-1} | x_1..x_t) of an HMM built to switch
    once per terrain change (delay 1 frame).

    The HMM: `steady_transition(stay)` (the paper's rules, a stay from walking) and the
    CNN's probabilities raised to `evidence` as the emission likelihood (see the design
    notes in inference.fusion_design). Frame t-1 is decided when frame t arrives: alpha_{t-1} (the
    filter) times T e_t (one frame of look-ahead), normalised; `flush` decides the last
    frame by its filter. Pure-Python floats, unrolled: one update in a few microseconds.
    """

    uses_gait = False  # push takes the frame's camera elevation too (GaitSteadyFusion)

    def __init__(self, stay: float = STEADY_STAY, evidence: float = STEADY_EVIDENCE):
        if not 0.0 < evidence <= 1.0:
            raise InferenceError(f"steady: evidence must be in (0, 1], got {evidence}")
        super().__init__(None)
        self.method = "steady"
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
        e0, e1, e2, e3, e4 = (x**b for x in _row(probabilities))
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


class GaitSteadyFusion(SteadyFusion):
    """ "steady+gait": steady whose chance of leaving a mode follows the gait phase.

    `push(probabilities, elevation_deg)`: the camera's optical axis above the horizon at
    the frame (inference.preprocess; it follows the thigh). The frame-to-frame change of
    it, in running standard deviations, tells the phase: below GAIT_PHASE_SD (the camera
    pitching down) leaving a mode is GAIT_LEAVE[0] times as likely as steady's average,
    otherwise GAIT_LEAVE[1] times (see the design notes there). Without an elevation (no
    IMU orientation) the frame uses steady's own transition.
    """

    uses_gait = True

    def __init__(self, stay: float = STEADY_STAY, evidence: float = STEADY_EVIDENCE):
        super().__init__(stay, evidence)
        self.method = "steady+gait"
        leave = 1.0 - self.stay
        self._phase_rows = tuple(
            tuple(tuple(r) for r in steady_transition(1.0 - leave * g).tolist()) for g in GAIT_LEAVE
        )
        self._last_elevation = math.nan
        self._rate_var = 1.0  # deg^2 a frame: a start that a second of walking replaces

    def _reset_state(self) -> None:
        super()._reset_state()
        self._last_elevation = math.nan
        self._rate_var = 1.0

    def push(self, probabilities, elevation_deg: float | None = None) -> FusionOutput | None:
        rows = self._rows
        e = math.nan if elevation_deg is None else float(elevation_deg)
        change = e - self._last_elevation
        if e == e:  # not NaN
            self._last_elevation = e
        if change == change:
            var = self._rate_var
            var += (change * change - var) / GAIT_RATE_FRAMES
            self._rate_var = var
            in_phase = change <= GAIT_PHASE_SD * math.sqrt(var)
            rows = self._phase_rows[0 if in_phase else 1]
        return self._update(probabilities, rows)


class HysteresisFusion(SteadyFusion):
    """ "steady+hysteresis": steady's posterior, with a switch margin (delay 1 frame).

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
            raise InferenceError(f"steady+hysteresis: margin must be in [0, 1), got {hysteresis}")
        super().__init__(stay, evidence)
        self.method = "steady+hysteresis"
        self.hysteresis = float(hysteresis)
        self._held = -1  # the last decision; -1 before the first

    def _reset_state(self) -> None:
        super()._reset_state()
        self._held = -1

    def _hold(self, out: FusionOutput) -> FusionOutput:
        g, d = out.probabilities, out.decision
        held = self._held
        if held < 0 or d != 0 or held == 0 or g[d] >= self.hysteresis:  # 0: level ground
            held = self._held = d
        out.decision = held
        return out

    def push(self, probabilities) -> FusionOutput | None:
        out = self._update(probabilities, self._rows)
        return None if out is None else self._hold(out)

    def flush(self) -> list[FusionOutput]:
        return [self._hold(out) for out in super().flush()]


class GeometryFusion(HysteresisFusion):
    """ "steady+geometry": steady+hysteresis with the terrain features as a second
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
            raise InferenceError(
                f"steady+geometry: geometry evidence must be in (0, 1], got {geometry_evidence}"
            )
        super().__init__(stay, evidence, hysteresis)
        self.method = "steady+geometry"
        self.geometry_evidence = float(geometry_evidence)
        # per shown mode (the last: unknown), the likelihood of each terrain
        self._shown = tuple(
            tuple(GEOMETRY_SHOWN[mode][g] ** self.geometry_evidence for mode in range(N_MODES))
            for g in range(N_MODES + 1)
        )

    def see_geometry(self, mode: int) -> None:
        """The mode the newest pushed frame's terrain features show (-1: unknown)."""
        a = self._alpha
        if a is None or self._flushed:
            return
        w = self._shown[mode if 0 <= mode < N_MODES else N_MODES]
        q = (a[0] * w[0], a[1] * w[1], a[2] * w[2], a[3] * w[3], a[4] * w[4])
        z = q[0] + q[1] + q[2] + q[3] + q[4]
        self._alpha = (q[0] / z, q[1] / z, q[2] / z, q[3] / z, q[4] / z)


def make_fusion(
    method: str,
    window: int = 5,
    vote_delay: int = 1,
    transition=PAPER_TRANSITION,
    lag: int = 1,
    stay: float = STEADY_STAY,
    evidence: float = STEADY_EVIDENCE,
    hysteresis: float = HYSTERESIS,
    geometry_hysteresis: float = GEOMETRY_HYSTERESIS,
    geometry_evidence: float = GEOMETRY_EVIDENCE,
) -> Fusion:
    """A fresh streaming fusion object; `lag` is used by "fixed-lag" only, `stay` and
    `evidence` by the "steady" methods only, `hysteresis` by "steady+hysteresis" only,
    `geometry_*` by "steady+geometry" only."""
    if int(vote_delay) != vote_delay or vote_delay < 0:
        raise InferenceError(f"vote delay l_v must be an integer >= 0, got {vote_delay}")
    if method == "cnn":
        return ArgmaxFusion()
    if method == "cnn+voting":
        return ArgmaxFusion(int(vote_delay))
    if method == "hmm":
        return HmmFusion(window, transition)
    if method == "hmm+voting":
        return HmmFusion(window, transition, int(vote_delay))
    if method == "forward":
        return ForwardFilter(transition)
    if method == "fixed-lag":
        return FixedLagSmoother(transition, lag)
    if method == "steady":
        return SteadyFusion(stay, evidence)
    if method == "steady+gait":
        return GaitSteadyFusion(stay, evidence)
    if method == "steady+hysteresis":
        return HysteresisFusion(stay, evidence, hysteresis)
    if method == "steady+geometry":
        return GeometryFusion(stay, evidence, geometry_hysteresis, geometry_evidence)
    raise InferenceError(f"unknown fusion method {method!r} (known: {', '.join(METHODS)})")
