"""Evaluation: offline = live, accuracies, delay sweep, statistics, score files, plots."""

import types

import numpy as np
import pytest
from scipy import stats

from inference import evaluation as ev
from inference.config import FusionConfig
from inference.errors import InferenceError
from inference.evaluation import metrics
from inference.fusion import METHODS, make_fusion
from inference.fusion_design import PAPER_TRANSITION
from tests.scored_trials import live_final, synthetic_trial

HEADER = "LG,US,DS,UR,DR,label\n"


@pytest.fixture(scope="module")
def trials():
    conditions = ["indoor", "indoor", "outdoor", "outdoor", "indoor", "outdoor"]
    return [
        synthetic_trial(
            i,
            accuracy=0.88,
            path=f"t{i}.mcap",
            metadata={"subject": f"S{i % 2 + 1}", "condition": c},
        )
        for i, c in enumerate(conditions)
    ]


# --- running methods ---------------------------------------------------------------------


# gait, geometry and steps need a recording's cues
SCORE_METHODS = [
    m
    for m in METHODS
    if not (
        getattr(make_fusion(m), "uses_gait", False)
        or getattr(make_fusion(m), "uses_geometry", False)
        or getattr(make_fusion(m), "uses_steps", False)
    )
]


@pytest.mark.parametrize("method", SCORE_METHODS)
def test_offline_decisions_are_the_live_ones(method, trials):
    params = FusionConfig(window=4, vote_delay=2, lag=2)
    e = trials[0].probabilities
    offline = metrics.run_offline(params.make(method), e)
    np.testing.assert_array_equal(offline.final, live_final(params.make(method), e))
    assert np.all(offline.final >= 0)


def test_vote_offline_is_the_streaming_vote(trials):
    e = trials[1].probabilities
    hmm = metrics.run_offline(make_fusion("hmm"), e)
    for lv in (0, 1, 3):
        voted = metrics.run_offline(make_fusion("hmm+voting", vote_delay=lv), e)
        np.testing.assert_array_equal(metrics.vote_offline(hmm.decisions, lv), voted.final)


def test_accuracy_counts_only_frames_with_a_reference():
    assert metrics.accuracy(np.array([0, 1, 2, 3]), np.array([0, 1, -1, 0])) == pytest.approx(2 / 3)
    with pytest.raises(InferenceError, match="no frame"):
        metrics.accuracy(np.array([0]), np.array([-1]))


def test_evaluate_trial_reports_each_method(trials):
    result = metrics.evaluate_trial(trials[0], ev.PAPER_METHODS)
    for m in ev.PAPER_METHODS:
        assert result.accuracy[m] == metrics.accuracy(result.runs[m].final, trials[0].reference)
    cnn = np.mean(np.argmax(trials[0].probabilities, axis=1) == trials[0].reference)
    assert result.accuracy["cnn"] == pytest.approx(cnn)
    assert result.accuracy["hmm"] > result.accuracy["cnn"]


def test_trial_validates_its_inputs():
    with pytest.raises(InferenceError, match="shape"):
        ev.Trial("a", np.ones((3, 4)) / 4, [0, 0, 0])
    with pytest.raises(InferenceError, match="3 frames but 2"):
        ev.Trial("a", np.full((3, 5), 0.2), ["LG", "US"])
    with pytest.raises(InferenceError, match="unknown mode 'XX'"):
        ev.Trial("a", np.full((1, 5), 0.2), ["XX"])
    t = ev.Trial("a", np.full((3, 5), 0.2), ["LG", None, "DR"])
    np.testing.assert_array_equal(t.reference, [0, -1, 4])


# --- statistics --------------------------------------------------------------------------


def test_mean_sd_and_paired_t_tests_match_scipy(trials):
    results = ev.evaluate(trials, ev.PAPER_METHODS)
    x = [r.accuracy["hmm"] for r in results]
    y = [r.accuracy["cnn+voting"] for r in results]
    mean, sd = metrics.mean_sd(x)
    assert mean == pytest.approx(np.mean(x)) and sd == pytest.approx(np.std(x, ddof=1))
    family = metrics.paired_t_tests(results, ev.PAPER_METHODS)
    assert family.trials == len(trials) and not family.too_few
    tests = {(t.a, t.b): t for t in family.tests}
    assert len(tests) == 6
    ref = stats.ttest_rel(y, x)
    test = tests[("cnn+voting", "hmm")]
    assert test.t == pytest.approx(ref.statistic)
    assert test.p == pytest.approx(ref.pvalue)
    d = np.subtract(y, x)
    assert test.d_z == pytest.approx(d.mean() / d.std(ddof=1))
    assert test.mean_difference == pytest.approx(d.mean())
    assert test.p_holm >= test.p
    assert tests[("cnn", "hmm")].n == len(trials)


def test_holm_adjusts_a_family_step_down():
    adjusted = metrics.holm([0.01, 0.04, 0.03, 0.005, float("nan")])
    assert adjusted[:4] == pytest.approx([0.03, 0.06, 0.06, 0.02])
    assert np.isnan(adjusted[4])
    assert metrics.holm([0.6, 0.9]) == pytest.approx([1.0, 1.0])  # capped at 1


def test_no_paired_t_test_on_too_few_trials(trials):
    results = ev.evaluate(trials, ["cnn", "hmm"])
    few = metrics.paired_t_tests(results[: metrics.MIN_TRIALS_FOR_TEST - 1], ["cnn", "hmm"])
    assert few.too_few and few.tests == []
    enough = metrics.paired_t_tests(results[: metrics.MIN_TRIALS_FOR_TEST], ["cnn", "hmm"])
    assert not enough.too_few and len(enough.tests) == 1


@pytest.mark.filterwarnings("error")
def test_paired_t_test_of_identical_and_constant_differences():
    same = metrics.paired_t_test([0.5, 0.6, 0.7], [0.5, 0.6, 0.7])
    assert same.p == 1.0 and np.isnan(same.t) and same.mean_difference == 0
    # nearly constant differences: scipy warns of catastrophic cancellation; no test here
    x = np.array([0.91, 0.93, 0.95, 0.97, 0.99])
    constant = metrics.paired_t_test(x, x - 0.1)
    assert np.isnan(constant.t) and np.isnan(constant.p)
    assert constant.mean_difference == pytest.approx(0.1)
    single = metrics.paired_t_test([0.5], [0.4])
    assert np.isnan(single.p)
    assert np.isnan(metrics.mean_sd([0.5])[1])


def test_confusion_matrix_counts_reference_rows_and_decided_columns(trials):
    c = metrics.confusion_matrix(np.array([0, 1, 1, 4, 2]), np.array([0, 1, 2, 4, -1]))
    assert c.sum() == 4 and c[0, 0] == 1 and c[1, 1] == 1 and c[2, 1] == 1 and c[4, 4] == 1
    results = ev.evaluate(trials, ["hmm"])
    pooled = metrics.pooled_confusion(results, "hmm")
    assert pooled.sum() == sum(len(t.reference) for t in trials)
    correct = sum(r.accuracy["hmm"] * len(r.trial.reference) for r in results)
    assert np.trace(pooled) == pytest.approx(correct)


def test_delay_sweep_aligns_methods_on_delayed_frames(trials):
    methods = SCORE_METHODS
    sweep = ev.delay_sweep(trials[:2], methods, 3, FusionConfig(lag=1))
    assert sweep.delays == [0, 1, 2, 3]
    a = sweep.accuracy
    for i, trial in enumerate(trials[:2]):
        base = metrics.evaluate_trial(trial, ["cnn", "hmm", "forward"])
        assert np.all(a["cnn"][i] == base.accuracy["cnn"])
        assert np.isnan(a["hmm"][i, 0]) and np.all(a["hmm"][i, 1:] == base.accuracy["hmm"])
        assert np.isnan(a["hmm+voting"][i, 0])
        assert a["hmm+voting"][i, 1] == base.accuracy["hmm"]
        assert a["cnn+voting"][i, 0] == base.accuracy["cnn"]
        assert a["fixed-lag"][i, 0] == pytest.approx(base.accuracy["forward"])
        for d in (2, 3):  # each point is the method configured for that delay
            p = FusionConfig(vote_delay=d, lag=d)
            assert (
                a["cnn+voting"][i, d]
                == metrics.evaluate_trial(trial, ["cnn+voting"], p).accuracy["cnn+voting"]
            )
            assert (
                a["fixed-lag"][i, d]
                == metrics.evaluate_trial(trial, ["fixed-lag"], p).accuracy["fixed-lag"]
            )
            p = FusionConfig(vote_delay=d - 1)
            assert (
                a["hmm+voting"][i, d]
                == metrics.evaluate_trial(trial, ["hmm+voting"], p).accuracy["hmm+voting"]
            )


def test_leave_one_out_transitions_exclude_the_trial_itself(trials):
    ts = ev.leave_one_out_transitions(trials[:3])
    from inference.fusion_design import estimate_transition

    np.testing.assert_allclose(ts[0], estimate_transition([t.reference for t in trials[1:3]]))
    assert len(ev.leave_one_out_transitions(trials[:1])) == 1


def test_report_shape(trials):
    params = FusionConfig()
    results = ev.evaluate(trials, ev.PAPER_METHODS)
    sweep = ev.delay_sweep(trials, ev.PAPER_METHODS, 2)
    data = ev.report(results, ev.PAPER_METHODS, params, sweep, grouped=True)
    assert [f["path"] for f in data["files"]] == [t.path for t in trials]
    assert set(data["files"][0]["accuracy"]) == set(ev.PAPER_METHODS)
    assert data["delay_frames"] == {"cnn": 0, "cnn+voting": 1, "hmm": 1, "hmm+voting": 2}
    assert all(0 <= v <= 1 for v in data["mean"].values())
    groups = {(g["condition"], g["subject"]): g["trials"] for g in data["groups"]}
    assert groups == {
        ("indoor", "S1"): 2,
        ("indoor", "S2"): 1,
        ("outdoor", "S1"): 1,
        ("outdoor", "S2"): 2,
    }
    assert [c["condition"] for c in data["conditions"]] == ["indoor", "outdoor"]
    assert data["sweep"]["mean"]["hmm"][0] is None
    assert data["sweep"]["mean"]["hmm"][1] == pytest.approx(data["mean"]["hmm"])
    assert len(data["paired_t_tests"]["tests"]) == 6
    assert data["paired_t_tests"]["correction"] == "holm"
    assert {"p_holm", "d_z", "mean_difference"} <= set(data["paired_t_tests"]["tests"][0])
    # three trials per condition: too few to test within one
    assert all(c["paired_t_tests"]["too_few"] for c in data["conditions"])


# --- score files -------------------------------------------------------------------------


def write(tmp_path, text, name="s.csv"):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def test_read_scores(tmp_path):
    path = write(tmp_path, HEADER + "0.9,0.05,0.05,0,0,LG\n0.1,0.6,0.1,0.1,0.1,US\n\n")
    trial = ev.read_scores(path)
    np.testing.assert_allclose(trial.probabilities[1], [0.1, 0.6, 0.1, 0.1, 0.1])
    np.testing.assert_array_equal(trial.reference, [0, 1])
    assert trial.path == path


@pytest.mark.parametrize(
    "text, where, words",
    [
        ("", "", "empty file"),
        (HEADER, "", "no frames"),
        ("LG,US,DS,UR,label\n", ":1:", "expected the header"),
        ("lg,us,ds,ur,dr,label\n0.2,0.2,0.2,0.2,0.2,LG\n", ":1:", "expected the header"),
        (HEADER + "0.2,0.2,0.2,0.2,0.2,LG\n0.2,nan,0.2,0.2,0.2,LG\n", ":3:", "US: not a finite"),
        (HEADER + "0.2,0.2,0.2,0.2,x,LG\n", ":2:", "DR: not a number"),
        (HEADER + "0.6,-0.2,0.2,0.2,0.2,LG\n", ":2:", "US: negative"),
        (HEADER + "0.5,0.2,0.2,0.2,0.2,LG\n", ":2:", "sum to 1.3"),
        (HEADER + "0.2,0.2,0.2,0.2,0.2,XX\n", ":2:", "unknown label 'XX'"),
        (HEADER + "0.2,0.2,0.2,0.2,0.2\n", ":2:", "expected 6 fields"),
    ],
)
def test_bad_score_files_name_file_and_line(tmp_path, text, where, words):
    path = write(tmp_path, text)
    with pytest.raises(ev.ScoreFileError) as e:
        ev.read_scores(path)
    assert str(e.value).startswith(path + where) and words in str(e.value)
    assert "\n" not in str(e.value)


def test_binary_score_file_is_a_clear_error(tmp_path):
    path = tmp_path / "s.csv"
    path.write_bytes(b"\xff\xfe\x00\x81garbage")
    with pytest.raises(ev.ScoreFileError, match="not a text file"):
        ev.read_scores(path)


# --- recordings --------------------------------------------------------------------------


def test_trial_from_recording_scores_the_terrain_and_keeps_the_live_keys_for_lead_time():
    probs = np.full((3, 5), 0.2)
    data = {
        "probabilities": probs,
        "labels": [None, "US", "US"],
        "truth": ["LG"] * 3,
        "metadata": {"subject": "A1", "condition": "outdoor"},
    }
    trial = ev.trial_from_recording("a.mcap", data)
    assert trial.reference_name == "terrain"
    np.testing.assert_array_equal(trial.reference, [0, 0, 0])
    np.testing.assert_array_equal(trial.locomotion, [-1, 1, 1])
    assert list(trial.references()) == ["terrain", "locomotion"]
    assert (trial.subject, trial.condition) == ("A1", "outdoor")
    # frame accuracy against the live keys only when asked for
    loco = ev.trial_from_recording("a.mcap", data, reference="locomotion")
    assert loco.reference_name == "locomotion" and loco.locomotion is None
    np.testing.assert_array_equal(loco.reference, [-1, 1, 1])
    # no terrain reference: refused, never replaced by the live keys
    with pytest.raises(InferenceError, match="no terrain reference .* --reference locomotion"):
        ev.trial_from_recording("a.mcap", dict(data, truth=None))
    obj = types.SimpleNamespace(**data)  # an object with attributes works as well
    assert ev.trial_from_recording("a.mcap", obj).subject == "A1"


def test_recordings_through_the_reader(monkeypatch, trials):
    from capture.corpus import trials as reader

    by_path = {t.path: t for t in trials}
    fake = lambda path, **_: types.SimpleNamespace(  # noqa: E731
        evaluation_inputs=lambda: {
            "probabilities": by_path[path].probabilities,
            "labels": [None] * len(by_path[path].reference),
            "truth": [int(x) for x in by_path[path].reference],
            "metadata": by_path[path].metadata,
        }
    )
    monkeypatch.setattr(reader, "read_trial", fake)
    loaded = reader.read_trials([t.path for t in trials[:2]])
    np.testing.assert_array_equal(loaded[1].reference, trials[1].reference)
    assert loaded[0].metadata["condition"] == "indoor"


# --- figures -----------------------------------------------------------------------------


@pytest.mark.slow
def test_write_plots_writes_the_papers_figures(tmp_path, trials):
    methods = list(ev.PAPER_METHODS)
    results = ev.evaluate(trials, methods)
    sweep = ev.delay_sweep(trials, methods, 2)
    written = ev.write_plots(results, tmp_path / "fig", methods, sweep=sweep)
    names = sorted(p.name for p in written)
    stems = [
        "accuracy_per_subject_indoor",
        "accuracy_per_subject_outdoor",
        "accuracy_vs_delay",
        *(f"{kind}_t{i}" for kind in ("decisions", "probabilities") for i in range(len(trials))),
        "confusion_indoor",
        "confusion_outdoor",
        "switches",
    ]
    assert names == sorted(f"{stem}.{ext}" for stem in stems for ext in ("pdf", "png"))
    for p in written:
        if p.suffix == ".pdf":
            assert p.read_bytes()[:4] == b"%PDF"
            continue
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and p.stat().st_size > 5000


def test_paper_transition_is_the_default():
    np.testing.assert_array_equal(FusionConfig().transition, PAPER_TRANSITION)


def test_a_gait_method_needs_the_cameras_elevation(trials):
    with pytest.raises(InferenceError, match="t0.mcap: steady.gait needs the camera"):
        metrics.evaluate_trial(trials[0], ["steady+gait"])
    n = len(trials[0].reference)
    trial = ev.Trial("t", trials[0].probabilities, trials[0].reference, elevation_deg=[-30.0] * n)
    assert metrics.evaluate_trial(trial, ["steady+gait"]).accuracy["steady+gait"] > 0.5


def test_a_geometry_method_needs_the_terrain_features(trials):
    with pytest.raises(InferenceError, match="t0.mcap: steady.geometry needs the terrain"):
        metrics.evaluate_trial(trials[0], ["steady+geometry"])
    t0 = trials[0]
    trial = ev.Trial("t", t0.probabilities, t0.reference, geometry=t0.reference)
    result = metrics.evaluate_trial(trial, ["steady", "steady+geometry"])
    # features that show the terrain itself can only help
    assert result.accuracy["steady+geometry"] >= result.accuracy["steady"]
    with pytest.raises(InferenceError, match="frames but 3 terrain geometries"):
        ev.Trial("t", t0.probabilities, t0.reference, geometry=[0, 1, 2])
