"""Shared copies (capture.corpus.share): the personal fields reduced by the rules, the sensor,
label and decision messages as recorded, dates moved by one offset per subject or study."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest

from capture.corpus import export
from capture.corpus.share import share
from capture.errors import CaptureError
from capture.recording import lineage, open_recording
from capture.recording import personal as P
from capture.recording import topics as T
from capture.recording.copy import copy_recording
from capture.recording.messages import iter_raw
from capture.recording.writer import Recorder
from tests.recording_fixtures import (
    frame_time,
    imu_sample,
    write_decision,
)

NAME = "Anna Schmidt"
NOTES = f"{NAME}, transfemoral, came from Uniklinik ward 3"
OPERATOR = "Jane Doe"
MARKER = "Anna stumbled"
RULES = P.ShareRules(secret="the study's secret")
STAMPS = {
    ("S01", 1): "20261122-101500",
    ("S01", 2): "20261122-103000",
    ("S02", 1): "20261123-090000",
}


def write(folder: Path, subject: str, trial: int, *, utc: bool = False) -> Path:
    """A small trial with personal fields everywhere walkcap puts them."""
    path = folder / f"{subject}_indoor_t{trial:02d}_{STAMPS[subject, trial]}.mcap"
    session = {
        "subject": subject,
        "condition": "indoor",
        "trial": trial,
        "age": 37,
        "height_m": 1.78,
        "weight_kg": 81.3,
        "sex": "female",
        "amputee": True,
        "side": "left",
        "residual_limb_cm": 31.0,
        "notes": NOTES,
        "operator": OPERATOR,
    }
    toml = f'[session]\noperator = "{OPERATOR}"\n'.encode()
    rec = Recorder(
        path,
        metadata={"session": session, "software": {"replay_of": ""}},
        attachments={"walkcap.toml": toml, "model.json": b'{"hash": "abc"}'},
        queue_size=100_000,
    )
    rec.start()
    for k in range(20):
        sample = imu_sample(k)
        if utc and k == 3:
            sample.extra = {"utc_time": [5, 2026, 3, 1, 10, 15, 0, 7]}
        rec.write_imu(sample)
    rec.write_label(frame_time(0), "LG", "operator")
    for i in range(20):
        write_decision(rec, i)
    rec.write_event(
        {"time_ns": frame_time(5), "device": "operator", "kind": "marker", "message": MARKER}
    )
    rec.write_event(
        {"time_ns": frame_time(6), "device": "imu", "kind": "gap", "message": "3 missing"}
    )
    rec.close()
    return path


@pytest.fixture(scope="module")
def lab(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("lab") / "recordings"
    folder.mkdir()
    write(folder, "S01", 1)
    t2 = write(folder, "S01", 2)
    write(folder, "S02", 1)
    corrected = folder / t2.name.replace(".mcap", "_corrected.mcap")
    label = T.label_json(frame_time(10), "US", "correction")
    copy_recording(
        t2, corrected, kind=lineage.CORRECTED, how="1 label correction(s)", labels=[label]
    )
    return folder


@pytest.fixture(scope="module")
def shared(lab, tmp_path_factory) -> tuple[Path, list]:
    out = tmp_path_factory.mktemp("shared")
    copies, _ = share([lab], out, RULES)
    return out, copies


def everything(path: Path) -> bytes:
    """Every byte a reader can get out of a recording: messages, metadata, attachments."""
    rec = open_recording(path)
    parts = [bytes(m.data) for _, _, m in iter_raw(rec.path, rec.complete, None)]
    parts += [repr(rec.raw_metadata_records).encode(), repr(rec.metadata_records).encode()]
    parts += [bytes(v) for v in rec.attachments.values()]
    return b"\n".join(parts)


def messages(path: Path, topics: set[str] | None = None) -> Counter:
    rec = open_recording(path)
    return Counter(
        (c.topic, m.log_time, m.publish_time, m.sequence, bytes(m.data))
        for _, c, m in iter_raw(rec.path, rec.complete, None)
        if topics is None or c.topic in topics
    )


def test_one_copy_per_trial_named_without_times(shared):
    out, copies = shared
    assert sorted(p.name for p in out.iterdir()) == [
        "S01_indoor_t01.mcap",
        "S01_indoor_t02.mcap",
        "S02_indoor_t01.mcap",
    ]
    t2 = open_recording(out / "S01_indoor_t02.mcap")
    assert t2.metadata["derivation"]["source_kind"] == lineage.CORRECTED  # it stands for t02
    member = lineage.describe(t2)
    assert member.kind == lineage.SHARED and "2026" not in member.source_name


def test_nothing_personal_is_left_in_a_shared_copy(lab, shared):
    out, _ = shared
    original = everything(next(lab.glob("S01_indoor_t01_*.mcap")))
    assert NAME.encode() in original and OPERATOR.encode() in original  # the test sees them
    for path in out.iterdir():
        blob = everything(path)
        for text in (NAME, "Schmidt", "Uniklinik", OPERATOR, MARKER, "20261122", "20261123"):
            assert text.encode() not in blob, (path.name, text)
    session = open_recording(out / "S01_indoor_t01.mcap").metadata["session"]
    assert session["notes"] == "" and session["operator"] == ""
    assert (session["age"], session["height_m"], session["amputee"]) == (37, 1.78, True)


def test_an_export_of_the_shared_copies_holds_no_name(shared):
    out, _ = shared
    tables, _ = export.corpus_tables([out])
    for name, df in tables.items():
        text = df.to_csv()
        for word in (NAME, "Schmidt", "Uniklinik", OPERATOR, MARKER, "20261122"):
            assert word not in text, (name, word)
    assert len(tables["trials"]) == 3 and set(tables["trials"]["kind"]) == {lineage.SHARED}


def test_sensor_label_and_decision_messages_are_byte_for_byte(lab, shared):
    out, _ = shared
    kept = {T.IMU, T.LABELS, "/inference/cnn", "/inference/fused"}
    for source, name in (
        (next(lab.glob("S01_indoor_t01_*.mcap")), "S01_indoor_t01.mcap"),
        (next(lab.glob("S01_indoor_t02_*_corrected.mcap")), "S01_indoor_t02.mcap"),
    ):
        assert messages(out / name, kept) == messages(source, kept)
        assert messages(out / name, kept)  # there is something to compare
    events = [m.data for m in open_recording(out / "S01_indoor_t01.mcap").messages([T.EVENTS])]
    marker = next(e for e in events if e["device"] == "operator")
    assert marker["message"] == "marker" and marker["time_ns"] == frame_time(5)
    assert any(e["message"] == "3 missing" for e in events)  # device events as they were


def test_dates_move_by_one_offset_per_subject_reproducibly(lab, shared, tmp_path):
    out, _ = shared

    def offset(path):
        return open_recording(path).unix_offset_ns

    originals = {p.name[:14]: offset(p) for p in lab.glob("*.mcap") if "corrected" not in p.name}
    moved = {n: offset(out / f"{n}.mcap") - originals[n] for n in originals}
    assert moved["S01_indoor_t01"] == moved["S01_indoor_t02"] != 0
    assert moved["S01_indoor_t01"] % P.DAY_NS == 0 and moved["S01_indoor_t01"] < 0
    assert moved["S02_indoor_t01"] != moved["S01_indoor_t01"]
    assert moved["S01_indoor_t01"] == P.date_offset_ns(RULES, "S01")
    again, _ = share([lab], tmp_path / "again", RULES)
    assert {c.path.name: offset(c.path) for c in again} == {
        p.name: offset(p) for p in out.iterdir()
    }
    study, _ = share([lab], tmp_path / "study", P.ShareRules(secret="s", dates="study"))
    offsets = {offset(c.path) - originals[c.path.stem] for c in study}
    assert len(offsets) == 1


def test_the_imu_utc_date_moves_with_the_dates(tmp_path):
    (tmp_path / "lab").mkdir()
    source = write(tmp_path / "lab", "S01", 1, utc=True)
    (copy,), _ = share([source], tmp_path / "out", P.ShareRules(shift_days=-1))
    utc = [
        m.data["extra"]["utc_time"]
        for m in open_recording(copy.path).messages([T.IMU])
        if "utc_time" in m.data["extra"]
    ]
    assert utc == [[5, 2026, 2, 28, 10, 15, 0, 7]]
    assert copy.rewritten == {T.IMU: 1, T.EVENTS: 1}


def test_the_copy_says_what_was_removed(shared):
    out, copies = shared
    sharing = open_recording(out / "S01_indoor_t01.mcap").metadata["sharing"]
    assert "notes dropped" in sharing["removed"] and "operator dropped" in sharing["removed"]
    assert sharing["rules"]["notes"] == "drop" and "secret" not in repr(sharing)
    assert "dates shifted (whole days)" in sharing["removed"]


def test_rules_are_checked_and_nothing_is_overwritten(lab, shared, tmp_path):
    with pytest.raises(CaptureError, match="secret"):
        share([lab], tmp_path / "x", P.ShareRules())
    assert not (tmp_path / "x").exists()
    with pytest.raises(CaptureError, match="exists"):
        share([lab], shared[0], RULES)
    for inside in (lab, lab / "shared"):
        with pytest.raises(CaptureError, match="folder of their own"):
            share([lab], inside, RULES)
    assert not (lab / "shared").exists()


def test_a_superseded_recording_is_not_shared(tmp_path):
    lab = tmp_path / "lab"
    lab.mkdir()
    first = write(lab, "S02", 1)
    again = lab / "S02_indoor_t01_20261123-091500.mcap"
    session = {"subject": "S02", "condition": "indoor", "trial": 1, "notes": NOTES}
    session["supersedes"] = [open_recording(first).id]
    with Recorder(again, metadata={"session": session}) as rec:
        rec.write_label(frame_time(0), "US", "operator")
    (copy,), corpus = share([lab], tmp_path / "out", RULES)
    assert copy.source == again and [p for p, _ in corpus.left_out] == [first]
