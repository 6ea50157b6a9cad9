"""`walkcap eval` per step: recordings with gait events and score files with a heel-contact
column carry `steps.<method>` in --json, a table in the text and a figure."""

import json

import pytest

from devices.frames import GaitEvent
from tests.recording_fixtures import T0, frame_time, write_trial
from tui import cli


def run(capsys, *argv):
    code = cli.main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def _trial_with_gait(path, condition: str):
    # the operator keys US at frame 40; the simulator's heel contacts every 10 frames,
    # the terrain under the foot US from the one at frame 45 on; the detector's events
    # 1 frame after the simulator's
    labels = [(T0, "LG", "operator"), (frame_time(40), "US", "operator")]
    session = {"subject": "S1", "condition": condition, "trial": 1}
    rec = write_trial(path, labels, session=session, frames=80, close=False)
    for k in range(5, 80, 10):
        mode = "US" if k >= 45 else "LG"
        rec.write_gait(GaitEvent(frame_time(k), "heel_contact", "simulator", mode))
        rec.write_gait(GaitEvent(frame_time(k + 5), "toe_off", "simulator", mode))
        rec.write_gait(GaitEvent(frame_time(k + 1), "heel_contact", "imu"))
        rec.write_gait(GaitEvent(frame_time(k + 6), "toe_off", "imu"))
    rec.close()
    return str(path)


def test_recordings_report_per_step_figures(capsys, tmp_path):
    paths = [
        _trial_with_gait(tmp_path / "S1_indoor_t01.mcap", "indoor"),
        _trial_with_gait(tmp_path / "S1_outdoor_t02.mcap", "outdoor"),
    ]
    methods = "cnn,steady,steady+steps"
    argv = ["eval", "recordings", *paths, "--reference", "locomotion", "--methods", methods]
    code, out, err = run(capsys, *argv, "--json")
    assert code == 0, err
    data = json.loads(out)
    keys = {
        "heel_contacts",
        "error_rate_at_heel_contact",
        "error_rate_at_toe_off",
        "transition_steps",
        "transition_steps_late",
        "lead_steps",
        "critical_errors",
    }
    for entry in data["files"]:
        assert set(entry["steps"]) == {"cnn", "steady", "steady+steps"}
        for stats in entry["steps"].values():
            assert keys <= set(stats)
            assert stats["heel_contacts"] == 8 and stats["transition_steps"] == 1
            assert stats["source"] == "simulator"
    # the CNN reads the terrain at 0.8: US from frame 40, so every heel contact is right
    cnn = data["files"][0]["steps"]["cnn"]
    assert cnn["error_rate_at_heel_contact"] == 0.0 and cnn["lead_steps"]["values"] == [0]
    assert data["steps"]["cnn"]["heel_contacts"] == 16  # pooled over both files
    assert {c["condition"] for c in data["conditions"] if "steps" in c} == {"indoor", "outdoor"}

    code, out, err = run(capsys, *argv)
    assert code == 0, err
    assert "per step (gait events: simulator" in out and "steady + steps" in out


@pytest.mark.slow
def test_recordings_with_gait_events_have_the_steps_figure(capsys, tmp_path):
    path = _trial_with_gait(tmp_path / "S1_indoor_t01.mcap", "indoor")
    fig = tmp_path / "fig"
    argv = ["eval", "recordings", path, "--reference", "locomotion", "--plot", str(fig)]
    code, _, err = run(capsys, *argv, "--methods", "cnn,steady+steps", "--plot-trials", "none")
    assert code == 0, err
    assert (fig / "steps.png").exists() and (fig / "steps.pdf").exists()


def test_recordings_without_gait_events_have_no_step_figures(capsys, tmp_path):
    path = tmp_path / "S1_indoor_t01.mcap"
    write_trial(path, [(T0, "LG", "operator")], frames=40)
    code, out, err = run(
        capsys, "eval", "recordings", str(path), "--reference", "locomotion", "--json"
    )
    assert code == 0, err
    data = json.loads(out)
    assert "steps" not in data and "steps" not in data["files"][0]
    assert "steady+steps" in data["files"][0]["accuracy"]  # runs, on its hold alone


def test_scores_with_a_heel_contact_column(capsys, tmp_path):
    rows = ["LG,US,DS,UR,DR,label,heel_contact"]
    for k in range(60):
        label = "LG" if k < 30 else "US"
        p = "0.9,0.025,0.025,0.025,0.025" if k < 30 else "0.025,0.9,0.025,0.025,0.025"
        rows.append(f"{p},{label},{1 if k % 8 == 3 else 0}")
    path = tmp_path / "s.csv"
    path.write_text("\n".join(rows) + "\n")
    code, out, err = run(
        capsys, "eval", "scores", str(path), "--json", "--methods", "cnn,steady+steps"
    )
    assert code == 0, err
    steps = json.loads(out)["files"][0]["steps"]
    assert steps["cnn"]["heel_contacts"] == 8 and steps["cnn"]["source"] == "scores"
    assert steps["cnn"]["error_rate_at_heel_contact"] == 0.0
