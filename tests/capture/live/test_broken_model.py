"""A broken model never costs raw data: a classifier that returns NaN, raises or runs late
leaves every frame, label and IMU sample recorded, and says so in one event per run; a
model file with NaN weights is refused at load; evaluation never scores NaN as right."""

from __future__ import annotations

import time

import numpy as np
import pytest
import torch

from capture.config import Config
from capture.live.session import Session
from capture.live.trials import SubjectInfo
from capture.recording import topics as T
from capture.recording.reader import open_recording
from inference.errors import InferenceError
from inference.evaluation.metrics import run_offline
from inference.fusion import make_fusion
from inference.model import BUNDLED_PATH, TerrainCNN, load_classifier, read_metadata, save_model
from inference.training import group_metrics
from tui import cli


@pytest.fixture(scope="module")
def nan_model(tmp_path_factory):
    """The bundled model's shapes, one weight NaN: what a diverged training run writes."""
    meta = read_metadata(BUNDLED_PATH)
    net = TerrainCNN(hidden=meta["architecture"]["hidden"])
    net.load_state_dict(torch.load(BUNDLED_PATH, weights_only=True))
    with torch.no_grad():
        next(net.parameters()).view(-1)[0] = float("nan")
    return save_model(net, tmp_path_factory.mktemp("model") / "nan.pt", {})


def test_a_model_with_nan_weights_is_refused_at_load(nan_model):
    with pytest.raises(InferenceError, match="no finite output on a probe image"):
        load_classifier(nan_model)
    load_classifier(None)  # the bundled model passes the probe


@pytest.mark.parametrize(
    "argv",
    [["record", "--duration", "3", "--auto-label", "--model"], ["eval", "model", "--model"]],
)
def test_commands_refuse_it_with_one_line(nan_model, capsys, argv):
    assert cli.main([*argv, str(nan_model)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nan.pt" in err[0] and "finite" in err[0]


def test_evaluation_never_scores_nan_as_right():
    from inference.evaluation.metrics import decisions_of

    p = np.full((6, 5), 0.05)
    p[:, 0] = 0.8
    p[2] = np.nan
    decided = decisions_of(p)
    assert decided.tolist() == [0, 0, -1, 0, 0, 0]
    labels = np.zeros(6, dtype=int)
    assert group_metrics(labels, decided).accuracy == pytest.approx(5 / 6)
    assert group_metrics(labels, np.full(6, -1)).accuracy == 0.0
    run = run_offline(make_fusion("hmm+voting"), p)
    assert run.final[2] == -1 and (np.delete(run.final, 2) == 0).all()  # no NaN spread


class _Classifier:
    metadata = {"weights_sha256": "test"}

    def __init__(self, broken) -> None:
        self.calls = 0
        self.broken = broken

    def predict(self, image):
        self.calls += 1
        if self.calls <= 3:  # the session's warm-up
            return np.full(5, 0.2)
        return self.broken(image)


def _nan(image):
    return np.full(5, np.nan)


def _raises(image):
    raise RuntimeError("CUDA error: an illegal memory access")


def _late(image):
    time.sleep(0.4)
    return np.full(5, 0.2)


def record(tmp_path, classifier, seconds=2.0):
    cfg = Config()
    cfg.session.recordings = str(tmp_path)
    cfg.camera.fps = 15.0
    session = Session(cfg, classifier=classifier, auto_label=True)
    session.start()
    try:
        path = session.start_recording(SubjectInfo(subject="S01", condition="indoor"))
        time.sleep(seconds)
        session.set_label("US")
    finally:
        stats = session.stop()
    return open_recording(path), stats, session.snapshot()


@pytest.mark.realtime
@pytest.mark.parametrize("broken", [_nan, _raises, _late], ids=["nan", "raises", "late"])
def test_a_broken_classifier_never_costs_a_raw_frame_or_a_label(tmp_path, broken):
    rec, stats, snap = record(tmp_path, _Classifier(broken))
    depth = rec.topics[T.DEPTH].count
    assert depth >= 0.8 * 15 * 2.0  # every frame the camera gave, not what the model managed
    assert rec.topics[T.IMU].count >= 40  # the IMU records on (fewer on a loaded machine)
    labels = [m.data for m in rec.messages([T.LABELS])]
    assert any(d["source"] in ("start", "simulator") for d in labels)  # the auto label
    assert any(d["mode"] == "US" and d["source"] == "operator" for d in labels)
    events = [m.data for m in rec.messages([T.EVENTS]) if m.data["device"] == "pipeline"]
    assert 1 <= len(events) <= 4  # a run of failures: its start and its count
    assert events[-1]["details"]["count"] >= (1 if broken is _late else depth - 2)
    if broken is not _late:
        assert T.CNN not in rec.topics or rec.topics[T.CNN].count == 0
        assert rec.topics[T.CLOUD].count >= depth - 2  # the preprocessing still recorded
    assert stats.state != "failed"
