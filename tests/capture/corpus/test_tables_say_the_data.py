"""The export and `info` say what the data holds: events in time order, time_s from the
recording's start (never negative), every column documented, marker notes shown, undone
label changes not listed as modes."""

import json
import re
from pathlib import Path

from capture.corpus import export
from capture.live.trials import SubjectInfo
from devices.base import DeviceEvent
from tests.recording_fixtures import T0, frame_time, write_recording, write_trial
from tui.cli import main

ROOT = Path(__file__).resolve().parents[3]
DOCS = ROOT / "docs" / "export.md"


def test_events_are_in_time_order(tmp_path):
    path = tmp_path / "t.mcap"
    rec = write_trial(path, [(frame_time(1), "LG", "operator")], close=False)
    # written in this order: a device event, then a marker placed earlier (the key press
    # came before the note was typed)
    rec.write_event(DeviceEvent(frame_time(60), "imu", "lost", "IMU lost"))
    rec.write_event(
        {"time_ns": frame_time(20), "device": "operator", "kind": "marker", "message": "slip"}
    )
    rec.write_event(DeviceEvent(frame_time(40), "camera", "stall", "no frame"))
    rec.close()
    events = export.tables(path)["events"]
    assert events["time_ns"].is_monotonic_increasing
    assert events["message"].tolist() == ["slip", "no frame", "IMU lost"]


def test_time_s_counts_from_the_recordings_start_and_is_never_negative(tmp_path):
    path = tmp_path / "t.mcap"
    write_recording(path, seconds=0.5)  # IMU samples are stamped 1 ms before they arrive
    tables = export.tables(path)
    firsts = {name: tables[name]["time_s"].min() for name in ("frames", "imu", "labels", "events")}
    assert all(v >= 0 for v in firsts.values()), firsts
    assert min(firsts.values()) == 0.0
    imu = tables["imu"]
    assert imu["time_s"].iloc[0] == 0.0 and imu["time_ns"].iloc[0] == T0
    frames = tables["frames"]  # one origin for every table: differences are true intervals
    gap = (frames["time_ns"].iloc[0] - imu["time_ns"].iloc[0]) * 1e-9
    assert abs(frames["time_s"].iloc[0] - imu["time_s"].iloc[0] - gap) < 1e-9


def documented_columns() -> set[str]:
    names = set()
    for line in DOCS.read_text().splitlines():
        if line.startswith("| `"):
            first_cell = line.split("|")[1]
            names |= set(re.findall(r"`([A-Za-z_0-9]+)`", first_cell))
            names |= set(re.findall(r"`(session_\w+)`", line))
    return names


def test_every_exported_column_is_documented(tmp_path):
    path = tmp_path / "t.mcap"
    write_recording(path, seconds=0.5)
    tables = export.tables(path)
    documented = documented_columns()
    for name, df in tables.items():
        missing = set(df.columns) - documented
        assert not missing, f"{name}: {sorted(missing)} not in docs/export.md"
    # a live session's form, operator and software, as Session writes them
    session_fields = {f"session_{k}" for k in SubjectInfo().to_metadata()} | {
        "session_operator",
        "session_supersedes",
    }
    wanted = session_fields - {"session_subject", "session_condition", "session_trial"}
    wanted |= {"model_hash", "model_path", "walkcap_version", "fusion_window"}
    assert not wanted - documented
    assert "decision_at_frame` is the frame whose arrival produced" in (
        (ROOT / "docs" / "recordings.md").read_text().replace("\n", " ")
    )


def test_info_shows_marker_notes_and_the_modes_as_they_stand(tmp_path, capsys):
    path = tmp_path / "t.mcap"
    labels = [
        (frame_time(1), "LG", "operator"),
        (frame_time(10), "DS", "operator"),  # a wrong key ...
        (frame_time(12), "LG", "undo:LG"),  # ... taken back
        (frame_time(30), "US", "operator"),
    ]
    rec = write_trial(path, labels, close=False)
    rec.write_event(
        {"time_ns": frame_time(20), "device": "operator", "kind": "marker", "message": "slip"}
    )
    rec.close()
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    (line,) = [x for x in out.splitlines() if x.startswith("  labels")]
    assert line.endswith(": LG US") and "DS" not in line and "1 undo(s) applied" in line
    assert re.search(r"marker\s+\+0\.\d s\s+slip", out)
    assert main(["info", "--json", str(path)]) == 0
    data = json.loads(capsys.readouterr().out)[0]
    assert [m["note"] for m in data["markers"]] == ["slip"]


def test_the_frames_table_has_every_recorded_terrain_feature(tmp_path):
    """The features the pipeline records (the IMU's tilt estimate among them) are columns,
    so `terrain_slope_deg + terrain_tilt_offset_deg` gives back the slope as leveled by the
    IMU alone."""
    path = tmp_path / "t.mcap"
    rec = write_trial(path, [(frame_time(1), "LG", "operator")], frames=3, close=False)
    rec.write_features(0, frame_time(0), {"slope_deg": 0.5, "tilt_offset_deg": -1.25})
    rec.close()
    frames = export.tables(path)["frames"]
    row = frames[frames.frame_index == 0].iloc[0]
    assert row.terrain_slope_deg + row.terrain_tilt_offset_deg == -0.75
    assert set(f"terrain_{n}" for n in export.FEATURE_FIELDS) <= set(frames.columns)
