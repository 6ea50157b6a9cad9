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
- "steady+slope": steady, except that it leaves a ramp for level ground only at
  steady+hysteresis's margin, and a ramp down only once the ground about a step ahead
  (the terrain features' slope there, `see_geometry`) has stopped sloping down
  (`SlopeFusion`; delay 1).
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

from collections import deque

import numpy as np

from inference.errors import InferenceError
from inference.fusion_base import (
    Fusion,
    FusionOutput,
    Stream,
    Voter,
    probability_row,
)
from inference.fusion_design import (
    GEOMETRY_EVIDENCE,
    GEOMETRY_HYSTERESIS,
    HYSTERESIS,
    N_MODES,
    PAPER_TRANSITION,
    STEADY_EVIDENCE,
    STEADY_STAY,
    validate_transition,
)
from inference.fusion_steady import (
    GaitSteadyFusion,
    GeometryFusion,
    HysteresisFusion,
    SlopeFusion,
    SteadyFusion,
)

__all__ = [
    "METHODS",
    "N_MODES",
    "ArgmaxFusion",
    "FixedLagSmoother",
    "ForwardFilter",
    "Fusion",
    "FusionOutput",
    "GaitSteadyFusion",
    "GeometryFusion",
    "HmmFusion",
    "HysteresisFusion",
    "SlopeFusion",
    "SteadyFusion",
    "Voter",
    "make_fusion",
]

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
    "steady+slope",
)


class ArgmaxFusion(Stream):
    """The CNN alone ("cnn"), or with voting ("cnn+voting")."""

    def __init__(self, vote_delay: int | None = None):
        super().__init__(vote_delay)
        self.method = "cnn" if vote_delay is None else "cnn+voting"
        self.delay_frames = vote_delay or 0

    def _reset_state(self) -> None:
        pass

    def push(self, probabilities) -> FusionOutput:
        self._check_open()
        e = probability_row(probabilities)
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


class HmmFusion(Stream):
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
        e0, e1, e2, e3, e4 = probability_row(probabilities)
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


class ForwardFilter(Stream):
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
        e = np.array(probability_row(probabilities))
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


class FixedLagSmoother(Stream):
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
        e = np.array(probability_row(probabilities))
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
    `evidence` by the "steady" methods only, `hysteresis` by "steady+hysteresis" and
    "steady+slope" only,
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
    if method == "steady+slope":
        return SlopeFusion(stay, evidence, hysteresis)
    raise InferenceError(f"unknown fusion method {method!r} (known: {', '.join(METHODS)})")
