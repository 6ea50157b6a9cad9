"""Sequential decision fusion: the paper's modified Viterbi update (HMM), voting, baselines.

Zhang et al., "Sequential Decision Fusion for Environmental Classification in Assistive
Walking" (IEEE TNSRE 2019), Algorithm 1 and equation (voting). Every method is a streaming
object: `push` one CNN probability vector per frame (index order `devices.frames.MODES`),
get back what became known with that frame; `flush` at the end of a sequence decides the
frames still waiting for future frames. Offline evaluation runs the same objects, so live
and offline decisions are identical by construction.

Methods (one row each of `METHOD_TABLE`, built by `make_fusion`), with the number of frames
each decision waits for:
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
- "steady+margins": steady whose every switch needs the new mode's posterior at a margin
  by the mode switched to, higher into level ground than into stairs or a ramp
  (`MarginFusion`; delay 1).
- "steady+geometry": steady+hysteresis whose filter also observes each frame's terrain
  features (the mode their geometry shows, after the frame's push: `see_geometry`), so a
  riser or a slope still in view holds stairs or a ramp against a run of level-ground
  misreads (`GeometryFusion`; delay 1).
- "steady+slope": steady, except that it leaves a ramp for level ground only at
  steady+hysteresis's margin, and a ramp down only once the ground about a step ahead
  (the terrain features' slope there, `see_geometry`) has stopped sloping down
  (`SlopeFusion`; delay 1).
- "steady+steps": steady+hysteresis whose changes are timed to the steps of the
  instrumented leg (the detector's heel contacts, `see_gait`): each at the heel contact
  before the foot swings onto the new terrain, as a prosthesis changes its mode at a gait
  event; how many heel contacts a change waits follows the stride's phase and the
  frame's camera elevation, which it takes with its probabilities (`StepFusion`; delay 1).
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
from dataclasses import dataclass

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
    MarginFusion,
    SlopeFusion,
    SteadyFusion,
)
from inference.fusion_steps import StepFusion

__all__ = [
    "METHODS",
    "METHOD_TABLE",
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
    "MarginFusion",
    "Method",
    "SlopeFusion",
    "SteadyFusion",
    "StepFusion",
    "Voter",
    "fusion_method",
    "make_fusion",
]


class ArgmaxFusion(Stream):
    """The CNN alone, or with voting."""

    def __init__(self, vote_delay: int | None = None):
        super().__init__(vote_delay)
        self.delay_frames = vote_delay or 0

    def _reset_state(self) -> None:
        pass

    def push(self, probabilities) -> FusionOutput:
        self._check_open()
        e = probability_row(probabilities)
        t = self._frame
        self._frame = t + 1
        decision = e.index(max(e))
        return self._voted(FusionOutput(t, decision, t, tuple(e)))

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
        return self._voted(FusionOutput(t - 1, decision, t, p))

    def flush(self) -> list[FusionOutput]:
        """Decide the last frame as argmax of its p(s_t) (it has no next frame), then votes."""
        if self._flushed:
            return []
        self._flushed = True
        outputs = []
        if self._frame > 0:
            last = self._smooth[-1]
            frame, decision = self._frame - 1, last.index(max(last))
            outputs.append(self._voted(FusionOutput(frame, decision)))
        return outputs + self._vote_outputs()


class ForwardFilter(Stream):
    """Standard HMM forward filter: argmax p(z_t | x_1..x_t), uniform prior (delay 0)."""

    def __init__(self, transition=PAPER_TRANSITION):
        super().__init__(None)
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


# ---------------------------------------------------------------------------------------
# the methods: one row each, from which make_fusion, the CLI, the docs, eval and the plots
# take a method's name, object, title, style and parameters


@dataclass(frozen=True)
class Method:
    """One fusion method: what builds it and how every surface names and shows it."""

    name: str
    cls: type
    params: tuple[str, ...]  # cls's arguments, in order: [fusion] keys and "transition"
    title: str  # in figures, tables and the live screen
    style: dict  # in figures: grey level, hatch, marker and dash (never a mode's colour)
    doc: str  # what it decides: the docs' methods table and `eval --methods` help
    cues: tuple[str, ...] = ()  # per-frame inputs beyond the CNN's (recordings only)
    paper: bool = False  # one of the paper's four
    default: bool = False  # `walkcap eval` runs it unless --methods says otherwise
    votes_on: str | None = None  # votes over this method's decisions (`--vote-delay`)
    bench_us: float | None = None  # `walkcap bench`'s bound on one push, us

    @property
    def keys(self) -> tuple[str, ...]:
        """The [fusion] keys it takes (besides the transition matrix)."""
        return tuple(k for k in self.params if k != "transition")

    def args(self, values: dict) -> tuple:
        """cls's arguments from the [fusion] parameter `values`."""
        return tuple(int(values[k]) if k == "vote_delay" else values[k] for k in self.params)


METHOD_TABLE: tuple[Method, ...] = (
    Method(
        "cnn",
        ArgmaxFusion,
        (),
        "CNN",
        {"color": "#e4e4e4", "hatch": "", "line": "#a8a8a8", "marker": "o", "linestyle": ":"},
        "each frame's largest CNN probability, no delay",
        paper=True,
        default=True,
    ),
    Method(
        "cnn+voting",
        ArgmaxFusion,
        ("vote_delay",),
        "CNN + voting",
        {
            "color": "#bcbcbc",
            "hatch": "////",
            "hatchcolor": "#4a4a4a",
            "line": "#7c7c7c",
            "marker": "s",
            "linestyle": "-.",
        },
        "the CNN's decisions voted over `--vote-delay` frames either side",
        paper=True,
        default=True,
        votes_on="cnn",
    ),
    Method(
        "hmm",
        HmmFusion,
        ("window", "transition"),
        "HMM",
        {"color": "#6a6a6a", "hatch": "", "line": "#505050", "marker": "D", "linestyle": "--"},
        "the HMM of Zhang et al. (Algorithm 1) over a smoothing window of `--window` frames",
        paper=True,
        default=True,
    ),
    Method(
        "hmm+voting",
        HmmFusion,
        ("window", "transition", "vote_delay"),
        "HMM + voting",
        {
            "color": "#262626",
            "hatch": "////",
            "hatchcolor": "#d0d0d0",
            "line": "#000000",
            "marker": "^",
            "linestyle": "-",
        },
        "the HMM's decisions voted over `--vote-delay` frames either side (the paper's)",
        paper=True,
        default=True,
        votes_on="hmm",
    ),
    Method(
        "forward",
        ForwardFilter,
        ("transition",),
        "forward filter",
        {
            "color": "#ffffff",
            "hatch": "....",
            "line": "#606060",
            "marker": "X",
            "linestyle": (0, (1, 1)),
        },
        "the standard HMM filter",
    ),
    Method(
        "fixed-lag",
        FixedLagSmoother,
        ("transition", "lag"),
        "fixed-lag smoother",
        {
            "color": "#d8d8d8",
            "hatch": "----",
            "line": "#404040",
            "marker": "p",
            "linestyle": (0, (6, 2)),
        },
        "the standard fixed-lag HMM smoother, `--lag` frames",
    ),
    Method(
        "steady",
        SteadyFusion,
        ("stay", "evidence"),
        "steady",
        {
            "color": "#ffffff",
            "hatch": "xxxx",
            "line": "#303030",
            "marker": "v",
            "linestyle": (0, (5, 1, 1, 1)),
        },
        "an HMM whose stay probability comes from walking (`[fusion] stay`, a terrain held "
        "~5 s) and whose evidence is tempered (`[fusion] evidence`): it switches once per "
        "terrain change",
        default=True,
        bench_us=5.0,
    ),
    Method(
        "steady+gait",
        GaitSteadyFusion,
        ("stay", "evidence"),
        "steady + gait",
        {
            "color": "#949494",
            "hatch": "\\\\\\\\",
            "hatchcolor": "#000000",
            "line": "#202020",
            "marker": "P",
            "linestyle": (0, (3, 1, 1, 1, 1, 1)),
        },
        "`steady` with the gait phase from the camera's pitch: a mode changes more readily "
        "while the thigh swings forward and pitches the camera up",
        cues=("orientation",),
        bench_us=20.0,
    ),
    Method(
        "steady+hysteresis",
        HysteresisFusion,
        ("stay", "evidence", "hysteresis"),
        "steady + hysteresis",
        {
            "color": "#b4b4b4",
            "hatch": "++++",
            "hatchcolor": "#000000",
            "line": "#101010",
            "marker": "h",
            "linestyle": (0, (8, 2, 2, 2)),
        },
        "`steady` that leaves stairs or a ramp for level ground only once level ground's "
        "posterior reaches `[fusion] hysteresis`",
        default=True,
        bench_us=5.0,
    ),
    Method(
        "steady+margins",
        MarginFusion,
        ("stay", "evidence"),
        "steady + margins",
        {
            "color": "#d6d6d6",
            "hatch": "xx",
            "hatchcolor": "#202020",
            "line": "#404040",
            "marker": "X",
            "linestyle": (0, (6, 1, 1, 1, 1, 1)),
        },
        "`steady` whose every switch waits for the new mode's posterior at a margin, 0.9 into "
        "level ground (what a classifier reads most often where it is not), 0.7 into stairs "
        "or a ramp",
        default=True,
        bench_us=5.0,
    ),
    Method(
        "steady+geometry",
        GeometryFusion,
        ("stay", "evidence", "geometry_hysteresis", "geometry_evidence"),
        "steady + geometry",
        {
            "color": "#1a1a1a",
            "hatch": "oo",
            "hatchcolor": "#ffffff",
            "line": "#000000",
            "marker": "*",
            "linestyle": (0, (2, 1)),
        },
        "`steady+hysteresis` whose filter also observes the terrain features of each frame "
        "(the mode their geometry shows), with `[fusion] geometry_evidence` and "
        "`geometry_hysteresis`",
        cues=("geometry",),
        bench_us=20.0,
    ),
    Method(
        "steady+slope",
        SlopeFusion,
        ("stay", "evidence", "hysteresis"),
        "steady + slope",
        {
            "color": "#ffffff",
            "hatch": "\\\\\\\\",
            "line": "#000000",
            "marker": "<",
            "linestyle": (0, (4, 1, 1, 1, 1, 1)),
        },
        "`steady` that leaves a ramp for level ground only at `[fusion] hysteresis`, and a "
        "ramp down only once the ground a step ahead (the terrain features' slope there) has "
        "stopped sloping down for 3 frames",
        cues=("geometry",),
        bench_us=20.0,
    ),
    Method(
        "steady+steps",
        StepFusion,
        ("stay", "evidence", "hysteresis"),
        "steady + steps",
        {
            "color": "#5a5a5a",
            "hatch": "||||",
            "hatchcolor": "#ffffff",
            "line": "#2a2a2a",
            "marker": "d",
            "linestyle": (0, (1, 2)),
        },
        "`steady+hysteresis` whose changes are timed to the steps: each at the heel contact "
        "of the instrumented leg before the foot reaches the new terrain (from the detector's "
        "gait events and the stride), and dropped if the terrain read goes back before it",
        cues=("gait",),
        bench_us=20.0,
    ),
)
METHODS = tuple(m.name for m in METHOD_TABLE)
_BY_NAME = {m.name: m for m in METHOD_TABLE}


def fusion_method(name: str) -> Method:
    """The row of METHOD_TABLE named `name`."""
    try:
        return _BY_NAME[name]
    except KeyError:
        raise InferenceError(
            f"unknown fusion method {name!r} (known: {', '.join(METHODS)})"
        ) from None


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
    """A fresh streaming fusion object of `method`; each method takes the parameters
    its row's `keys` name (and the HMMs the transition matrix), the others go unused."""
    if int(vote_delay) != vote_delay or vote_delay < 0:
        raise InferenceError(f"vote delay l_v must be an integer >= 0, got {vote_delay}")
    spec = fusion_method(method)
    fusion = spec.cls(*spec.args(locals()))
    fusion.method = spec.name
    return fusion
