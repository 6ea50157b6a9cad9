"""A name typed into the form's Notes reaches no shared copy and no export of the shared copies;
`walkcap forget` leaves no trace of a subject in the configuration folder; the marker's note
stays out of tui.log."""

from __future__ import annotations

import logging
import os
import stat
from pathlib import Path

import pytest
from textual.widgets import Input

from capture.config import Config
from capture.live.trials import TrialFile, trial_metadata
from capture.recording import open_recording
from capture.recording.messages import iter_raw
from capture.recording.writer import Recorder
from tests.recording_fixtures import (
    frame_time,
    imu_sample,
    write_decision,
)
from tests.tui.screens import SIZE
from tests.tui_fake_session import FakeSession
from tests.waiting import wait_for_app
from tui import cli
from tui.app import WalkcapApp
from tui.remembered import load_remembered, save_last_session
from tui.session_screen import SessionScreen, last_session_path

NOTE = "Anna Schmidt, transfemoral, came from Uniklinik ward 3"
SECRETS = ("Anna", "Schmidt", "Uniklinik", "Jane Doe")


def record(folder: Path, config: Config, info) -> Path:
    """A trial recorded with the form's values, as a session writes them."""
    trial = TrialFile(folder / f"{info.subject}_indoor_t01_20261122-101500.mcap", info, [], "")
    meta = trial_metadata(config, trial, {"camera_backend": "mock"}, {"model_hash": "abc"})
    toml = f'[session]\noperator = "{config.session.operator}"\n'.encode()
    rec = Recorder(trial.path, metadata=meta, attachments={"walkcap.toml": toml})
    rec.start()
    for k in range(10):
        rec.write_imu(imu_sample(k))
    rec.write_label(frame_time(0), "LG", "operator")
    for i in range(10):
        write_decision(rec, i)
    rec.write_event(
        {"time_ns": frame_time(3), "device": "operator", "kind": "marker", "message": NOTE}
    )
    rec.close()
    return trial.path


def readable(path: Path) -> str:
    rec = open_recording(path)
    parts = [bytes(m.data).decode() for _, _, m in iter_raw(rec.path, rec.complete, None)]
    parts += [repr(rec.metadata_records), repr(rec.raw_metadata_records)]
    parts += [bytes(v).decode(errors="replace") for v in rec.attachments.values()]
    return "\n".join(parts)


@pytest.mark.slow  # the form typed key by key, then share, export and info
async def test_a_name_typed_into_notes_reaches_no_shared_copy_and_no_export(tmp_path, capsys):
    config = Config()
    app = WalkcapApp(config, session=FakeSession())
    async with app.run_test(size=SIZE) as pilot:
        await wait_for_app(pilot, lambda: isinstance(app.screen, SessionScreen))
        form = app.screen
        form.query_one("#f-subject", Input).value = "S04"
        form.query_one("#f-operator", Input).value = "Jane Doe"
        form.query_one("#f-notes", Input).focus()
        await pilot.press(*NOTE)
        await wait_for_app(
            pilot, lambda: "a name" in str(form.query_one("#notes-warning").render())
        )
        await pilot.press("ctrl+s")
        await wait_for_app(pilot, lambda: not isinstance(app.screen, SessionScreen))
        info = app.subject
    assert info.notes == NOTE and config.session.operator == "Jane Doe"
    for f in last_session_path().parent.iterdir():  # notes are never remembered
        assert "Schmidt" not in f.read_text()
    lab = tmp_path / "lab"
    lab.mkdir()
    source = record(lab, config, info)
    assert all(s in readable(source) for s in SECRETS)  # the recording holds them
    out = tmp_path / "shared"
    assert cli.main(["share", str(lab), "-o", str(out), "--shift-days", "-30"]) == 0
    (copy,) = out.iterdir()
    assert copy.name == "S04_indoor_t01.mcap"
    text = readable(copy)
    for s in (*SECRETS, "20261122"):
        assert s not in text, s
    tables = tmp_path / "tables"
    assert cli.main(["export", str(out), "--format", "csv", "-o", str(tables), "--quiet"]) == 0
    for table in tables.iterdir():
        for s in SECRETS:
            assert s not in table.read_text(), (table.name, s)
    capsys.readouterr()
    assert cli.main(["info", str(copy)]) == 0
    shown = capsys.readouterr().out
    assert "shared      removed: " in shown and "notes dropped" in shown
    assert "operator dropped" in shown and "marker text" in shown


def test_share_without_a_secret_is_one_line(tmp_path, capsys):
    lab = tmp_path / "lab"
    lab.mkdir()
    from capture.live.trials import SubjectInfo

    record(lab, Config(), SubjectInfo(subject="S04", notes=NOTE))
    code = cli.main(["share", str(lab), "-o", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and "secret" in err[0]
    assert not (tmp_path / "out").exists()
    secret = tmp_path / "study.secret"
    secret.write_text("a long study secret\n")
    args = ["share", str(lab), "-o", str(tmp_path / "out"), "--secret-file", str(secret)]
    assert cli.main([*args, "--body", "coarsen"]) == 0
    assert open_recording(next((tmp_path / "out").iterdir())).metadata["session"]["notes"] == ""


def test_forget_leaves_no_trace_of_the_subject(capsys):
    from capture.live.trials import SubjectInfo

    save_last_session(SubjectInfo(subject="S07", height_m=1.82, age=41), operator="RA1")
    save_last_session(SubjectInfo(subject="S03", height_m=1.64))
    save_last_session(SubjectInfo(subject="S07", condition="outdoor", height_m=1.82))
    path = last_session_path()
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o600
    assert cli.main(["forget", "S07"]) == 0
    assert "forgot S07" in capsys.readouterr().out
    for f in path.parent.rglob("*"):
        if f.is_file():
            assert "S07" not in f.read_text() and "1.82" not in f.read_text(), f
    remembered = load_remembered()
    assert remembered.subjects["S03"]["height_m"] == 1.64 and remembered.operator == "RA1"
    assert cli.main(["forget", "S07"]) == 0
    assert "nothing remembered of S07" in capsys.readouterr().out


def test_body_data_are_remembered_for_the_configured_days_only(tmp_path):
    from capture.live.trials import SubjectInfo

    path = tmp_path / "last_session.json"
    save_last_session(SubjectInfo(subject="S07", height_m=1.82), path, days=90, today="2026-01-01")
    save_last_session(SubjectInfo(subject="S03", height_m=1.64), path, days=90, today="2026-03-25")
    later = load_remembered(path, days=90, today="2026-04-15")
    assert set(later.subjects) == {"S03"}  # S07: 104 days ago
    assert load_remembered(path, days=0, today="2026-03-25").subjects == {}
    save_last_session(SubjectInfo(subject="S03", height_m=1.64), path, days=0, today="2026-03-26")
    assert "1.64" not in path.read_text() and "S07" not in path.read_text()


async def test_a_marker_note_stays_out_of_the_log(caplog):
    from tests.tui.screens import open_live

    caplog.set_level(logging.INFO)
    app = WalkcapApp(Config(), session=FakeSession())
    async with app.run_test(size=SIZE) as pilot:
        await open_live(pilot)
        await pilot.press("m")
        await pilot.pause()
        await pilot.press(*"Anna fell", "enter")
        await wait_for_app(pilot, lambda: any("marker" in n.text for n in app.notices))
    assert any("Anna fell" in n.text for n in app.notices)  # the operator sees it
    assert "Anna" not in caplog.text and "marker (with a note)" in caplog.text


def test_the_ui_log_is_its_owners_only(tmp_path):
    from tui.logfile import logging_to_file

    path = tmp_path / "cache" / "tui.log"
    with logging_to_file(str(path)):
        logging.getLogger("walkcap.test").info("trial saved: S04")
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o600
