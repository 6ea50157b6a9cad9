"""`walkcap synth --format recording`: simulated sessions as recordings, and recordings
as training data (one dataset code path for synth and recordings)."""

import numpy as np
import pytest

from capture.corpus.dataset import read_sessions
from capture.recording.reader import labeled_session, open_recording, read_trial
from tui import cli


@pytest.fixture(scope="module")
def synth_folder(tmp_path_factory):
    out = tmp_path_factory.mktemp("synth")
    assert (
        cli.main(
            [
                "synth",
                "--format",
                "recording",
                "--out",
                str(out),
                "--sessions",
                "2",
                "--preset",
                "both",
                "--seed",
                "5",
                "--frames",
                "40",
            ]
        )
        == 0
    )
    return out


def test_writes_one_complete_recording_per_session(synth_folder):
    files = sorted(synth_folder.glob("*.mcap"))
    assert [f.name.split("_")[1] for f in files] == ["indoor", "outdoor"]
    for f in files:
        rec = open_recording(f)
        assert rec.topics["/camera/depth"].count == 40
        assert rec.topics["/imu"].count >= 39 / 15 * 100  # the IMU at 100 Hz up to the last frame
        trial = read_trial(f)
        assert np.all(trial["labels"] >= 0)  # labelled from the first frame
        # the labels key the walker's locomotion mode, as an operator keys it live; the
        # terrain reference is what each image shows
        walker = {
            int(m.data["frame_index"]): m.data["locomotion_mode"]
            for m in rec.messages(["/sim/truth"])
        }
        keyed = [trial["modes"][k] for k in trial["locomotion"]]
        assert keyed == [walker[int(i)] for i in trial["frame_index"]]
        np.testing.assert_array_equal(trial["terrain"], trial["truth"])
        assert trial["terrain_source"] == "simulator"


def test_recordings_are_training_sessions(synth_folder):
    sessions = read_sessions([synth_folder])
    assert len(sessions) == 2
    for s in sessions:
        assert s.source == "recording" and s.images.shape == (40, 100, 100)
        assert set(np.unique(s.images)) <= {0, 1}
        assert s.labels.min() >= 0


def test_frames_before_the_first_operator_label_are_unlabelled(tmp_path):
    from tests.recording_fixtures import label_schedule, write_recording

    path = tmp_path / "r.mcap"
    write_recording(path, seconds=2.0)
    session = labeled_session(path, reference="labels")
    first_label = label_schedule(2.0)[0][0]
    trial = read_trial(path)
    unlabelled = trial["time_ns"] < first_label
    assert np.all(session.labels[unlabelled[: len(session.labels)]] == -1)
    assert np.all(session.labels[~unlabelled[: len(session.labels)]] >= 0)
