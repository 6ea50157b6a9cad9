"""Labels, trials and corpora an analyst can trust: undo, identity and lineage, duplicate
trials, typed metadata, clock time, export and `info --json`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import scipy.io
from mcap.writer import Writer

from capture.corpus import selection as corpus
from capture.corpus.export import corpus_tables, matlab_name, tables, write
from capture.corpus.trials import read_trial
from capture.errors import CaptureError
from capture.recording import lineage, naming
from capture.recording import topics as T
from capture.recording.labels import LabelChange, effective_changes
from capture.recording.reader import open_recording
from capture.recording.recover import recover
from tests.old_recordings import as_version_1
from tests.recording_fixtures import T0, frame_time, write_trial
from tui import cli
from tui.replay import corrected_path, write_corrected

SESSION = {"subject": "S01", "condition": "indoor", "trial": 1}


def mistake_and_undo() -> list[tuple[int, str, str]]:
    """LG from the start; DS keyed by mistake at frame 30; undone at frame 60."""
    return [
        (T0, "LG", "operator"),
        (frame_time(30) + 1, "DS", "operator"),
        (frame_time(60) + 1, "LG", "undo:DS"),
    ]


# ---- undo ----------------------------------------------------------------------------


def test_an_undone_change_never_happened_but_stays_in_the_file(tmp_path):
    path = tmp_path / "S01_indoor_t01.mcap"
    write_trial(path, mistake_and_undo())
    trial = read_trial(path)
    assert "DS" not in [c[1] for c in trial.reference_changes]
    assert (trial.frames.labels == 0).all()  # LG on every frame: the mistake is gone
    assert [c[2] for c in trial.label_changes] == ["operator", "operator", "undo:DS"]


def test_two_undos_undo_two_changes():
    changes = [
        (0, "LG", "operator"),
        (10, "US", "operator"),
        (20, "DS", "operator"),
        (30, "US", "undo:DS"),
        (40, "LG", "undo:US"),
    ]
    assert effective_changes(changes) == [(0, "LG", "operator")]


def test_undoing_the_mode_in_force_at_the_start_restores_the_earlier_mode():
    # keyed before the recording started: the file knows only the start label
    changes = [(5, "DS", "start"), (20, "LG", "undo:DS")]
    assert effective_changes(changes) == [(5, "LG", "undo:DS")]


def test_corrections_lie_over_the_undone_reference():
    changes = [
        (0, "LG", "operator"),
        (10, "DS", "operator"),
        (15, "UR", "correction"),  # between the mistake and its undo: not what is undone
        (20, "LG", "undo:DS"),
    ]
    assert effective_changes(changes) == [(0, "LG", "operator"), (15, "UR", "correction")]


def test_export_of_a_trial_with_a_mistake_and_an_undo_has_no_frame_of_the_mistake(tmp_path):
    path = tmp_path / "S01_indoor_t01.mcap"
    write_trial(path, mistake_and_undo())
    t = tables(path)
    assert len(t["frames"]) == 90 and set(t["frames"]["label"]) == {"LG"}
    labels = t["labels"]
    assert list(labels["mode"]) == ["LG", "DS", "LG"]  # the audit trail
    assert list(labels["undone"]) == [False, True, False]
    assert list(labels["is_undo"]) == [False, False, True]


# ---- identity, lineage, corpus ---------------------------------------------------------


def _replay_of(source_path, target):
    """A replay file as capture.corpus.replay writes it: its own id and a derivation record."""
    source = open_recording(source_path)
    derived = lineage.derivation(source, "replay-id-1", lineage.REPLAY, "replay with model abc")
    write_trial(target, mistake_and_undo(), session=SESSION, metadata={"derivation": derived})


def test_a_folder_with_a_trial_its_copies_and_a_recovered_trial_counts_two_trials(tmp_path, capsys):
    folder = tmp_path / "recordings"
    folder.mkdir()
    a = folder / "S01_indoor_t01_20260101-100000.mcap"
    write_trial(a, mistake_and_undo(), session=SESSION)
    _replay_of(a, folder / "S01_indoor_t01_20260101-100000.replay.mcap")
    fix = [LabelChange(frame_time(45), "US", "correction")]
    corrected = write_corrected(a, corrected_path(a), fix, [])
    # trial 2: cut off by a crash, then recovered
    b_full = tmp_path / "full.mcap"
    write_trial(b_full, [(T0, "LG", "operator")], session={**SESSION, "trial": 2})
    b = folder / "S01_indoor_t02_20260101-101000.mcap"
    b.write_bytes(b_full.read_bytes()[: b_full.stat().st_size // 2])
    recovered = Path(recover(b).output)

    chosen = corpus.select([folder])
    assert sorted(p.name for p in chosen.files) == sorted([corrected.name, recovered.name])
    why = {p.name: reason for p, reason in chosen.left_out}
    assert set(why) == {a.name, b.name, "S01_indoor_t01_20260101-100000.replay.mcap"}
    assert "corrected" in why[a.name] and "unfinished" in why[b.name]
    assert "another model" in why["S01_indoor_t01_20260101-100000.replay.mcap"]

    # lineage in the files: own ids, source ids
    copy = open_recording(corrected)
    assert copy.id != open_recording(a).id
    assert copy.metadata["derivation"]["source_id"] == open_recording(a).id
    assert open_recording(recovered).metadata["derivation"]["kind"] == "recovered"

    # the corrected labels are the reference of trial 1
    assert (read_trial(corrected).frames.labels[45:] == 1).all()

    # live keys only in trial 2: its accuracy only against them, asked for
    assert cli.main(["eval", "recordings", str(folder), "--json"]) == 1
    assert "no terrain reference" in capsys.readouterr().err
    assert cli.main(["eval", "recordings", str(folder), "--json", "--reference", "locomotion"]) == 0
    out = capsys.readouterr()
    assert len(json.loads(out.out)["files"]) == 2
    assert "left out 3 file(s)" in out.err and a.name in out.err

    with_replays = corpus.select([folder], replays=True)
    assert [p.name for p in with_replays.files] == ["S01_indoor_t01_20260101-100000.replay.mcap"]
    argv = ["eval", "recordings", str(folder), "--replays", "--json", "--reference", "locomotion"]
    assert cli.main(argv) == 0
    out = capsys.readouterr()
    assert len(json.loads(out.out)["files"]) == 1 and "no replay of this trial" in out.err

    # training takes one file per trial too: no trial in both training and test
    from capture.corpus.dataset import select_session_files

    files, lines = select_session_files([folder])
    assert sorted(f.name for f in files) == sorted([corrected.name, recovered.name])
    assert any("left out 3 file(s)" in line for line in lines)


def test_old_derived_files_are_recognised_by_their_names_and_records(tmp_path):
    a = tmp_path / "S01_indoor_t01.mcap"
    write_trial(a, mistake_and_undo())
    old_replay = tmp_path / "S01_indoor_t01.replay.mcap"
    new = tmp_path / "b.mcap"
    write_trial(new, mistake_and_undo(), metadata={"software": {"replay_of": a.name}})
    as_version_1(new, old_replay)  # format version 1: derived files had no "derivation"
    new.unlink()
    chosen = corpus.select([tmp_path])
    assert chosen.files == [a]
    assert chosen.left_out[0][0] == old_replay


def test_an_overwrite_supersedes_the_earlier_recording_of_the_trial(tmp_path):
    first = tmp_path / "S01_indoor_t01_a.mcap"
    write_trial(first, mistake_and_undo())
    trial, supersedes, notice = naming.trial_conflict(
        tmp_path, "S01", "indoor", 1, naming.OVERWRITE
    )
    assert trial == 1 and supersedes == [open_recording(first).id] and "supersedes" in notice
    again = tmp_path / "S01_indoor_t01_b.mcap"
    write_trial(again, mistake_and_undo(), session={**SESSION, "supersedes": supersedes})
    chosen = corpus.select([tmp_path])
    assert chosen.files == [again] and "superseded" in chosen.left_out[0][1]


# ---- duplicate trials -------------------------------------------------------------------


def test_an_existing_trial_moves_to_the_next_free_number_or_is_refused(tmp_path):
    for n in (1, 2, 4):
        write_trial(tmp_path / f"S01_indoor_t{n:02d}_x.mcap", [], session={**SESSION, "trial": n})
    (tmp_path / "S01_indoor_t01_x.replay.mcap").write_bytes(b"")  # same trial, not a new one
    trial, _, notice = naming.trial_conflict(tmp_path, "S01", "indoor", 1, naming.NEXT_TRIAL)
    assert trial == 3 and "trial 1 exists" in notice and "recording trial 3" in notice
    assert naming.trial_conflict(tmp_path, "S01", "outdoor", 1, naming.TRIAL_ERROR)[0] == 1
    with pytest.raises(CaptureError, match="trial 2 exists.*--overwrite"):
        naming.trial_conflict(tmp_path, "S01", "indoor", 2, naming.TRIAL_ERROR)


def test_record_refuses_an_explicit_existing_trial_before_opening_devices(tmp_path, capsys):
    write_trial(tmp_path / "S01_indoor_t01_x.mcap", [])
    code = cli.main(
        ["record", "--out", str(tmp_path), "--subject", "S01", "--condition", "indoor",
         "--trial", "1"]
    )  # fmt: skip
    assert code == 1
    assert "trial 1 exists" in capsys.readouterr().err
    assert len(list(tmp_path.glob("*.mcap"))) == 1


# ---- typed metadata, clock time ----------------------------------------------------------


def test_metadata_comes_back_typed(tmp_path):
    path = tmp_path / "t.mcap"
    session = {**SESSION, "height_m": 1.78, "amputee": True, "age": None, "tags": ["a", "b"]}
    write_trial(path, [], session=session)
    rec = open_recording(path)
    assert rec.metadata["session"] == session
    assert isinstance(rec.metadata["recording"]["unix_offset_ns"], int)
    assert rec.trial == ("S01", "indoor", 1)


def _old_style_file(path):
    """A file as walkcap wrote it before JSON metadata values and recording ids."""
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="", library="walkcap 0.0.9")
        w.add_metadata(
            "session",
            {"subject": "S07", "condition": "outdoor", "trial": "3", "height_m": "1.78",
             "amputee": "True", "age": "", "notes": "old"},
        )  # fmt: skip
        w.add_metadata(
            "recording", {"format_version": "1", "unix_offset_ns": "1700000000000000000"}
        )
        channels = {}
        for topic in (T.CNN, T.LABELS):
            spec = T.TOPICS[topic]
            sid = w.register_schema(spec.schema_name, spec.schema_encoding, spec.schema_data)
            channels[topic] = w.register_channel(topic, spec.message_encoding, sid)
        for topic, t, data in [
            (T.LABELS, T0, T.label_json(T0, "LG", "operator")),
            (T.LABELS, frame_time(3), T.label_json(frame_time(3), "DS", "operator")),
            (T.LABELS, frame_time(6), T.label_json(frame_time(6), "LG", "undo:DS")),
        ] + [(T.CNN, frame_time(i), T.cnn_json(i, frame_time(i), np.eye(5)[0])) for i in range(10)]:
            w.add_message(channels[topic], t, T.encode_json(data), t)
        w.finish()


def test_a_file_from_before_typed_metadata_still_reads(tmp_path):
    path = tmp_path / "S07_outdoor_t03.mcap"
    _old_style_file(path)
    rec = open_recording(path)
    session = rec.metadata["session"]
    assert session["trial"] == 3 and session["height_m"] == 1.78 and session["amputee"] is True
    assert session["age"] is None and session["notes"] == "old"
    assert rec.id.startswith("file:") and rec.trial == ("S07", "outdoor", 3)
    trial = read_trial(path)
    assert (trial.frames.labels == 0).all()  # the undo applies in old files too
    assert trial.unix_time_ns[0] == frame_time(0) + 1_700_000_000_000_000_000
    assert corpus.select([tmp_path]).files == [path]


def test_messages_carry_unix_time(tmp_path):
    path = tmp_path / "t.mcap"
    write_trial(path, [(T0, "LG", "operator")])
    rec = open_recording(path)
    m = next(rec.messages([T.CNN]))
    assert m.unix_time_ns == m.publish_time_ns + rec.unix_offset_ns
    offset_s = rec.unix_offset_ns * 1e-9
    assert abs(offset_s + T0 * 1e-9 - __import__("time").time()) < 1e9  # plausible epoch


# ---- export, info --json -----------------------------------------------------------------


FRAME_COLUMNS = {
    "frame_index", "time_ns", "unix_time_ns", "time_s", "label", "p_LG", "p_DR",
    "cnn_decision", "posterior_LG", "decision", "decision_at_frame", "voted",
    "voted_at_frame", "terrain_kind", "preprocess_flag", "oriented", "qw", "qz",
    "subject", "condition", "trial", "recording_id",
}  # fmt: skip


def test_export_cli_writes_parquet_that_pandas_reads_and_mat_that_scipy_reads(tmp_path, capsys):
    folder = tmp_path / "rec"
    folder.mkdir()
    write_trial(folder / "S01_indoor_t01_x.mcap", mistake_and_undo())
    write_trial(folder / "S01_indoor_t02_x.mcap", [(T0, "US", "operator")],
                session={**SESSION, "trial": 2})  # fmt: skip
    out = tmp_path / "tables"
    assert cli.main(["export", str(folder), "--format", "parquet", "-o", str(out)]) == 0
    frames = pd.read_parquet(out / "frames.parquet")
    assert FRAME_COLUMNS <= set(frames.columns) and len(frames) == 180
    assert set(frames[frames.trial == 1].label) == {"LG"}
    assert set(frames[frames.trial == 2].label) == {"US"}
    assert frames.time_s.iloc[0] == pytest.approx(0.0) and frames.unix_time_ns.iloc[0] > 1e18
    for name in ("imu", "labels", "events", "trials"):
        assert (out / f"{name}.parquet").exists()
    assert len(pd.read_parquet(out / "trials.parquet")) == 2

    assert cli.main(["export", str(folder), "--format", "mat", "--out", str(out)]) == 0
    mat = scipy.io.loadmat(out / "walkcap.mat", squeeze_me=True, struct_as_record=False)
    f = mat["frames"]
    assert set(f._fieldnames) >= FRAME_COLUMNS
    assert len(f.time_s) == 180 and list(f.label[:3]) == ["LG", "LG", "LG"]
    assert f.time_ns.dtype == np.int64  # nanoseconds keep every digit
    assert mat["trials"].subject.tolist() == ["S01", "S01"]

    assert cli.main(["export", str(folder), "--format", "csv", "-o", str(out)]) == 0
    assert len(pd.read_csv(out / "labels.csv")) == 4


def test_export_lists_what_it_leaves_out(tmp_path, capsys):
    a = tmp_path / "S01_indoor_t01.mcap"
    write_trial(a, mistake_and_undo())
    as_version_1(a, tmp_path / "S01_indoor_t01.recovered.mcap")  # a version 1 copy, by name
    t, chosen = corpus_tables([tmp_path])
    assert chosen.files == [a] and len(t["trials"]) == 1
    assert cli.main(["export", str(tmp_path), "-o", str(tmp_path / "o"), "--quiet"]) == 0
    assert "recovered copy" in capsys.readouterr().err


def test_matlab_names_are_identifiers():
    assert matlab_name("p_LG") == "p_LG" and matlab_name("1st col") == "x1st_col"
    assert len(matlab_name("a" * 80)) == 63


def test_info_json_has_the_table_typed(tmp_path, capsys):
    path = tmp_path / "S01_indoor_t01.mcap"
    write_trial(path, mistake_and_undo(), session={**SESSION, "height_m": 1.8})
    assert cli.main(["info", "--json", str(path)]) == 0
    [data] = json.loads(capsys.readouterr().out)
    assert data["trial"] == {"subject": "S01", "condition": "indoor", "trial": 1}
    assert data["metadata"]["session"]["height_m"] == 1.8
    assert data["topics"][T.CNN]["messages"] == 90
    assert data["start"]["unix_ns"] == data["start"]["session_ns"] + data["unix_offset_ns"]
    assert data["start"]["utc"].startswith("20")
    assert [x["in_reference"] for x in data["labels"]] == [True, False, False]
    assert cli.main(["info", str(path)]) == 0
    text = capsys.readouterr().out
    assert "session clock" in text and "S01 indoor trial 1" in text and "1 undo(s)" in text


def test_write_rejects_an_unknown_format(tmp_path):
    with pytest.raises(CaptureError, match="one of parquet, csv, mat"):
        write({}, tmp_path, "xlsx")


def test_the_replay_screen_shows_the_reference_with_the_undo_applied(tmp_path):
    from tui.replay import ReplaySource

    path = tmp_path / "S01_indoor_t01.mcap"
    write_trial(path, mistake_and_undo())
    source = ReplaySource(path, play=False)
    source.start()
    labels = source._labels_at(source.frames.time_ns)
    assert (labels == 0).all()  # LG throughout: the DS keyed by mistake never shows


def test_a_session_records_the_next_free_trial_and_says_so(tmp_path):
    from capture.config import Config
    from capture.live.session import Session
    from capture.live.trials import SubjectInfo

    write_trial(tmp_path / "S01_indoor_t01_x.mcap", [])
    config = Config()
    config.session.recordings = str(tmp_path)
    session = Session(config)  # devices not started: recording needs only the folder
    path = session.start_recording(SubjectInfo(subject="S01", condition="indoor", trial=1))
    try:
        assert "_t02_" in path.name and "recording trial 2" in session.trial_notice
        assert session.trial.trial == 2
    finally:
        session.stop_recording()
    assert open_recording(path).metadata["session"]["trial"] == 2
    with pytest.raises(CaptureError, match="exists"):
        session.start_recording(SubjectInfo(subject="S01", condition="indoor"), "error")
