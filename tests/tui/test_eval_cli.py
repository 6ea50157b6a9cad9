"""`walkcap eval`: scores, recordings (through a stand-in reader), the model verb."""

import json
import subprocess
import sys

import numpy as np
import pytest

from devices.frames import MODES
from inference import evaluation as ev
from inference.fusion import make_fusion
from tests.scored_trials import live_final, synthetic_trial
from tui import cli
from tui.commands import eval_model


def write_scores(path, trial):
    lines = ["LG,US,DS,UR,DR,label"]
    for p, r in zip(trial.probabilities, trial.reference):
        lines.append(",".join(repr(float(x)) for x in p) + "," + MODES[r])
    path.write_text("\n".join(lines) + "\n")
    return str(path)


@pytest.fixture
def score_files(tmp_path):
    return [write_scores(tmp_path / f"s{i}.csv", synthetic_trial(i)) for i in range(3)]


def run(capsys, *argv):
    code = cli.main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def live_accuracy(method, probabilities, reference, **kw):
    """The decisions a live session would make, frame by frame."""
    final = live_final(make_fusion(method, **kw), probabilities)
    return np.mean([final[i] == r for i, r in enumerate(reference) if r >= 0])


def test_scores_table(capsys, score_files):
    code, out, err = run(capsys, "eval", "scores", *score_files)
    assert code == 0, err
    for word in (
        "CNN",
        "CNN + voting",
        "HMM",
        "HMM + voting",
        "mean",
        "SD",
        "delay (frames)",
        "s0.csv",
        "s2.csv",
        "paired t-tests",
    ):
        assert word in out


@pytest.mark.filterwarnings("error")
def test_scores_on_too_few_trials_say_so_and_test_nothing(capsys, score_files):
    code, out, err = run(capsys, "eval", "scores", *score_files[:2])
    assert code == 0, err
    assert "paired t-tests: n=2 trial(s): too few for a test (need >= 5)" in out
    assert "t = " not in out and "p = " not in out
    code, out, _ = run(capsys, "eval", "scores", *score_files[:2], "--json")
    tests = json.loads(out)["paired_t_tests"]
    assert tests["too_few"] and tests["tests"] == [] and tests["trials"] == 2


def test_scores_tests_are_holm_corrected_with_effect_sizes(capsys, tmp_path):
    files = [write_scores(tmp_path / f"s{i}.csv", synthetic_trial(i)) for i in range(5)]
    code, out, err = run(capsys, "eval", "scores", *files, "--methods", "cnn,hmm,hmm+voting")
    assert code == 0, err
    assert "paired t-tests over 5 trials (p Holm-corrected over 3 comparisons" in out
    assert out.count("p_Holm = ") == 3 and out.count("d_z = ") == 3


def test_scores_json_equals_live_decisions(capsys, score_files):
    code, out, _ = run(
        capsys, "eval", "scores", *score_files, "--window", "4", "--vote-delay", "2", "--json"
    )
    assert code == 0
    data = json.loads(out)
    assert data["delay_frames"] == {
        "cnn": 0,
        "cnn+voting": 2,
        "hmm": 1,
        "hmm+voting": 3,
        "steady": 1,
        "steady+hysteresis": 1,
        "steady+margins": 1,
    }
    assert data["parameters"]["window"] == 4
    for path, entry in zip(score_files, data["files"]):
        trial = ev.read_scores(path)
        assert entry["path"] == path and entry["frames"] == len(trial.reference)
        for method, acc in entry["accuracy"].items():
            assert acc == pytest.approx(
                live_accuracy(method, trial.probabilities, trial.reference, window=4, vote_delay=2)
            )
    means = {m: np.mean([f["accuracy"][m] for f in data["files"]]) for m in data["mean"]}
    assert data["mean"] == pytest.approx(means)
    assert data["mean"]["hmm"] > data["mean"]["cnn"]


def test_scores_use_the_configured_fusion(capsys, score_files, tmp_path):
    config = tmp_path / "walkcap.toml"
    config.write_text("[fusion]\nwindow = 3\nvote_delay = 4\nhysteresis = 0.9\n")
    code, out, _ = run(capsys, "--config", str(config), "eval", "scores", score_files[0], "--json")
    data = json.loads(out)
    assert data["parameters"]["window"] == 3 and data["delay_frames"]["cnn+voting"] == 4
    assert data["parameters"]["hysteresis"] == 0.9
    config.write_text("[fusion]\ntransition = [[1.0, 0.0, 0.0, 0.0, 0.0]]\n")
    code, _, err = run(capsys, "--config", str(config), "eval", "scores", score_files[0])
    assert code == 1 and "fusion.transition" in err and len(err.strip().splitlines()) == 1


def test_scores_sweep_methods_and_estimated_transition(capsys, score_files, tmp_path):
    code, out, _ = run(
        capsys,
        "eval",
        "scores",
        *score_files,
        "--methods",
        "cnn,hmm,fixed-lag",
        "--lag",
        "2",
        "--transition",
        "estimated",
        "--sweep-delay",
        "3",
        "--json",
    )
    assert code == 0
    data = json.loads(out)
    assert set(data["mean"]) == {"cnn", "hmm", "fixed-lag"}
    assert data["delay_frames"]["fixed-lag"] == 2
    assert data["parameters"]["transition"] == "estimated"
    assert data["sweep"]["delays"] == [0, 1, 2, 3]
    assert data["sweep"]["mean"]["hmm"][0] is None
    code, out, _ = run(capsys, "eval", "scores", *score_files, "--sweep-delay")
    lines = out.splitlines()
    header = lines[lines.index("accuracy (%) against delayed frames (mean over files):") + 1]
    assert header.split() == ["method", "0", "1", "2", "3", "4", "5", "6"]


@pytest.mark.subprocess
def test_bad_score_file_is_one_line_naming_file_and_line(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("LG,US,DS,UR,DR,label\n0.2,0.2,0.2,0.2,0.2,LG\n0.2,0.2,nan,0.2,0.2,LG\n")
    out = subprocess.run(
        [sys.executable, "-m", "tui.cli", "eval", "scores", str(bad)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 1
    assert out.stderr.strip().splitlines() == [
        f"walkcap eval: error: {bad}:3: DS: not a finite number: nan"
    ]


@pytest.mark.parametrize(
    "argv",
    [
        ["eval"],
        ["eval", "scores"],
        ["eval", "scores", "a.csv", "--methods", "kalman"],
        ["eval", "scores", "a.csv", "--window", "0"],
    ],
)
def test_usage_errors(capsys, argv):
    with pytest.raises(SystemExit) as e:
        cli.main(argv)
    assert e.value.code == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_missing_score_file(capsys):
    code, _, err = run(capsys, "eval", "scores", "nowhere.csv")
    assert code == 1 and "nowhere.csv" in err


@pytest.fixture
def fake_reader(tmp_path):
    """Four small recordings (two trials of S1 indoor, A1 indoor and outdoor)."""
    from tests.recording_fixtures import T0, frame_time, write_trial

    paths = []
    for i, (subject, condition) in enumerate(
        [("S1", "indoor"), ("S1", "indoor"), ("A1", "indoor"), ("A1", "outdoor")]
    ):
        path = tmp_path / f"{subject}_{condition}_t{i + 1:02d}.mcap"
        labels = [(T0, "LG", "operator"), (frame_time(40 + 3 * i), "US", "operator")]
        session = {"subject": subject, "condition": condition, "trial": i + 1}
        write_trial(path, labels, session=session, frames=80)
        paths.append(str(path))
    return paths


@pytest.mark.slow
def test_recordings_grouped_with_sweep_and_plots(capsys, fake_reader, tmp_path):
    # live keys only: no terrain reference, so frame accuracy is refused unless asked for
    code, _, err = run(capsys, "eval", "recordings", *fake_reader)
    assert code == 1 and "A1_indoor_t03.mcap: no terrain reference" in err
    code, out, err = run(
        capsys,
        "eval",
        "recordings",
        *fake_reader,
        "--reference",
        "locomotion",
        "--sweep-delay",
        "2",
        "--plot",
        str(tmp_path / "fig"),
    )
    assert code == 0, err
    assert "accuracy in % against the locomotion reference" in out
    assert "condition" in out and "S1" in out and "A1" in out and "±" in out
    assert "against delayed frames" in out and "wrote 28 figure file(s)" in out
    fig = tmp_path / "fig"
    assert (fig / "accuracy_vs_delay.pdf").read_bytes().startswith(b"%PDF")
    from PIL import Image

    with Image.open(fig / "accuracy_vs_delay.png") as png:
        assert round(png.info["dpi"][0]) == 300
    assert (fig / "switches.png").exists()  # accuracy against spurious switches
    # every trial's sequential figures, confusion matrices per condition
    assert len(list(fig.glob("decisions_*.png"))) == 4
    assert {p.name for p in fig.glob("confusion*.png")} == {
        "confusion_indoor.png",
        "confusion_outdoor.png",
    }
    code, out, _ = run(
        capsys, "eval", "recordings", *fake_reader, "--plot", str(tmp_path / "f2"),
        "--plot-trials", "A1_", "--reference", "locomotion",
    )  # fmt: skip
    assert code == 0 and len(list((tmp_path / "f2").glob("decisions_*.png"))) == 2
    code, out, _ = run(
        capsys, "eval", "recordings", *fake_reader, "--json", "--reference", "locomotion"
    )
    data = json.loads(out)
    assert data["accuracy_reference"] == "locomotion"
    assert sorted(f["subject"] for f in data["files"]) == ["A1", "A1", "S1", "S1"]
    assert {(g["condition"], g["subject"], g["trials"]) for g in data["groups"]} == {
        ("indoor", "S1", 2),
        ("indoor", "A1", 1),
        ("outdoor", "A1", 1),
    }
    assert set(data) >= {"files", "mean", "sd", "delay_frames", "paired_t_tests"}


def test_eval_model_is_the_model_command(capsys, monkeypatch):
    calls = []
    monkeypatch.setattr(eval_model, "run", lambda args, config: calls.append(args) or 0)
    code, _, _ = run(capsys, "eval", "model", "--sessions", "3", "--preset", "indoor")
    assert code == 0 and (calls[0].sessions, calls[0].preset) == (3, "indoor")


def test_real_recording_end_to_end(capsys, tmp_path):
    """A recording written by capture's recorder, read by capture.corpus.trials."""
    from capture.corpus.trials import read_trial
    from tests.recording_fixtures import write_recording

    path = str(tmp_path / "S07_indoor_t03.mcap")
    write_recording(path, seconds=2.0)
    code, out, err = run(capsys, "eval", "recordings", path, "--json", "--reference", "locomotion")
    assert code == 0, err
    data = json.loads(out)
    (entry,) = data["files"]
    assert (entry["subject"], entry["condition"]) == ("S07", "indoor")
    recorded = read_trial(path)
    assert entry["frames"] == len(recorded.frames.probabilities)
    assert entry["accuracy"]["hmm"] == pytest.approx(
        live_accuracy("hmm", recorded.frames.probabilities, recorded.frames.labels)
    )
    code, out, _ = run(capsys, "eval", "recordings", path, "--json")  # terrain: sim truth
    truth = json.loads(out)["files"][0]["accuracy"]
    assert truth["cnn"] == pytest.approx(
        np.mean(np.argmax(recorded.frames.probabilities, axis=1) == recorded.truth)
    )


def test_a_folder_stands_for_its_recordings(capsys, fake_reader, tmp_path):
    code, out, err = run(
        capsys, "eval", "recordings", str(tmp_path), "--json", "--reference", "locomotion"
    )
    assert code == 0, err
    assert len(json.loads(out)["files"]) == 4
    empty = tmp_path / "empty"
    empty.mkdir()
    code, _, err = run(capsys, "eval", "recordings", str(empty))
    assert code == 1 and "no .mcap recordings" in err


def test_scores_json_carries_switches_against_both_references(capsys, tmp_path):
    """A hand-made trial: terrain LG 60 frames then US 60; the subject steps up 15 frames
    (1 s) after the terrain changed; the CNN is sure of each frame and wrong on frame 20
    (DS for one frame) and frame 62 (back to LG for one frame)."""
    rows = ["LG,US,DS,UR,DR,label,locomotion"]
    for k in range(120):
        terrain = "LG" if k < 60 else "US"
        decided = {20: "DS", 62: "LG"}.get(k, terrain)
        p = [0.9 if m == decided else 0.025 for m in MODES]
        rows.append(",".join(map(str, p)) + f",{terrain},{'LG' if k < 75 else 'US'}")
    path = tmp_path / "t.csv"
    path.write_text("\n".join(rows) + "\n")
    code, out, err = run(
        capsys, "eval", "scores", str(path), "--methods", "cnn", "--json", "--sweep-delay", "1"
    )
    assert code == 0, err
    data = json.loads(out)
    assert data["accuracy_reference"] == "terrain"
    cnn = data["files"][0]["transitions"]["cnn"]
    terrain, loco = cnn["terrain"], cnn["locomotion"]
    # 5 switches: LG-DS-LG, LG-US (the change), US-LG-US; 4 spurious in 8 s
    assert (terrain["changes"], terrain["switches"], terrain["missed"]) == (1, 5, 0)
    assert terrain["spurious"] == 4 and terrain["spurious_per_min"] == pytest.approx(30.0)
    assert terrain["delay_frames"]["median"] == 0 and terrain["delay_ms"]["median"] == 0
    # against the step up (frame 75) the nearest switch to US is the one at frame 63: 0.8 s
    assert loco["lead_ms"]["median"] == pytest.approx(800.0) and loco["late"] == 0
    assert data["transitions"]["cnn"]["terrain"]["spurious"] == 4
    assert data["sweep"]["spurious_per_min"]["cnn"] == [pytest.approx(30.0)] * 2
    code, out, _ = run(capsys, "eval", "scores", str(path), "--methods", "cnn", "--fps", "30")
    assert "spurious/min" in out and "lead median" in out and "60.0" in out


def test_recordings_are_read_and_evaluated_one_at_a_time(capsys, fake_reader, monkeypatch):
    """A folder of many long trials: each trial's frames are let go once it is evaluated
    (only its figures stay), so memory does not grow with the number of trials; the
    report is the one evaluating every trial at once gives."""
    import gc
    import weakref

    from capture.corpus import trials as reader

    folder = str(fake_reader[0]).rsplit("/", 1)[0]
    alive: list[weakref.ref] = []
    most = []
    read = reader.read_evaluation_trial

    def counted(*args):
        gc.collect()
        most.append(sum(r() is not None for r in alive))  # trials still held at this read
        trial = read(*args)
        alive.append(weakref.ref(trial))
        return trial

    monkeypatch.setattr(reader, "read_evaluation_trial", counted)
    argv = ("eval", "recordings", folder, "--json", "--reference", "locomotion")
    code, out, err = run(capsys, *argv)
    assert code == 0, err
    assert most == [0, 0, 0, 0]  # the trial before was gone when the next was read
    streamed = json.loads(out)

    # the same with every trial's frames at once (the delay sweep needs them all)
    alive.clear()
    code, out, err = run(capsys, *argv, "--sweep-delay", "1")
    assert code == 0, err
    whole = json.loads(out)
    assert max(most[4:]) >= 1  # held together, for the sweep
    whole.pop("sweep")
    assert streamed == whole
