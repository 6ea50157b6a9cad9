"""Remembered values belong to a subject: another subject id never inherits the last one's
body data; the trial is the next free one for that subject and condition; the operator is
remembered across restarts."""

import dataclasses
import json

from capture.config import Config
from capture.live.trials import SubjectInfo
from capture.recording.reader import open_recording
from tests.tui.screens import FILLED_SUBJECT, SIZE
from tests.tui_fake_session import FakeSession
from tests.waiting import wait_for_app
from tui import cli
from tui.app import WalkcapApp
from tui.cli import build_parser
from tui.commands import apply_device_flags
from tui.commands.record import remembered_operator
from tui.commands.tui import starting_form
from tui.session_screen import SessionScreen, last_session_path, save_last_session

S07 = dataclasses.replace(
    FILLED_SUBJECT,
    subject="S07",
    condition="outdoor",
    trial=6,
    height_m=1.82,
    notes="socket refitted",
)


def tui_form(*flags):
    args = build_parser().parse_args(["tui", *flags])
    config = Config()
    apply_device_flags(args, config)
    return starting_form(args, config), config


def touch(folder, *names):
    folder.mkdir(parents=True, exist_ok=True)
    for name in names:
        (folder / name).write_bytes(b"")


def test_a_new_subject_starts_with_empty_subject_fields_and_its_own_trial(tmp_path):
    save_last_session(S07, operator="RA1")
    touch(tmp_path / "recordings", *(f"S07_outdoor_t{n:02d}_20261201-1000.mcap" for n in (1, 5)))
    form, _ = tui_form("--subject", "S03", "--condition", "outdoor")
    assert form.subject == "S03" and form.condition == "outdoor"
    assert form.trial == 1  # S03 has no outdoor trial in the folder
    assert (form.height_m, form.weight_kg, form.age, form.residual_limb_cm) == (None,) * 4
    assert (form.sex, form.amputee, form.side, form.notes) == ("", False, "", "")


def test_a_subject_seen_before_gets_its_own_last_values(tmp_path):
    save_last_session(S07)
    s03 = SubjectInfo(subject="S03", condition="indoor", trial=2, height_m=1.64, age=30)
    save_last_session(s03)
    form, _ = tui_form("--subject", "S07")
    assert (form.height_m, form.side) == (1.82, "left")
    assert form.notes == ""  # notes belong to one trial: never remembered
    assert form.condition == "indoor"  # the session's condition stays; the subject's data follow
    form, _ = tui_form("--subject", "S03")
    assert (form.height_m, form.age, form.side) == (1.64, 30, "")


def test_the_trial_is_the_next_free_one_in_the_recordings_folder(tmp_path):
    save_last_session(S07)
    names = [f"S07_outdoor_t{n:02d}_20261201-1000.mcap" for n in (1, 2, 3, 6, 7)]
    touch(tmp_path / "recordings", *names, "S03_outdoor_t01_20261201-1000.mcap")
    form, _ = tui_form()  # the same subject and condition: on from the remembered trial
    assert (form.subject, form.trial) == ("S07", 8)
    form, _ = tui_form("--subject", "S03", "--condition", "outdoor")
    assert form.trial == 2
    touch(tmp_path / "other", "S03_outdoor_t01_x.mcap", "S03_outdoor_t02_x.mcap")
    form, _ = tui_form("--subject", "S03", "--condition", "outdoor", "--out", "other")
    assert form.trial == 3
    form, _ = tui_form("--subject", "S03", "--trial", "9")
    assert form.trial == 9  # a trial given is taken as given


def test_the_operator_is_remembered_unless_a_flag_names_one():
    save_last_session(S07, operator="RA1")
    _, config = tui_form()
    assert config.session.operator == "RA1"
    _, config = tui_form("--operator", "RA2")
    assert config.session.operator == "RA2"


async def test_the_form_confirms_and_remembers_the_operator_across_a_restart():
    save_last_session(S07)
    app = WalkcapApp(Config(), session=FakeSession())
    async with app.run_test(size=SIZE) as pilot:
        await wait_for_app(pilot, lambda: isinstance(app.screen, SessionScreen))
        app.screen.query_one("#f-operator").value = "RA1"
        await pilot.press("ctrl+s")
        await wait_for_app(pilot, lambda: not isinstance(app.screen, SessionScreen))
    assert json.loads(last_session_path().read_text())["operator"] == "RA1"
    config = Config()  # a restart: the form and every recording name the operator again
    app = WalkcapApp(config, session=FakeSession())
    async with app.run_test(size=SIZE) as pilot:
        await wait_for_app(pilot, lambda: isinstance(app.screen, SessionScreen))
        assert app.screen.query_one("#f-operator").value == "RA1"
        await pilot.press("ctrl+s")
        await wait_for_app(pilot, lambda: not isinstance(app.screen, SessionScreen))
    assert config.session.operator == "RA1"


async def test_typing_another_subject_in_the_form_swaps_the_subject_fields(tmp_path):
    save_last_session(SubjectInfo(subject="S03", condition="outdoor", height_m=1.64))
    save_last_session(S07)
    touch(tmp_path / "recordings", "S03_outdoor_t01_x.mcap")
    app = WalkcapApp(Config(), session=FakeSession())
    async with app.run_test(size=SIZE) as pilot:
        await wait_for_app(pilot, lambda: isinstance(app.screen, SessionScreen))
        form = app.screen
        assert form.values()["height_m"] == "1.82" and form.values()["trial"] == "6"
        form.query_one("#f-weight_kg").value = "79"  # the operator's own edit stays
        form.query_one("#f-subject").value = "S99"
        await pilot.pause()
        values = form.values()
        assert values["height_m"] == "" and values["notes"] == "" and values["side"] == ""
        assert values["amputee"] is False and values["trial"] == "1"
        assert values["weight_kg"] == "79"
        form.query_one("#f-subject").value = "S03"
        await pilot.pause()
        values = form.values()
        assert values["height_m"] == "1.64" and values["trial"] == "2"
        await pilot.press("ctrl+s")
        await wait_for_app(pilot, lambda: not isinstance(app.screen, SessionScreen))
    assert app.subject.subject == "S03" and app.subject.height_m == 1.64
    assert app.subject.side == "" and app.subject.trial == 2


def test_record_takes_the_remembered_operator_unless_one_is_given(tmp_path, capsys):
    save_last_session(SubjectInfo(subject="S07"), operator="RA7")
    out = tmp_path / "rec"
    code = cli.main(["record", "--fast", "--duration", "0.5", "--out", str(out), "--trial", "1"])
    assert code == 0, capsys.readouterr().err
    assert "operator RA7" in capsys.readouterr().err
    (path,) = out.glob("*.mcap")
    assert open_recording(path).metadata["session"]["operator"] == "RA7"
    args = build_parser().parse_args(["record", "--operator", "RA2"])
    config = Config()
    apply_device_flags(args, config)
    assert remembered_operator(args, config) == "RA2"  # the flag over what is remembered
