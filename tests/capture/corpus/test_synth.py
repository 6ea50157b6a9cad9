"""`walkcap synth --format dataset`, the dataset files, `walkcap train` and `eval model`."""

import argparse
import json

import numpy as np
import pytest

from capture.corpus.dataset import read_sessions, session_plan
from devices.frames import MODES
from inference.dataset import LabeledSession, read_session, write_session
from inference.errors import InferenceError
from tui import cli
from tui.commands import eval_model


def _drawn_sessions(count=6, per_class=3):
    from tests.drawn_sessions import drawn_sessions

    return drawn_sessions(count, per_class)


def test_session_plan_alternates_presets_with_consecutive_seeds():
    assert session_plan(3, "both", 10) == [("indoor", 10), ("outdoor", 11), ("indoor", 12)]
    assert session_plan(2, "outdoor", 0) == [("outdoor", 0), ("outdoor", 1)]
    with pytest.raises(InferenceError):
        session_plan(1, "moon", 0)


def test_synth_writes_one_compressed_session_per_walk(tmp_path, capsys):
    out = tmp_path / "set"
    assert (
        cli.main(["synth", "--out", str(out), "--sessions", "2", "--seed", "5", "--frames", "4"])
        == 0
    )
    files = sorted(out.glob("*.npz"))
    assert [f.name for f in files] == ["indoor-000005.npz", "outdoor-000006.npz"]
    s = read_session(files[1])
    assert s.images.shape == (4, 100, 100) and s.images.dtype == np.uint8
    assert set(np.unique(s.images)) <= {0, 1} and s.images.any()
    assert np.all((s.labels >= 0) & (s.labels < len(MODES)))
    assert s.preset == "outdoor" and s.meta["seed"] == 6 and s.meta["fps"] == 15.0
    assert s.meta["preprocess"]["grid_size"] == 100 and "mounting_pitch_deg" in s.meta["preprocess"]
    assert len(s.flags) == 4
    with np.load(files[1]) as z:  # packed bits, no pickles
        assert z["images"].shape == (4, 1250) and z["images"].dtype == np.uint8
        assert len(z["time_ns"]) == 4 and np.all(np.diff(z["time_ns"]) > 0)
    # Deterministic for a seed.
    again = tmp_path / "again"
    cli.main(["synth", "--out", str(again), "--sessions", "1", "--seed", "5", "--frames", "4"])
    np.testing.assert_array_equal(
        read_session(again / "indoor-000005.npz").images, read_session(files[0]).images
    )


def test_dataset_files_round_trip_and_bad_files_are_one_line(tmp_path):
    rng = np.random.default_rng(0)
    images = (rng.random((7, 100, 100)) < 0.1).astype(np.uint8)
    labels = np.array([0, 1, 2, 3, 4, -1, 0])
    s = LabeledSession(
        "walk", images, labels, "indoor", flags=np.array([""] * 6 + ["x"]), meta={"seed": 3}
    )
    path = write_session(tmp_path / "walk.npz", s)
    back = read_session(path)
    np.testing.assert_array_equal(back.images, images)
    np.testing.assert_array_equal(back.labels, labels)
    assert back.flags[-1] == "x" and back.meta["seed"] == 3 and back.preset == "indoor"
    assert len(back.labelled()) == 6
    assert back.locomotion_modes is None and back.errors is None  # a recording's session has none
    # The simulator's truth travels with the frames, and labelled() keeps it aligned.
    views, errors = np.array(list("ABCDEFG")), np.array([""] * 5 + ["sky", "foot"])
    truth = write_session(
        tmp_path / "truth.npz", s, extra={"locomotion_modes": views, "errors": errors}
    )
    kept = read_session(truth).labelled()
    assert list(kept.locomotion_modes) == list("ABCDEG") and list(kept.errors) == [""] * 5 + [
        "foot"
    ]
    write_session(
        tmp_path / "short.npz", s, extra={"locomotion_modes": views[:3], "errors": errors}
    )
    with pytest.raises(InferenceError, match="do not match"):
        read_session(tmp_path / "short.npz")
    (tmp_path / "junk.npz").write_bytes(b"junk")
    with pytest.raises(InferenceError, match="not a readable dataset"):
        read_session(tmp_path / "junk.npz")
    (tmp_path / "walk.mcap").write_bytes(b"")
    with pytest.raises(InferenceError, match="walk.mcap is empty"):
        read_sessions([tmp_path / "walk.mcap"])
    with pytest.raises(InferenceError, match="no sessions"):
        (tmp_path / "empty").mkdir()
        read_sessions([tmp_path / "empty"])


def test_recording_reader_feeds_the_same_code_path(tmp_path, monkeypatch):
    import capture.corpus.dataset as dataset

    session = _drawn_sessions(1)[0]
    (tmp_path / "a.mcap").write_bytes(b"")
    monkeypatch.setitem(dataset.READERS, ".mcap", lambda p: session)
    assert read_sessions([tmp_path])[0] is session


def test_train_and_eval_model_commands(tmp_path, capsys, monkeypatch):
    data = tmp_path / "data"
    for s in _drawn_sessions(6):
        write_session(data / f"{s.name}.npz", s)
    model = tmp_path / "m.pt"
    kept = []  # the command keeps its freed memory; the test process must not
    monkeypatch.setattr("inference.training.keep_freed_memory", lambda: kept.append(1))
    assert (
        cli.main(
            [
                "train",
                "--data",
                str(data),
                "--out",
                str(model),
                "--epochs",
                "1",
                "--max-steps",
                "2",
                "--hidden",
                "4",
                "--threads",
                "1",
                "--quiet",
            ]
        )
        == 0
    )
    assert kept == [1]
    out = capsys.readouterr().out
    assert "6 sessions" in out and "test sessions" in out and "confusion" in out
    assert "indoor:" in out and "outdoor:" in out
    meta = json.loads(model.with_suffix(".json").read_text())
    assert meta["classes"] == list(MODES) and meta["data"]["train"]["sessions"] >= 2
    assert set(meta["metrics"]["test"]) >= {"all", "indoor", "outdoor"}
    assert meta["training"]["seed"] == 0 and meta["preprocess"] is not None
    assert meta["split"]["test"] and len(meta["weights_sha256"]) == 64
    argv = ["train", "--data", str(data), "--out", str(tmp_path / "j.pt"), "--epochs", "1"]
    argv += ["--max-steps", "2", "--hidden", "4", "--threads", "1", "--json"]
    assert cli.main(argv) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["sessions"] == 6 and set(summary["test"]) >= {"all", "indoor", "outdoor"}
    assert summary["weights"].endswith("j.pt") and len(summary["sha256"]) == 64

    parser = argparse.ArgumentParser()
    eval_model.add_arguments(parser)
    from capture.config import Config

    args = parser.parse_args(["--model", str(model), "--data", str(data), "--json"])
    assert eval_model.run(args, Config()) == 0
    result = json.loads(capsys.readouterr().out)
    assert len(result["sessions"]) == 6
    assert result["metrics"]["all"]["frames"] == 6 * 3 * 5


def test_eval_model_renders_unseen_sessions(tmp_path, capsys):
    from capture.config import Config
    from inference.model import TerrainCNN, save_model

    model = save_model(TerrainCNN(hidden=4), tmp_path / "m.pt")
    parser = argparse.ArgumentParser()
    eval_model.add_arguments(parser)
    args = parser.parse_args(["--model", str(model), "--sessions", "2", "--frames", "3"])
    assert eval_model.run(args, Config()) == 0
    out = capsys.readouterr().out
    assert "indoor:" in out and "outdoor:" in out and "seeds 100000" in out
    # Rendered sessions carry the simulator's truth: the report says where the errors are.
    assert out.count("locomotion oracle") == 3 and "near a mode change" in out
