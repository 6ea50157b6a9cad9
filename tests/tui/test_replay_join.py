"""One per-frame join (capture.recording.frames): `read_trial`, `walkcap export` and the
replay screen see the same frames, decisions, votes, labels and truth, as recorded."""

import numpy as np
import pytest

from capture.corpus.export import tables
from capture.corpus.trials import read_trial
from capture.recording.labels import mode_index
from capture.recording.writer import Recorder
from devices.frames import MODES
from inference.preprocess import STALE_ORIENTATION
from tui.replay import ReplaySource

FPS = 15
N = 40
T0 = 7_000_000_000
STALE = 9  # a frame left undecided: a preprocessing record, no CNN output


def frame_time(i: int) -> int:
    return T0 + int(i * 1e9 / FPS)


def true_mode(i: int) -> int:
    return 0 if i < 20 else 1


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """Fused decisions name the frame before, votes the frame before that; the operator
    keys US by mistake at frame 12 and undoes it at frame 15, and keys US at frame 24."""
    path = tmp_path_factory.mktemp("join") / "S02_indoor_t01.mcap"
    rec = Recorder(path, metadata={"session": {"subject": "S02", "condition": "indoor"}})
    rec.start()
    rec.write_label(T0, "LG", "operator")
    rec.write_label(frame_time(12) + 1, "US", "operator")
    rec.write_label(frame_time(15) + 1, "LG", "undo:US")
    rec.write_label(frame_time(24) + 1, "US", "operator")
    image = np.zeros((100, 100), np.uint8)
    cloud = np.zeros((10, 3), np.float32)
    for i in range(N):
        t = frame_time(i)
        flag = STALE_ORIENTATION if i == STALE else ""
        rec.write_processed(i, t, t + 1_000_000, cloud, image, np.array([1.0, 0, 0, 0]), flag)
        if i == STALE:
            continue
        probs = np.full(5, 0.05)
        probs[true_mode(i)] = 0.8
        fused = (
            {
                "frame_index": i - 1,
                "decision": MODES[true_mode(i - 1)],
                "posterior": probs,
                "voted": MODES[true_mode(i - 2)],
                "voted_frame_index": i - 2,
            }
            if i >= 2
            else {}
        )
        rec.write_inference(i, t, t + 2_000_000, probs, fused)
        rec.write_truth(i, t, {"mode": MODES[true_mode(i)]})
    rec.close()
    return path


def test_read_trial_export_and_the_replay_screen_show_the_same_frames(recording):
    trial = read_trial(recording)
    frames = tables(recording)["frames"]
    source = ReplaySource(recording, play=False)
    source.start()
    shown = source.frames

    # every frame in export and on the screen, the undecided one too; read_trial: classified
    assert list(frames.frame_index) == list(range(N)) == list(shown.index)
    classified = [i for i in range(N) if i != STALE]
    assert list(trial.frames.index) == classified
    rows = np.array(classified)

    exported = {
        "decisions": [mode_index(m) for m in frames.decision],
        "voted": [mode_index(m) for m in frames.voted],
        "labels": [mode_index(m) for m in frames.label],
        "truth": [mode_index(m) for m in frames.truth],
    }
    on_screen = {
        "decisions": shown.fused,
        "voted": shown.voted,
        "labels": source._labels_at(shown.time_ns),
        "truth": shown.truth,
    }
    read = {
        "decisions": trial.frames.decision,
        "voted": trial.frames.voted,
        "labels": trial.frames.labels,
        "truth": trial.truth,
    }
    for name in exported:
        assert list(read[name]) == list(np.array(exported[name])[rows]), name
        assert list(exported[name]) == list(on_screen[name]), name
    assert list(trial.frames.time_ns) == list(frames.time_ns[rows]) == list(shown.time_ns[rows])
    p = frames[[f"p_{m}" for m in MODES]].to_numpy()
    np.testing.assert_array_equal(trial.frames.probabilities, p[rows])
    np.testing.assert_allclose(shown.probabilities, p, rtol=1e-7)  # the screen keeps float32

    # and what the join says is what was recorded
    decided = [j for j in range(1, N - 1) if j + 1 != STALE]  # decided when j + 1 came
    assert [trial.frames.decision[classified.index(j)] for j in decided if j != STALE] == [
        true_mode(j) for j in decided if j != STALE
    ]
    assert frames.decision[STALE] == MODES[true_mode(STALE)]  # decided at the next frame
    assert frames.decision_at_frame[STALE] == STALE + 1
    assert frames.voted_at_frame[5] == 7 and frames.voted[5] == MODES[true_mode(5)]
    assert frames.decision[N - 1] == "" and frames.preprocess_flag[STALE] == STALE_ORIENTATION
    assert np.isnan(p[STALE]).all() and shown.cnn[list(shown.index).index(STALE)] == -1
    # the undone US never shows; the US at frame 24 holds from frame 25
    expected = [0 if i <= 24 else 1 for i in range(N)]
    assert exported["labels"] == expected
    assert trial.frames.terrain_source == "simulator"
    assert list(frames.terrain) == list(frames.truth)
    # the big display shows the latest decision produced: none before frame 2
    assert list(shown.fused_shown[:3]) == [-1, -1, true_mode(1)]
