"""Sequential decision fusion: Algorithm 1, voting, baselines, transition matrices."""

import numpy as np
import pytest

from devices.frames import MODES
from inference.config import FusionConfig
from inference.errors import InferenceError
from inference.evaluation.metrics import FrameOutputs, accuracy, run_offline
from inference.fusion import (
    METHODS,
    FixedLagSmoother,
    ForwardFilter,
    HmmFusion,
    HysteresisFusion,
    SteadyFusion,
    Voter,
    make_fusion,
)
from inference.fusion_design import (
    PAPER_TRANSITION,
    design_transition,
    estimate_transition,
    steady_transition,
    validate_transition,
    walking_stay,
)
from tests.inference.paper_reference import paper_viterbi
from tests.scored_trials import synthetic_trial

T = PAPER_TRANSITION


def random_probabilities(rng, n, concentration=0.5):
    return rng.dirichlet(np.full(5, concentration), size=n)


def stream(fusion, probabilities):
    """Live use: push each frame, then flush; collect by frame."""
    by_frame = FrameOutputs(len(probabilities))
    for out in [fusion.push(row) for row in probabilities] + fusion.flush():
        by_frame.add(out)
    return by_frame.decisions, by_frame.voted, by_frame.posteriors


# --- transition matrices -----------------------------------------------------------------


def test_paper_matrix_is_the_authors_and_the_six_rules_with_defaults():
    np.testing.assert_array_equal(T, np.array(FusionConfig().transition))
    np.testing.assert_allclose(design_transition(), T, atol=1e-15)


def test_designed_matrix_follows_the_six_rules():
    t = design_transition(stay=0.9, to_level=0.06, same_direction=0.02)
    np.testing.assert_allclose(t.sum(axis=1), 1.0)
    off = ~np.eye(5, dtype=bool)
    assert np.all(np.diag(t)[:, None] > np.where(off, t, 0))  # rule 1
    assert np.ptp(np.diag(t)) == 0  # rule 2
    assert np.ptp(t[0, 1:]) == 0  # rule 3
    assert np.ptp(t[1:, 0]) == 0  # rule 4
    same = [t[1, 3], t[3, 1], t[2, 4], t[4, 2]]  # US<->UR, DS<->DR
    opposite = [t[1, 2], t[2, 1], t[1, 4], t[4, 1], t[3, 2], t[2, 3], t[3, 4], t[4, 3]]
    assert np.ptp(same) == 0 and np.ptp(opposite) == 0 and min(same) > max(opposite)  # 5, 6
    assert t[1, 3] == 0.02 and t[1, 2] == pytest.approx(0.01)


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(stay=0.1),
        dict(stay=0.8, to_level=0.25),
        dict(same_direction=0.005),
    ],
)
def test_designs_breaking_the_rules_are_refused(kwargs):
    with pytest.raises(InferenceError):
        design_transition(**kwargs)


@pytest.mark.parametrize(
    "matrix, words",
    [
        (np.eye(4), "5 rows"),
        (np.where(np.eye(5, dtype=bool), 1.0, 0.0), "positive"),
        (T * 0.9, "row LG sums to 0.9"),
        ("nonsense", "5 rows"),
    ],
)
def test_invalid_transition_matrices_name_the_problem(matrix, words):
    with pytest.raises(InferenceError, match=words):
        validate_transition(matrix, "fusion.transition")


def test_estimated_transition_counts_labeled_pairs_with_smoothing():
    t = estimate_transition([["LG", "LG", "LG", "US", "US", None, "DS"]], smoothing=1.0)
    # LG->LG twice, LG->US once (+1 everywhere: row LG = [3, 2, 1, 1, 1] / 8)
    np.testing.assert_allclose(t[0], np.array([3, 2, 1, 1, 1]) / 8)
    np.testing.assert_allclose(t[1], np.array([1, 2, 1, 1, 1]) / 6)  # US->(None) skipped
    np.testing.assert_allclose(t[2], np.full(5, 0.2))
    validate_transition(t)


# --- Algorithm 1 -------------------------------------------------------------------------


def test_one_update_by_hand():
    """Window 1, two frames: the formulas of Algorithm 1 written out directly."""
    e0 = np.array([0.5, 0.2, 0.1, 0.1, 0.1])
    e1 = np.array([0.1, 0.6, 0.1, 0.1, 0.1])
    fusion = HmmFusion(window=1)
    assert fusion.push(e0) is None  # frame 0 is decided when frame 1 arrives
    out = fusion.push(e1)
    pbar = e0  # mean over the last l_w = 1 smooth states
    phat_last = np.array([sum(pbar[i] * T[i, j] * e1[j] for j in range(5)) for i in range(5)])
    s_opt = int(np.argmax(phat_last))
    phat = pbar[s_opt] * T[s_opt] * e1
    assert (out.frame, out.decision) == (0, s_opt)
    assert out.posterior_frame == 1
    np.testing.assert_allclose(out.posterior, phat / phat.sum())
    # by hand: phat_last = [0.5 * 0.125, 0.2 * 0.5, ...] -> US; p(s_1) = T[US] * e1 / 0.5
    assert s_opt == 1
    np.testing.assert_allclose(out.posterior, [0.03, 0.96, 0.002, 0.006, 0.002])


@pytest.mark.parametrize("window", [1, 2, 3, 5, 8])
def test_streaming_equals_the_numpy_transcription(window):
    rng = np.random.default_rng(window)
    for n in (0, 1, 2, window - 1, window, window + 1, 300):
        if n < 0:
            continue
        e = random_probabilities(rng, n)
        states, smooth = paper_viterbi(e, T, window)
        decisions, _, posteriors = stream(HmmFusion(window, T), e)
        np.testing.assert_array_equal(decisions, states)
        # frame 0 reports no posterior: p(s_0) is the CNN's output
        np.testing.assert_allclose(posteriors[1:], smooth[1:], rtol=0, atol=1e-14)


def test_streaming_equals_transcription_with_other_matrices():
    rng = np.random.default_rng(7)
    t = estimate_transition([rng.integers(0, 5, 200)])
    e = random_probabilities(rng, 500, concentration=1.0)
    states, _ = paper_viterbi(e, t, 4)
    np.testing.assert_array_equal(stream(HmmFusion(4, t), e)[0], states)


def test_hmm_decides_the_previous_frame_and_flush_decides_the_last():
    e = random_probabilities(np.random.default_rng(1), 10)
    fusion = HmmFusion(window=3)
    assert fusion.delay_frames == 1
    assert fusion.push(e[0]) is None
    for t in range(1, 10):
        out = fusion.push(e[t])
        assert out.frame == t - 1 and out.posterior_frame == t and out.voted is None
        assert out.decision is not None
    (last,) = fusion.flush()
    assert last.frame == 9
    assert fusion.flush() == []
    with pytest.raises(InferenceError, match="reset"):
        fusion.push(e[0])


def test_warm_up_frames_are_the_cnn_argmax():
    e = random_probabilities(np.random.default_rng(2), 20)
    decisions, _, _ = stream(HmmFusion(window=6), e)
    np.testing.assert_array_equal(decisions[:5], np.argmax(e[:5], axis=1))


def test_reset_starts_a_new_sequence():
    rng = np.random.default_rng(3)
    a, b = random_probabilities(rng, 50), random_probabilities(rng, 40)
    fusion = make_fusion("hmm+voting", window=5, vote_delay=2)
    stream(fusion, a)
    fusion.reset()
    again = stream(fusion, b)
    fresh = stream(make_fusion("hmm+voting", window=5, vote_delay=2), b)
    for x, y in zip(again, fresh):
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize(
    "bad, words",
    [
        ([0.5, 0.5], "expected 5"),
        ([np.nan, 0.2, 0.2, 0.3, 0.3], "not a probability"),
        ([-0.1, 0.3, 0.3, 0.3, 0.2], "not a probability"),
        ([0, 0, 0, 0, 0], "not a probability"),
    ],
)
def test_bad_probability_vectors_are_refused(bad, words):
    with pytest.raises(InferenceError, match=words):
        HmmFusion().push(np.array(bad, dtype=float))


def test_hmm_beats_the_cnn_on_noisy_blocks():
    """Blocks of modes, CNN ~90 % per frame with independent, less confident errors."""
    gains = []
    for seed in range(5):
        trial = synthetic_trial(seed, accuracy=0.9)
        cnn = accuracy(np.argmax(trial.probabilities, axis=1), trial.reference)
        hmm = accuracy(run_offline(HmmFusion(), trial.probabilities).final, trial.reference)
        assert 0.85 < cnn < 0.95
        gains.append(hmm - cnn)
    assert min(gains) > 0.03


# --- voting ------------------------------------------------------------------------------


def test_voting_window_cut_at_the_ends_and_ties_to_the_smallest_mode():
    voter = Voter(1)
    assert voter.push(0, 3) is None
    assert voter.push(1, 3) == (0, 3)  # window frames 0..1
    assert voter.push(2, 1) == (1, 3)  # 3, 3, 1
    assert voter.push(3, 2) == (2, 1)  # 3, 1, 2: a tie, smallest index
    assert voter.flush() == [(3, 1)]  # frames 2..3: 1, 2 tie
    assert voter.flush() == []
    with pytest.raises(InferenceError, match="expected frame"):
        Voter(1).push(5, 0)


def test_voting_equals_the_mode_over_the_window():
    rng = np.random.default_rng(4)
    d = rng.integers(0, 5, 60)
    for lv in (0, 1, 2, 5):
        voter = Voter(lv)
        votes = {}
        for f, x in enumerate(d.tolist()):
            out = voter.push(f, x)
            if out:
                votes[out[0]] = out[1]
        votes.update(voter.flush())
        for f in range(len(d)):
            window = d[max(0, f - lv) : f + lv + 1]
            counts = np.bincount(window, minlength=5)
            assert votes[f] == int(np.argmax(counts)), (lv, f)


def test_voting_delays_and_combines_with_the_hmm():
    e = random_probabilities(np.random.default_rng(5), 30)
    fusion = make_fusion("hmm+voting", window=5, vote_delay=2)
    assert fusion.delay_frames == 3 and fusion.votes
    outs = [fusion.push(row) for row in e]
    voted = [
        (t, o.voted_frame)
        for t, o in enumerate(outs)
        if o is not None and o.voted_frame is not None
    ]
    assert voted[0] == (3, 0) and all(t - f == 3 for t, f in voted)
    hmm, _, _ = stream(make_fusion("hmm"), e)
    _, votes, _ = stream(make_fusion("hmm+voting", window=5, vote_delay=2), e)
    for f in range(30):
        assert votes[f] == np.argmax(np.bincount(hmm[max(0, f - 2) : f + 3], minlength=5))


def test_cnn_baselines():
    e = random_probabilities(np.random.default_rng(6), 25)
    decisions, _, posteriors = stream(make_fusion("cnn"), e)
    np.testing.assert_array_equal(decisions, np.argmax(e, axis=1))
    np.testing.assert_array_equal(posteriors, e)
    fusion = make_fusion("cnn+voting", vote_delay=1)
    assert fusion.delay_frames == 1
    _, votes, _ = stream(fusion, e)
    assert np.all(votes >= 0)


# --- standard HMM baselines --------------------------------------------------------------


def forward_backward(e, t):
    n = len(e)
    alpha = np.empty_like(e)
    prior = np.full(5, 0.2)
    for k in range(n):
        a = prior * e[k]
        alpha[k] = a / a.sum()
        prior = alpha[k] @ t
    beta = np.ones_like(e)
    for k in range(n - 2, -1, -1):
        b = t @ (e[k + 1] * beta[k + 1])
        beta[k] = b / b.sum()
    gamma = alpha * beta
    return alpha, gamma / gamma.sum(axis=1, keepdims=True)


def test_forward_filter_and_fixed_lag_smoother_match_batch_forward_backward():
    e = random_probabilities(np.random.default_rng(8), 40)
    alpha, gamma = forward_backward(e, T)
    decisions, _, posteriors = stream(ForwardFilter(T), e)
    np.testing.assert_allclose(posteriors, alpha)
    np.testing.assert_array_equal(decisions, np.argmax(alpha, axis=1))
    # lag >= N: every frame sees the whole sequence, i.e. the full smoother
    decisions, _, posteriors = stream(FixedLagSmoother(T, lag=50), e)
    np.testing.assert_allclose(posteriors, gamma)
    # lag 0 is the filter; lag 2 decides frame t-2 with frames up to t
    np.testing.assert_allclose(stream(FixedLagSmoother(T, lag=0), e)[2], alpha)
    smoother = FixedLagSmoother(T, lag=2)
    outs = [smoother.push(row) for row in e[:10]]
    assert outs[0] is None and outs[1] is None and outs[2].frame == 0
    np.testing.assert_allclose(outs[9].posterior, forward_backward(e[:10], T)[1][7])


def test_make_fusion_knows_every_method_and_its_delay():
    delays = {m: make_fusion(m, window=5, vote_delay=3, lag=2).delay_frames for m in METHODS}
    assert delays == {
        "cnn": 0,
        "cnn+voting": 3,
        "hmm": 1,
        "hmm+voting": 4,
        "forward": 0,
        "fixed-lag": 2,
        "steady": 1,
        "steady+gait": 1,
        "steady+hysteresis": 1,
        "steady+margins": 1,
        "steady+geometry": 1,
        "steady+slope": 1,
        "steady+steps": 1,
    }
    with pytest.raises(InferenceError, match="unknown fusion method"):
        make_fusion("kalman")
    with pytest.raises(InferenceError, match="window"):
        make_fusion("hmm", window=0)


def test_bench_fusion_reports_both_timings():
    from capture.bench.components import bench_fusion

    result = bench_fusion(updates=300)
    assert set(result) == {"fusion_update_us", "paper_loop_us", "speedup"}
    assert result["fusion_update_us"] > 0 and result["paper_loop_us"] > 0


def test_steady_is_the_fixed_lag_1_smoother_of_its_walking_hmm():
    """Frame t-1 decided at frame t: the fixed-lag-1 smoother of the HMM with the paper's
    rules at the walking stay and the CNN's probabilities to the power `evidence`."""
    e = random_probabilities(np.random.default_rng(9), 60)
    steady = SteadyFusion(stay=0.987, evidence=0.75)
    decisions, _, posteriors = stream(steady, e)
    reference = FixedLagSmoother(steady_transition(0.987), lag=1)
    expected, _, expected_posteriors = stream(reference, e**0.75)
    np.testing.assert_array_equal(decisions, expected)
    np.testing.assert_allclose(posteriors, expected_posteriors, rtol=1e-9)
    assert steady.delay_frames == 1
    outs = [SteadyFusion().push(row) for row in e[:1]]
    assert outs == [None]  # frame 0 waits for frame 1


def test_steady_design_from_walking():
    assert walking_stay(15.0, 5.0) == pytest.approx(1 - 1 / 75)
    t = steady_transition(0.987)
    np.testing.assert_allclose(t.sum(axis=1), 1.0)
    assert np.all(np.diag(t) == 0.987)
    # the paper's proportions of what leaves a mode: 75 % of it to level ground
    assert t[1, 0] == pytest.approx(0.75 * 0.013) and t[1, 3] == pytest.approx(0.15 * 0.013)
    with pytest.raises(InferenceError, match="evidence"):
        SteadyFusion(evidence=0.0)


def test_steady_ignores_a_two_frame_error_the_hmm_follows():
    """Level ground at 0.7 with two down-stairs frames at 0.9 (a swing blur), then up
    stairs: Algorithm 1 switches to down stairs and back, steady holds; both follow the
    real change on the same frame."""

    def scores(mode: int, p: float) -> list[float]:
        return [p if j == mode else (1 - p) / 4 for j in range(5)]

    frames = np.array([scores(0, 0.7)] * 30 + [scores(2, 0.9)] * 2 + [scores(0, 0.7)] * 30
                      + [scores(1, 0.7)] * 30)  # fmt: skip
    hmm = run_offline(HmmFusion(5, T), frames).final
    steady = run_offline(SteadyFusion(), frames).final
    assert 2 in set(hmm[30:33]) and np.count_nonzero(np.diff(hmm)) == 3
    assert set(steady[:62]) == {0} and np.count_nonzero(np.diff(steady)) == 1
    assert np.argmax(steady == 1) == np.argmax(hmm == 1) == 64


def test_bench_times_the_steady_update():
    from capture.bench.components import bench_method_update

    assert bench_method_update("steady", updates=200) > 0
    assert bench_method_update("steady+hysteresis", updates=200) > 0
    assert bench_method_update("steady+geometry", updates=200) > 0


def gait_reference(e, elevation, stay=0.987, evidence=0.75):
    """steady+gait by its definition, in numpy: per frame the transition of its gait phase,
    the fixed-lag-1 smoother of that HMM."""
    from inference.fusion_design import GAIT_LEAVE, GAIT_PHASE_SD, GAIT_RATE_FRAMES

    e = np.asarray(e) ** evidence
    var, last, rows = 1.0, np.nan, []
    for el in elevation:
        change, last = el - last, el
        if np.isnan(change):
            rows.append(steady_transition(stay))
            continue
        var += (change**2 - var) / GAIT_RATE_FRAMES
        g = GAIT_LEAVE[0] if change >= GAIT_PHASE_SD * np.sqrt(var) else GAIT_LEAVE[1]
        rows.append(steady_transition(1 - (1 - stay) * g))
    alpha = []
    for k, row in enumerate(e):
        a = row if k == 0 else (alpha[-1] @ rows[k]) * row
        alpha.append(a / a.sum())
    decisions = [np.argmax(alpha[k] * (rows[k + 1] @ e[k + 1])) for k in range(len(e) - 1)]
    return np.array([*decisions, np.argmax(alpha[-1])])


def test_steady_gait_is_its_phase_dependent_smoother():
    from inference.fusion import GaitSteadyFusion

    rng = np.random.default_rng(10)
    e = random_probabilities(rng, 80, concentration=0.3)
    elevation = -35 + 20 * np.sin(2 * np.pi * np.arange(80) / 15) + rng.normal(0, 1, 80)
    fusion = GaitSteadyFusion()
    run = run_offline(fusion, e, elevation)
    np.testing.assert_array_equal(run.final, gait_reference(e, elevation))
    assert fusion.delay_frames == 1 and fusion.uses_gait
    # without the camera's orientation it is steady
    blind = run_offline(GaitSteadyFusion(), e, np.full(80, np.nan))
    np.testing.assert_array_equal(blind.final, run_offline(SteadyFusion(), e).final)
    with pytest.raises(InferenceError, match="orientation"):
        run_offline(GaitSteadyFusion(), e)


def test_steady_gait_switches_in_the_phase_where_terrain_changes_show():
    """The same weak evidence for up stairs: taken while the camera pitches up (the phase
    where terrain changes show), it switches; at another phase it waits."""
    from inference.fusion import GaitSteadyFusion

    def scores(mode, p):
        return [p if j == mode else (1 - p) / 4 for j in range(5)]

    frames = np.array([scores(0, 0.8)] * 40 + [scores(1, 0.9)] * 2 + [scores(0, 0.8)] * 18)
    k = np.arange(60)  # a stride of 15 frames: 1 s at 15 fps
    # frames 40-41 while the camera pitches up (phase 4), or down (phase 12)
    up = run_offline(GaitSteadyFusion(), frames, -35 + 20 * np.sin(2 * np.pi * (k + 4) / 15))
    down = run_offline(GaitSteadyFusion(), frames, -35 + 20 * np.sin(2 * np.pi * (k + 12) / 15))
    assert 1 in set(up.final[40:42]) and 1 not in set(down.final)


def test_terrain_changes_show_in_the_gait_phase_steady_gait_favours():
    """The judge of the phase is the walk: on simulated courses, indoors and outdoors,
    the camera's view changes terrain (settled changes of the mode its image shows) in
    GaitPhase far more often than the phase's share of frames, as the design says."""
    from devices.simulator.course import make_course
    from devices.simulator.simulator import Simulator
    from inference.evaluation.transitions import settled_changes
    from inference.fusion_design import GAIT_LEAVE
    from inference.fusion_steady import gait_phases

    changes = in_phase = frames = frames_in = 0
    for preset, seed in (("indoor", 3), ("outdoor", 4)):
        sim = Simulator(make_course(preset, seed), seed=seed, events=[])
        t = np.arange(0.0, sim.duration_s, 1 / 15)
        poses = [sim.camera_pose(s) for s in t]
        elevation = np.degrees(np.arcsin(np.clip([p[2, 2] for p in poses], -1, 1)))
        shown = [MODES.index(sim.course.segments[sim.truth_at(s)[0]].mode) for s in t]
        phase = np.array([bool(p) for p in gait_phases(elevation)])
        found = settled_changes(shown, t)
        changes += len(found)
        in_phase += sum(bool(phase[c.frame]) for c in found)
        frames, frames_in = frames + len(t), frames_in + int(phase.sum())
    assert changes >= 10
    likelier = (in_phase / changes) / (frames_in / frames)
    assert likelier > 0.6 * GAIT_LEAVE[0], (in_phase, changes, frames_in, frames)


def test_the_pipeline_gives_a_gait_fusion_the_cameras_elevation():
    from capture.live.pipeline import Pipeline
    from devices.rotations import quat_from_euler
    from devices.simulator.synthetic import synthetic_frame
    from inference.config import PreprocessConfig
    from inference.fusion import GaitSteadyFusion

    class Spy(GaitSteadyFusion):
        def push(self, probabilities, elevation_deg=None):
            seen.append(elevation_deg)
            return super().push(probabilities, elevation_deg)

    class Classifier:
        def predict(self, image):
            return np.array([0.6, 0.1, 0.1, 0.1, 0.1])

    seen: list = []
    pipeline = Pipeline(PreprocessConfig(), Classifier(), Spy())
    for k in (0, 11, 22):  # thigh swing 20 degrees at ~1 Hz (synthetic_frame's)
        q = quat_from_euler(0.0, np.radians(20.0) * np.sin(2 * np.pi * k / 45.0), 0.0)
        pipeline.process(synthetic_frame(k, 1_000_000 * k), q)
    assert len(seen) == 3 and all(np.isfinite(seen))
    assert seen[1] != pytest.approx(seen[0]) and max(seen) < 0  # looking down, swinging


def margins_reference(posteriors: np.ndarray, margins) -> np.ndarray:
    """steady+margins by its definition: the first decision is steady's argmax; after it a
    switch to another mode needs that mode's posterior at its margin."""
    out, held = [], -1
    for g in posteriors:
        best = int(np.argmax(g))
        if held < 0 or (best != held and g[best] >= margins[best]):
            held = best
        out.append(held)
    return np.array(out)


def hysteresis_reference(posteriors: np.ndarray, margin: float) -> np.ndarray:
    """steady+hysteresis by its definition: steady's decision (the posterior's argmax),
    except that a move from stairs or a ramp to level ground (0) needs level ground's
    posterior at the margin: a margin into level ground alone."""
    return margins_reference(posteriors, (margin, 0.0, 0.0, 0.0, 0.0))


@pytest.mark.parametrize(
    "method, margins",
    [("steady+hysteresis", (m, 0.0, 0.0, 0.0, 0.0)) for m in (0.0, 0.6, 0.8, 0.95)]
    + [("steady+margins", m) for m in ((0.9, 0.7, 0.7, 0.7, 0.7), (0.5, 0.95, 0.6, 0.8, 0.99))],
)
def test_a_margin_method_is_steadys_posterior_with_its_switch_margins(method, margins):
    """steady+hysteresis (a margin into level ground alone) and steady+margins (one into
    every mode) against their definition, on steady's posterior; all zero: steady itself."""
    from inference.fusion import MarginFusion

    e = random_probabilities(np.random.default_rng(11), 200, concentration=0.3)
    if method == "steady+hysteresis":
        fusion = HysteresisFusion(hysteresis=margins[0])
    else:
        fusion = MarginFusion(margins=margins)
    decisions, _, posteriors = stream(fusion, e)
    _, _, steady_posteriors = stream(SteadyFusion(), e)
    np.testing.assert_allclose(posteriors, steady_posteriors, rtol=1e-12)
    np.testing.assert_array_equal(decisions, margins_reference(steady_posteriors, margins))
    assert fusion.delay_frames == 1
    if max(margins) == 0.0:
        np.testing.assert_array_equal(decisions, stream(SteadyFusion(), e)[0])
    fusion.reset()  # a new sequence starts without the held decision
    again = stream(fusion, e[::-1])[0]
    np.testing.assert_array_equal(
        again, margins_reference(stream(SteadyFusion(), e[::-1])[2], margins)
    )


def test_steady_hysteresis_holds_a_misread_run_steady_follows():
    """Up stairs at 0.8 with four level-ground frames at 0.6 (the CNN reading level ground
    on the stairs), then level ground at 0.95: steady switches to level ground and back,
    steady+hysteresis holds; both follow the real change on the same frame."""

    def scores(mode: int, p: float) -> list[float]:
        return [p if j == mode else (1 - p) / 4 for j in range(5)]

    frames = np.array([scores(1, 0.8)] * 30 + [scores(0, 0.6)] * 4 + [scores(1, 0.8)] * 30
                      + [scores(0, 0.95)] * 30)  # fmt: skip
    steady = run_offline(SteadyFusion(), frames).final
    held = run_offline(make_fusion("steady+hysteresis"), frames).final
    assert 0 in set(steady[30:35]) and np.count_nonzero(np.diff(steady)) == 3
    assert set(held[:64]) == {1} and np.count_nonzero(np.diff(held)) == 1
    assert np.argmax(held[40:] == 0) == np.argmax(steady[40:] == 0) == 64 - 40


def test_steady_hysteresis_margin_is_checked_and_configured():
    with pytest.raises(InferenceError, match="margin"):
        HysteresisFusion(hysteresis=1.0)
    assert make_fusion("steady+hysteresis", hysteresis=0.9).hysteresis == 0.9
    assert HysteresisFusion().hysteresis == 0.8  # 4 to 1 against the other modes


# --- steady+margins ----------------------------------------------------------------------


def test_steady_margins_holds_a_misread_run_into_level_ground_not_a_change_into_stairs():
    """On a ramp up, three frames read as level ground at 0.8 then the ramp again: steady
    follows level ground, steady+margins (0.9 into level ground; the posterior peaks at
    0.85) holds the ramp. A real change to stairs up at 0.85 passes stairs' margin (0.7)
    on the same frame for both."""

    def scores(mode: int, p: float) -> list[float]:
        return [p if j == mode else (1 - p) / 4 for j in range(5)]

    frames = np.array([scores(3, 0.9)] * 30 + [scores(0, 0.8)] * 3 + [scores(3, 0.9)] * 30
                      + [scores(1, 0.85)] * 30)  # fmt: skip
    steady = run_offline(make_fusion("steady"), frames).final
    held = run_offline(make_fusion("steady+margins"), frames).final
    assert 0 in set(steady[30:40]) and np.count_nonzero(np.diff(steady)) == 3
    assert set(held[:63]) == {3} and np.count_nonzero(np.diff(held)) == 1
    assert held[-1] == steady[-1] == 1
    assert np.argmax(held == 1) == np.argmax(steady[40:] == 1) + 40


def test_steady_margins_are_checked():
    from inference.fusion import MarginFusion
    from inference.fusion_design import MARGINS

    with pytest.raises(InferenceError, match="margins"):
        MarginFusion(margins=(0.9, 0.7, 1.0, 0.9, 0.9))
    with pytest.raises(InferenceError, match="margins"):
        MarginFusion(margins=(0.9, 0.7))
    assert make_fusion("steady+margins").margins == MARGINS == (0.9, 0.7, 0.7, 0.7, 0.7)


# --- steady+geometry ---------------------------------------------------------------------


def geometry_reference(e, shown, margin, weight, stay=0.987, evidence=0.75):
    """steady+geometry by its definition, in numpy: the steady HMM whose every frame is also
    observed by its geometry (GEOMETRY_SHOWN's column, to `weight`), the fixed-lag-1
    smoother's posterior, and the switch margin of steady+hysteresis."""
    from inference.fusion_design import GEOMETRY_SHOWN

    likelihood = np.array(GEOMETRY_SHOWN).T ** weight  # [shown mode or 5: unknown] -> row
    t = steady_transition(stay)
    e = np.asarray(e) ** evidence
    alpha = []
    for k, row in enumerate(e):
        a = row if k == 0 else (alpha[-1] @ t) * row
        a = a * likelihood[shown[k] if shown[k] >= 0 else 5]
        alpha.append(a / a.sum())
    posteriors = [alpha[k] * (t @ e[k + 1]) for k in range(len(e) - 1)] + [alpha[-1]]
    return hysteresis_reference(np.array([g / g.sum() for g in posteriors]), margin)


def stream_geometry(fusion, probabilities, shown):
    """Live use: push each frame, then show it its geometry; flush; decisions by frame."""
    decisions = np.full(len(probabilities), -1)
    outputs = []
    for row, mode in zip(probabilities, shown):
        outputs.append(fusion.push(row))
        fusion.see_geometry(int(mode))
    for out in [*outputs, *fusion.flush()]:
        if out is not None:
            decisions[out.frame] = out.decision
    return decisions


@pytest.mark.parametrize("margin, weight", [(0.6, 0.36), (0.0, 1.0), (0.8, 0.5)])
def test_steady_geometry_is_the_steady_hmm_observing_the_geometry_too(margin, weight):
    from inference.fusion import GeometryFusion

    rng = np.random.default_rng(12)
    e = random_probabilities(rng, 200, concentration=0.3)
    shown = rng.integers(-1, 5, size=200)
    fusion = GeometryFusion(hysteresis=margin, geometry_evidence=weight)
    decisions = stream_geometry(fusion, e, shown)
    np.testing.assert_array_equal(decisions, geometry_reference(e, shown, margin, weight))
    assert fusion.delay_frames == 1
    fusion.reset()
    assert np.array_equal(stream_geometry(fusion, e, shown), decisions)


def stairs_then_level(misread: float = 0.7, run: int = 3):
    """Up stairs at 0.8 with `run` frames read as level ground at `misread` from frame 30,
    more stairs, then level ground at 0.95 from frame 64."""

    def scores(mode: int, p: float) -> list[float]:
        return [p if j == mode else (1 - p) / 4 for j in range(5)]

    return np.array([scores(1, 0.8)] * 30 + [scores(0, misread)] * run
                    + [scores(1, 0.8)] * (34 - run) + [scores(0, 0.95)] * 30)  # fmt: skip


def test_steady_geometry_holds_stairs_while_a_riser_is_in_view():
    """Three frames of level ground read at 0.7 on up stairs (the middling misreads of the
    design recordings): steady switches to level ground and back; steady+geometry does too
    when the features show level ground in those frames, and holds the stairs when they
    show the riser still in view. At the real change, with the features showing level
    ground, it switches on the frame steady does."""
    frames = stairs_then_level()
    us, lg = 1, 0
    riser_in_view = [us] * 64 + [lg] * 30
    level_in_view = [us] * 30 + [lg] * 3 + [us] * 31 + [lg] * 30
    steady = run_offline(SteadyFusion(), frames).final
    agreeing = stream_geometry(make_fusion("steady+geometry"), frames, level_in_view)
    held = stream_geometry(make_fusion("steady+geometry"), frames, riser_in_view)
    assert lg in set(steady[30:34]) and lg in set(agreeing[30:34])
    assert set(held[:64]) == {us} and np.count_nonzero(np.diff(held)) == 1
    assert np.argmax(held[40:] == lg) == np.argmax(steady[40:] == lg) == 64 - 40


def test_steady_geometry_follows_a_real_change_the_features_still_misread():
    """Outdoors, level ground often shows as stairs or a ramp (uneven ground, curbs): a
    real change from up stairs to level ground read at 0.95 is followed within one frame of
    steady even while the features still show stairs."""
    frames = stairs_then_level(run=0)
    still_stairs = [1] * 94
    held = stream_geometry(make_fusion("steady+geometry"), frames, still_stairs)
    steady = run_offline(SteadyFusion(), frames).final
    assert np.argmax(held == 0) - np.argmax(steady == 0) <= 1
    assert set(held[70:]) == {0}


def test_steady_geometry_parameters_are_checked_and_configured():
    from inference.fusion import GeometryFusion
    from inference.fusion_design import GEOMETRY_EVIDENCE, GEOMETRY_HYSTERESIS, GEOMETRY_SHOWN

    with pytest.raises(InferenceError, match="geometry evidence"):
        GeometryFusion(geometry_evidence=0.0)
    with pytest.raises(InferenceError, match="margin"):
        GeometryFusion(hysteresis=1.0)
    fusion = make_fusion("steady+geometry", geometry_hysteresis=0.7, geometry_evidence=0.3)
    assert (fusion.hysteresis, fusion.geometry_evidence) == (0.7, 0.3)
    assert (GEOMETRY_HYSTERESIS, GEOMETRY_EVIDENCE) == (0.6, 0.36)
    assert np.allclose(np.sum(GEOMETRY_SHOWN, axis=1), 1.0, atol=2e-3)
    # each terrain shows as itself more often than any other shows as it, but stairs down
    assert all(GEOMETRY_SHOWN[m][m] == max(r[m] for r in GEOMETRY_SHOWN) for m in (0, 1, 3, 4))


def test_shown_mode_names_the_terrain_the_features_show():
    from inference.features import shown_mode

    assert shown_mode("level", "up") == 0
    assert [shown_mode("stairs", d) for d in ("up", "down")] == [1, 2]
    assert [shown_mode("ramp", d) for d in ("up", "down")] == [3, 4]
    assert shown_mode("unknown", "") == shown_mode(None) == shown_mode("ramp", "") == -1


# --- steady+slope ------------------------------------------------------------------------


def stream_slope(fusion, probabilities, ahead):
    """Live use: push each frame, then show it its ground ahead; flush; decisions by frame."""
    decisions = np.full(len(probabilities), -1)
    outputs = []
    for row, mode in zip(probabilities, ahead):
        outputs.append(fusion.push(row))
        fusion.see_geometry(-1, int(mode))
    for out in [*outputs, *fusion.flush()]:
        if out is not None:
            decisions[out.frame] = out.decision
    return decisions


def ramp_then_level(misread: float = 0.97, run: int = 6):
    """Down a ramp at 0.8 with `run` frames read as level ground at `misread` from frame 30
    (the confident runs outdoors), more ramp, then level ground at 0.95 from frame 64."""
    dr, lg = 4, 0

    def scores(mode: int, p: float) -> list[float]:
        return [p if j == mode else (1 - p) / 4 for j in range(5)]

    return np.array([scores(dr, 0.8)] * 30 + [scores(lg, misread)] * run
                    + [scores(dr, 0.8)] * (34 - run) + [scores(lg, 0.95)] * 30)  # fmt: skip


def test_steady_slope_holds_a_ramp_while_the_ground_ahead_still_slopes():
    """Six frames read as level ground at 0.97 on a ramp down: steady+hysteresis switches to
    level ground and back; steady+slope holds the ramp while the ground ahead slopes down,
    then follows the real change once the ground ahead has shown level ground for three
    frames (SLOPE_HOLD_FRAMES)."""
    frames = ramp_then_level()
    dr, lg = 4, 0
    ahead = [dr] * 65 + [lg] * 29  # the ground levels out a frame after the image changes
    hysteresis = run_offline(make_fusion("steady+hysteresis"), frames).final
    held = stream_slope(make_fusion("steady+slope"), frames, ahead)
    assert lg in set(hysteresis[30:36]) and np.count_nonzero(np.diff(hysteresis)) == 3
    assert set(held[:65]) == {dr} and np.count_nonzero(np.diff(held)) == 1
    assert np.argmax(hysteresis[40:] == lg) + 40 == 64
    assert np.argmax(held == lg) == 67


def slope_reference(posteriors: np.ndarray, ahead, margin: float = 0.8, hold: int = 3):
    """steady+slope by its definition: steady's decision (the posterior's argmax), except
    that a move from a ramp (3, 4) to level ground (0) needs level ground's posterior at the
    margin, and from a ramp down (4) also no ramp down shown ahead in the last `hold` frames
    up to the decided one."""
    out, held = [], -1
    for k, g in enumerate(posteriors):
        best = int(np.argmax(g))
        if held in (3, 4) and best == 0:
            recent = list(ahead[max(0, k - hold + 1) : k + 1])
            if g[0] < margin or (held == 4 and 4 in recent):
                best = held
        held = best
        out.append(held)
    return np.array(out)


@pytest.mark.parametrize("seed", [5, 6])
def test_steady_slope_is_steady_holding_ramps_by_the_ground_ahead(seed):
    """Random scores and random ground ahead: every decision is the definition's; with the
    ground ahead never showing a ramp down, ramps are left at steady+hysteresis's margin and
    stairs as steady leaves them."""
    rng = np.random.default_rng(seed)
    e = random_probabilities(rng, 400, concentration=0.3)
    _, _, posteriors = stream(SteadyFusion(), e)
    for ahead in (rng.integers(-1, 5, size=400), np.full(400, 4), np.full(400, 3)):
        decisions = stream_slope(make_fusion("steady+slope"), e, ahead)
        np.testing.assert_array_equal(decisions, slope_reference(posteriors, ahead))
    steady = stream(SteadyFusion(), e)[0]
    level_ahead = stream_slope(make_fusion("steady+slope"), e, np.full(400, 3))  # up: no hold
    hysteresis = run_offline(make_fusion("steady+hysteresis"), e).final
    on_ramps = np.isin(hysteresis, (3, 4)) | np.isin(steady, (3, 4))
    assert (level_ahead != steady).any() and (level_ahead != hysteresis).any()
    np.testing.assert_array_equal(level_ahead[on_ramps], hysteresis[on_ramps])


def test_steady_slope_parameters_are_checked_and_configured():
    from inference.fusion import SlopeFusion
    from inference.fusion_design import SLOPE_HOLD_FRAMES

    with pytest.raises(InferenceError, match="hold frames"):
        SlopeFusion(hold_frames=0)
    fusion = make_fusion("steady+slope", hysteresis=0.7)
    assert (fusion.hysteresis, fusion.hold_frames, SLOPE_HOLD_FRAMES) == (0.7, 3, 3)
    assert fusion.uses_geometry and fusion.delay_frames == 1


def test_make_fusion_builds_and_names_every_row_of_the_method_table():
    from inference.fusion import METHOD_TABLE, METHODS, make_fusion

    assert METHODS == tuple(m.name for m in METHOD_TABLE) and len(set(METHODS)) == len(METHODS)
    for m in METHOD_TABLE:
        fusion = make_fusion(m.name, window=4, vote_delay=2, lag=3)
        assert type(fusion) is m.cls and fusion.method == m.name
        assert fusion.votes == (m.votes_on is not None)
        if m.votes_on is not None:  # the vote's window on top of its base's delay
            assert fusion.delay_frames == make_fusion(m.votes_on, window=4).delay_frames + 2
    assert make_fusion("fixed-lag", lag=3).delay_frames == 3
    with pytest.raises(InferenceError, match="unknown fusion method 'nope'"):
        make_fusion("nope")
