"""`walkcap synth --format recording`: simulated sessions as recordings, and recordings
as training data (one dataset code path for synth and recordings)."""

import numpy as np
import pytest

from capture.corpus.dataset import labeled_session, read_sessions
from capture.corpus.trials import read_trial
from capture.recording.reader import frame_table, open_recording
from tests.recording_fixtures import synth_recording
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


def test_each_session_walks_with_a_walker_of_its_own(synth_folder, tmp_path):
    """Recordings draw the walker per session, as training sessions do (the same walker for
    the same seed), with the mounting calibrated for it; --fixed-walker keeps [simulator]."""
    from capture.corpus.dataset import session_walker
    from devices.config import SimulatorConfig

    walkers = []
    for f, seed in zip(sorted(synth_folder.glob("*.mcap")), (5, 6)):
        meta = open_recording(f).meta
        walker, pitch, _ = session_walker(seed, True, SimulatorConfig(), 0.5)
        recorded = meta.devices.to_dict()["simulator"]
        assert {k: recorded[k] for k in walker} == walker
        assert meta.software.to_dict()["preprocess"]["mounting_pitch_deg"] == pytest.approx(pitch)
        walkers.append(walker)
    assert walkers[0] != walkers[1]
    args = ["synth", "--format", "recording", "--out", str(tmp_path), "--sessions", "1"]
    assert cli.main([*args, "--seed", "5", "--frames", "2", "--fixed-walker"]) == 0
    (fixed,) = tmp_path.glob("*.mcap")
    recorded = open_recording(fixed).meta.devices.to_dict()["simulator"]
    assert recorded["speed_mps"] == SimulatorConfig().speed_mps
    assert recorded["camera_tilt_deg"] == SimulatorConfig().camera_tilt_deg


def test_writes_one_complete_recording_per_session(synth_folder):
    files = sorted(synth_folder.glob("*.mcap"))
    assert [f.name.split("_")[1] for f in files] == ["indoor", "outdoor"]
    for f in files:
        rec = open_recording(f)
        assert rec.topics["/camera/depth"].count == 40
        assert rec.topics["/imu"].count >= 39 / 15 * 100  # the IMU at 100 Hz up to the last frame
        trial = read_trial(f)
        assert np.all(trial.frames.labels >= 0)  # labelled from the first frame
        # the labels key the walker's locomotion mode, as an operator keys it live; the
        # terrain reference is what each image shows
        walker = {
            int(m.data["frame_index"]): m.data["locomotion_mode"]
            for m in rec.messages(["/sim/truth"])
        }
        keyed = [trial.MODES[k] for k in trial.frames.locomotion]
        assert keyed == [walker[int(i)] for i in trial.frames.index]
        np.testing.assert_array_equal(trial.frames.terrain, trial.truth)
        assert trial.frames.terrain_source == "simulator"


def test_recordings_are_training_sessions(synth_folder):
    sessions = read_sessions([synth_folder])
    assert len(sessions) == 2
    for s in sessions:
        assert s.source == "recording" and s.images.shape == (40, 100, 100)
        assert set(np.unique(s.images)) <= {0, 1}
        assert s.labels.min() >= 0


def test_each_frame_carries_the_geometry_its_terrain_features_show(synth_folder):
    """The cues of fusions "steady+geometry" and "steady+slope" offline: /terrain/features
    as the live pipeline recorded them, one mode (or -1) per decided frame."""
    from inference.features import ground_ahead, shown_mode

    for f in sorted(synth_folder.glob("*.mcap")):
        trial = read_trial(f, keep_features=False)  # as the evaluation reads it
        recorded = open_recording(f).messages(["/terrain/features"])
        features = {int(m.data["frame_index"]): m.data for m in recorded}
        expected = [
            shown_mode(features[i]["kind"], features[i]["direction"]) if i in features else -1
            for i in trial.frames.index.tolist()
        ]
        assert trial.frames.geometry.tolist() == expected
        assert (trial.frames.geometry >= 0).any()
        ahead = [
            ground_ahead(features[i].get("ahead_slope_deg")) if i in features else -1
            for i in trial.frames.index.tolist()
        ]
        assert trial.frames.ground_ahead.tolist() == ahead
        # the evaluation's trial keeps the cues alone, the whole table the features too
        assert all(f == {} for f in trial.frames.features)
        assert all(x for x in read_trial(f).frames.features[:10])
        table, _ = frame_table(open_recording(f))
        assert table.select(table.classified).geometry.tolist() == expected
        assert sum(bool(f) for f in table.features) == len(features)
        assert (trial.frames.ground_ahead >= 0).any()


def test_frames_before_the_first_operator_label_are_unlabelled(tmp_path):
    from tests.recording_fixtures import label_schedule, write_recording

    path = tmp_path / "r.mcap"
    write_recording(path, seconds=2.0)
    session = labeled_session(path, reference="labels")
    first_label = label_schedule(2.0)[0][0]
    trial = read_trial(path)
    unlabelled = trial.frames.time_ns < first_label
    assert np.all(session.labels[unlabelled[: len(session.labels)]] == -1)
    assert np.all(session.labels[~unlabelled[: len(session.labels)]] >= 0)


@pytest.mark.parametrize("method", ["steady+geometry", "steady+slope"])
def test_a_geometry_fusion_decides_offline_as_it_decided_live(tmp_path, method):
    """A recording made with [fusion] method = "steady+geometry" (or "steady+slope"): the
    fusion run offline on the recorded CNN outputs and terrain features repeats every live
    decision and posterior (so the live pipeline showed the fusion each frame's features,
    as eval does)."""
    from inference.evaluation.metrics import run_offline
    from inference.fusion import make_fusion

    path = synth_recording(tmp_path, method, "outdoor", 60)
    trial = read_trial(path)
    fusion = make_fusion(method)
    cues = trial.frames.geometry, trial.frames.ground_ahead
    offline = run_offline(fusion, trial.frames.probabilities, None, *cues)
    live = trial.frames.decision
    assert (live >= 0).sum() == len(live) - 1  # the last frame waits for a next one
    np.testing.assert_array_equal(offline.final[live >= 0], live[live >= 0])
    row = {int(i): k for k, i in enumerate(trial.frames.index)}
    posteriors = {
        row[m.data.get("posterior_frame_index", m.data["frame_index"])]: m.data["posterior"]
        for m in open_recording(path).messages(["/inference/fused"])
    }
    assert len(posteriors) == len(live) - 1 and (trial.frames.geometry >= 0).mean() > 0.5
    assert (trial.frames.ground_ahead >= 0).mean() > 0.5
    for k, posterior in posteriors.items():
        np.testing.assert_allclose(offline.posteriors[k], posterior, rtol=1e-9)


def test_recordings_hold_the_walks_gait_and_the_detectors_and_eval_gait_judges_them(
    synth_folder, capsys
):
    import json

    from capture.recording.gait import read_gait

    for f in sorted(synth_folder.glob("*.mcap")):
        rec = open_recording(f)
        truth, found = read_gait(rec, "simulator"), read_gait(rec, "imu")
        assert len(truth.heel_contacts()) >= 2 and len(found.heel_contacts()) >= 2
        frames = [m.publish_time_ns for m in rec.messages(["/camera/depth"])]
        assert frames[0] <= truth.time_ns.min() and truth.time_ns.max() <= frames[-1]
    assert cli.main(["eval", "gait", str(synth_folder), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert set(report["groups"]) == {"indoor", "outdoor", "all"}
    heel = report["groups"]["all"]["scores"]["heel_contact"]
    assert heel["true"] >= 4 and heel["recall"] == 1.0 and heel["precision"] == 1.0
    assert abs(heel["error_ms_median"]) < 20
