"""What the fusion methods' HMMs are built from: transition matrices and the designed
parameters of the steady methods (inference.fusion runs them).

The transition matrix follows the paper's six rules (`design_transition`; the authors'
numbers are `PAPER_TRANSITION`), or is counted from labelled sequences
(`estimate_transition`); `paper_step` is Algorithm 1's update as the paper writes it.
Every designed number here comes from walking or from simulated design recordings (seeds
900000-900011 and 910000-910011), never from a data set a figure is reported on.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from devices.frames import MODES
from inference.errors import InferenceError

N_MODES = len(MODES)


# The authors' transition matrix (rows: from, columns: to; LG, US, DS, UR, DR), as in
# Zhang et al., "Sequential Decision Fusion for Environmental Classification in Assistive
# Walking", IEEE TNSRE 2019; the configuration's default.
PAPER_TRANSITION = np.array(
    [
        [0.80, 0.05, 0.05, 0.05, 0.05],
        [0.15, 0.80, 0.01, 0.03, 0.01],
        [0.15, 0.01, 0.80, 0.01, 0.03],
        [0.15, 0.03, 0.01, 0.80, 0.01],
        [0.15, 0.01, 0.03, 0.01, 0.80],
    ]
)

# SteadyFusion's design, from walking, not from any data set it is evaluated on:
# - a terrain lasts about a flight of stairs or a ramp: some 8 steps, 4.6 s at 105 steps a
#   minute; so about 5 s, and at the paper's 15 fps a frame stays in its mode with
#   probability 1 - 1/(15 * 5) = 0.987;
# - the CNN's errors come in runs (swing blur, a foot in view): 1.34 frames on average on
#   12 simulated recordings (`walkcap synth --format recording --sessions 12 --seed
#   900000`), so one frame carries about 1/1.34 = 0.75 of an independent frame's
#   evidence: its probabilities enter raised to the power 0.75.
TERRAIN_DWELL_S = 5.0
STEADY_EVIDENCE = 0.75


def walking_stay(fps: float = 15.0, dwell_s: float = TERRAIN_DWELL_S) -> float:
    """The per-frame probability of staying in a mode held `dwell_s` on average."""
    return 1.0 - 1.0 / (fps * dwell_s)


STEADY_STAY = round(walking_stay(), 3)  # 0.987 at 15 fps

# GaitSteadyFusion: on the same 12 simulated recordings, 84 % of the terrain changes (settled,
# inference.evaluation.transitions) came while the camera pitched up faster than 0.75 standard
# deviations of its frame-to-frame pitch change (the thigh swinging forward, the view reaching
# ahead), in 31 % of the frames; so a change is 0.84 / 0.31 = 2.7 times likelier than average
# in that phase and 0.16 / 0.69 = 0.24 times outside it. The CNN's errors start at any phase
# (37 % in it). The camera's elevation is the preprocessing's, as /tf records it.
GAIT_PHASE_SD = 0.75  # the phase: pitch change above this many standard deviations
GAIT_LEAVE = (2.7, 0.24)  # leaving a mode, times the average: in the phase, outside it
GAIT_RATE_FRAMES = 15  # the pitch change's variance: running over about a second

# HysteresisFusion: the CNN's misreads outdoors (level ground on a ramp or stairs) come in
# runs of 1 frame up to about a step (13 frames at 15 fps) read with a middling
# probability: 0.73 on average, 0.58-0.89 for 80 % of the runs (`walkcap synth --format
# recording --sessions 12 --seed 900000`), and steady's posterior follows the longer runs.
# A change to level ground is read at 0.86 (median over its first 4 frames) as the new
# terrain fills the view. So a switch from stairs or a ramp to level ground needs level
# ground's posterior at 4 to 1 against all the others together: 0.8. The other switches
# (onto stairs or a ramp, between them) keep steady's timing: the CNN rarely reads stairs or
# a ramp on level ground, and a margin there only delays real changes, which costs
# accuracy where the terrain flickers near a change. On separate simulated sessions
# (`--sessions 12 --preset outdoor --seed 910000`) this halves Algorithm 1's spurious
# switches outdoors at steady's accuracy and median switch delay (1 frame); the same
# margin on every switch costs 0.4 points of accuracy; a margin of 0.7 leaves more than half
# of them (2.3 a minute against 3.6).
HYSTERESIS = 0.8


# GeometryFusion: the terrain features (inference.features) as a second observation of
# each frame. How often the features show each terrain (columns: level ground, stairs up,
# stairs down, ramp up, ramp down, unknown; inference.features.shown_mode) on each one
# (rows, the terrain the image shows), counted on the 24 design recordings (`walkcap synth
# --format recording --sessions 12 --seed 900000` and `--sessions 12 --preset outdoor
# --seed 910000`, exported with `walkcap export --format csv`; 7,839 decided frames,
# add-one). Stairs and ramps show as themselves 84-97 % of the time, stairs down least
# (their nosings hide the risers); level ground shows as stairs up a fifth of the time
# (outdoors, a curb in view is one riser).
GEOMETRY_SHOWN = (
    (0.658, 0.205, 0.098, 0.014, 0.013, 0.012),
    (0.010, 0.965, 0.001, 0.007, 0.003, 0.014),
    (0.021, 0.124, 0.737, 0.004, 0.034, 0.080),
    (0.010, 0.043, 0.001, 0.932, 0.001, 0.012),
    (0.026, 0.026, 0.099, 0.001, 0.840, 0.009),
)
# The features' misreads come in runs of 2.7 frames on average on the same recordings (a
# riser stays in view over several frames), so one frame's geometry carries about 1/2.7 of
# an independent observation: its likelihood enters raised to the power 0.36.
GEOMETRY_EVIDENCE = 0.36
# With the geometry in the posterior, the switch from stairs or a ramp to level ground needs
# level ground's posterior at 3 to 2: the lowest margin at which the design recordings'
# spurious switches outdoors fall to half of Algorithm 1's (24 there; 13 at 0.5, 11 at
# 0.6); each step above costs accuracy indoors, where real changes to level ground are
# read at a middling posterior for a frame or two.
GEOMETRY_HYSTERESIS = 0.6

# SlopeFusion: HysteresisFusion's remaining spurious switches outdoors are mostly runs of level
# ground read on a ramp down, some at 0.9-1.0, where the CNN's probabilities and the features' kind
# cannot outweigh them. The slope of the fitted ground about a step ahead (inference.features:
# AHEAD_M, beyond FLAT_MAX_DEG) keeps showing a ramp down through such runs: on GeometryFusion's 24
# design recordings above it shows one in 96 % of the frames on a ramp down where it is seen,
# indoors and outdoors (the kind: 90 and 82 %), and on level ground in 3 % indoors and 15 % outdoors
# (uneven ground, the IMU's error of a session; the kind shows a ramp down in 0 and 2 %), so the cue
# only ever holds a ramp down, never starts one. Leaving a ramp down for level ground needs the
# ground ahead not to have shown a ramp down in the last 3 frames (a frame's slope drops out where
# the profile has a gap, or reads a bump; on the design recordings 2 frames leave more spurious
# switches, 6 or more miss a real change). A ramp up is not held: at its top the ground ahead shows
# the ramp for a frame or two after the image shows level ground (the crest). Leaving a ramp keeps
# HysteresisFusion's margin; stairs are left as steady leaves them (their landings indoors show the
# next flight, and with ramps held a margin on stairs removed no spurious switch on the design
# recordings). Designed on 72 simulated recordings (`walkcap synth --format recording --sessions 12
# --seed 900000`, `--sessions 12 --preset outdoor --seed 910000`, `--sessions 24 --preset outdoor
# --seed 920000` and `--sessions 24 --preset indoor --seed 940000`; 0.75 or 1.0 m ahead, 3 or 5
# degrees, 1-10 frames, margins 0-0.9, which ramps and stairs are held): outdoors 6 and 9 spurious
# switches against Algorithm 1's 24 and 33, at 96.65 and 97.01 against 95.78 and 96.04 % accuracy;
# indoors 97.90 and 97.68 against 97.51 and 97.28 %.
SLOPE_HOLD_FRAMES = 3


# MarginFusion ("steady+margins"): a score-only method for a classifier whose errors come
# as a real one's do (devices/simulator/walk.py, docs/simulator.md "Classifier errors"):
# mostly unsure runs, which steady's prior outlasts, and a few sure runs of a few frames
# where the image shows a terrain that is not there, level ground most often. Every switch
# needs the new mode's posterior (steady's, with its stay and evidence) at a margin: into
# level ground MARGINS' 0.9 (9 to 1 against the others together), into stairs or a ramp
# 0.7. Designed on 48 simulated recordings with the bundled model (`walkcap synth --format
# recording --sessions 12 --preset indoor --seed 960000`, `--seed 961000`, and `--preset
# outdoor` `--seed 970000`, `--seed 971000`): a sweep over stay (0.987, 0.993), evidence
# (0.75, 0.9), margins into level ground (0.8, 0.9), ramps (0.5-0.9) and stairs (0.5,
# 0.7), keeping frame accuracy within 0.3 points of Algorithm 1's, to the fewest spurious
# switches a minute in the worse condition: 3.27 indoors and 2.53 outdoors against
# Algorithm 1's 7.70 and 4.84, at 0.13 points below Algorithm 1's accuracy. Margins of 0.8
# into a ramp and 0.5 into stairs tie with it (the same worse condition, the accuracy to
# a hundredth of a point); one margin for every terrain but level ground is the simpler.
MARGINS = (0.9, 0.7, 0.7, 0.7, 0.7)  # by the mode switched to: LG, US, DS, UR, DR


def steady_transition(stay: float = STEADY_STAY) -> np.ndarray:
    """The paper's transition rules and proportions (of what leaves a non-level mode, 75 %
    goes to level ground, 15 % to the same direction, 5 % to each opposite one; level
    ground leaves equally) with the stay probability `stay`."""
    return design_transition(stay, 0.75 * (1.0 - stay), 0.15 * (1.0 - stay))


# Algorithm 1's update as the paper writes it, in numpy: the benchmark's baseline for the
# streaming HmmFusion and the tests' reference.
def paper_step(
    smooth_window: np.ndarray, emission: np.ndarray, transition: np.ndarray, window: int
) -> tuple[int, np.ndarray]:
    """One iteration of Algorithm 1 in numpy: (s_opt(t-1), p(s_t))."""
    pbar = smooth_window.sum(axis=0) / window
    phat_last = pbar * (transition @ emission)
    s_opt = int(np.argmax(phat_last))
    phat = pbar[s_opt] * transition[s_opt] * emission
    return s_opt, phat / phat.sum()


def validate_transition(matrix, name: str = "transition") -> np.ndarray:
    """A 5x5 row-stochastic matrix with positive entries, as float64; else InferenceError."""
    try:
        t = np.array(matrix, dtype=float)
    except (TypeError, ValueError):
        raise InferenceError(f"{name}: expected 5 rows of 5 numbers") from None
    if t.shape != (N_MODES, N_MODES):
        raise InferenceError(
            f"{name}: expected 5 rows of 5 numbers ({', '.join(MODES)}), got shape {t.shape}"
        )
    if not np.all(np.isfinite(t)) or np.any(t <= 0):
        raise InferenceError(
            f"{name}: every entry must be a positive number (a zero transition could never be left)"
        )
    for i, row in enumerate(t):
        if abs(row.sum() - 1.0) > 1e-3:
            raise InferenceError(f"{name}: row {MODES[i]} sums to {row.sum():.4g}, expected 1")
    return t


def design_transition(
    stay: float = 0.80, to_level: float = 0.15, same_direction: float = 0.03
) -> np.ndarray:
    """The transition matrix from the paper's six rules, as a function of three numbers.

    stay: t_ii for every mode (rules 1, 2); leaving level ground is split equally over the
    four other modes (rule 3); to_level: from any non-level mode to LG (rule 4);
    same_direction: between US and UR or DS and DR (|i-j| even, rule 5); the rest of each
    row goes equally to the two opposite-direction modes (|i-j| odd, the lowest, rule 6).
    The defaults give the authors' matrix.
    """
    opposite = (1.0 - stay - to_level - same_direction) / 2.0
    leave_level = (1.0 - stay) / (N_MODES - 1)
    if min(stay, to_level, same_direction, opposite, leave_level) <= 0:
        raise InferenceError(
            "transition design: every probability must be positive "
            f"(stay={stay}, to_level={to_level}, "
            f"same_direction={same_direction}, opposite={opposite:.4g})"
        )
    if stay <= max(to_level, same_direction, leave_level):
        raise InferenceError("transition design: staying must be more likely than any change")
    if same_direction <= opposite:
        raise InferenceError(
            "transition design: same-direction changes must be more likely "
            f"than opposite-direction ones ({same_direction} <= {opposite:.4g})"
        )
    t = np.empty((N_MODES, N_MODES))
    t[0, :] = leave_level
    t[1:, 0] = to_level
    for i in range(1, N_MODES):
        for j in range(1, N_MODES):
            if i == j:
                continue
            t[i, j] = same_direction if (i - j) % 2 == 0 else opposite
    np.fill_diagonal(t, stay)
    return t


def mode_indices(labels: Iterable) -> np.ndarray:
    """Labels as mode indices: names ("LG") or ints; None, "" or -1 mean unlabeled (-1)."""
    out = []
    for label in labels:
        if label is None or label == "":
            out.append(-1)
        elif isinstance(label, str):
            if label not in MODES:
                raise InferenceError(f"unknown mode {label!r} (expected one of {', '.join(MODES)})")
            out.append(MODES.index(label))
        else:
            index = int(label)
            if not -1 <= index < N_MODES:
                raise InferenceError(f"mode index {index} out of range 0..{N_MODES - 1}")
            out.append(index)
    return np.array(out, dtype=int)


def estimate_transition(label_sequences: Iterable[Iterable], smoothing: float = 1.0) -> np.ndarray:
    """Transition probabilities counted from labeled frame sequences, additively smoothed.

    Pairs of consecutive frames count when both are labeled. Note that per-frame counts at
    15 fps give a much higher stay probability than the authors' designed 0.80.
    """
    if smoothing <= 0:
        raise InferenceError("transition estimate: smoothing must be positive")
    counts = np.zeros((N_MODES, N_MODES))
    for labels in label_sequences:
        z = mode_indices(labels)
        a, b = z[:-1], z[1:]
        keep = (a >= 0) & (b >= 0)
        np.add.at(counts, (a[keep], b[keep]), 1.0)
    counts += smoothing
    return counts / counts.sum(axis=1, keepdims=True)


# StepFusion (inference.fusion_steps): a mode changes at a step. A prosthesis needs the
# old mode at the heel contact of the last step on the old terrain and the new one from the
# toe off after it (the swing onto the new terrain): so the change belongs just after that
# heel contact. The camera sees the new terrain earlier, by how far ahead it looks when the
# image shows the change, and steady+hysteresis's switch comes some way before the
# transition step's heel contact. Its proposal is therefore scheduled at a heel contact: it
# waits round(phase + STEP_OFFSET[old][new] + STEP_ELEVATION * (elevation -
# STEP_ELEVATION_REF_DEG)) heel contacts (0 or fewer: at once), where phase is the strides
# since the last heel contact and elevation the camera's at the proposed frame (degrees
# above the horizon; /tf's). The gait phase alone places the view only roughly: how far
# ahead the camera looks at a proposal follows its elevation (the thigh's swing, the
# walker's posture, the terrain underfoot), and the farther it looks, the more steps the
# change waits. Designed on 48 simulated recordings with the bundled model (`walkcap synth
# --format recording --sessions 12 --preset indoor --seed 960000` and `--seed 961000`,
# `--preset outdoor --seed 970000` and `--seed 971000`; 328 proposals that led to a
# terrain change of the steps, each with the number of heel contacts that would have
# switched it right after the heel contact before the transition step): the elevation's
# weight that schedules the most of them so, swept over 0-0.08 strides a degree with the
# offsets fitted at each (0.03: 285 of 328 right; the phase alone, 260; fitted on one half,
# the other half's changes are 83-85 % right against 73-77 % by the phase alone), then per pair
# of terrains the middle of the widest range of offsets that schedules the most right.
# The reference elevation, -20 degrees, is near the proposals' median (-18). Off stairs down
# the proposal comes as the floor below fills the view, a step before the foot reaches it
# (1.06). Pairs the design recordings never showed take the one offset that schedules the
# most over all pairs (0.13). A proposal must hold STEP_HOLD_FRAMES decided frames first
# (a one-frame misread never schedules). The stride is the running mean of the intervals
# between heel contacts, from STEP_STRIDE_FRAMES (1.1 s at 15 fps: 105 steps a minute).
# Without a heel contact for STEP_STALL_FRAMES frames (2 s, longer than any stride at
# walking cadence) the walker stands or the detector is silent: a proposal then switches on
# the hold alone. Without an elevation (a score file, no IMU) a proposal counts as at the
# reference elevation, -20 degrees.
STEP_HOLD_FRAMES = 2
STEP_STALL_FRAMES = 30
STEP_STRIDE_FRAMES = 17.0
STEP_ELEVATION = 0.03  # strides a degree of the camera's elevation
STEP_ELEVATION_REF_DEG = -20.0
_STEP_ANY = 0.13  # a pair of terrains the design recordings never showed
STEP_OFFSET = (  # strides; rows: from, columns: to (LG, US, DS, UR, DR)
    (_STEP_ANY, 0.06, _STEP_ANY, _STEP_ANY, -0.02),
    (_STEP_ANY, _STEP_ANY, _STEP_ANY, 0.44, _STEP_ANY),
    (1.06, _STEP_ANY, _STEP_ANY, _STEP_ANY, _STEP_ANY),
    (-0.12, _STEP_ANY, _STEP_ANY, _STEP_ANY, _STEP_ANY),
    (_STEP_ANY, _STEP_ANY, 0.08, _STEP_ANY, _STEP_ANY),
)
