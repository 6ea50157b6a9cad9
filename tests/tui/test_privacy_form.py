"""Subject ids are pseudonyms of the study's pattern, and the form warns of personal notes."""

from __future__ import annotations

import pytest
from textual.widgets import Input

from capture.config import Config
from capture.errors import CaptureError
from capture.live.trials import SUBJECT_PATTERN, SubjectInfo, check_pseudonym
from capture.recording.personal import note_warnings
from tests.tui.screens import SIZE, rendered
from tests.tui_fake_session import FakeSession
from tests.waiting import wait_for_app
from tui import cli
from tui.app import WalkcapApp
from tui.session_screen import SessionScreen


@pytest.mark.parametrize("subject", ["S01", "S03", "P07", "A03", "OP1", "AB12"])
def test_the_default_pattern_keeps_the_codes_in_use(subject):
    check_pseudonym(subject)


@pytest.mark.parametrize("subject", ["Anna_Schmidt", "anna", "Schmidt", "s01", "S01_x", ""])
def test_the_default_pattern_refuses_names(subject):
    with pytest.raises(CaptureError, match=r"\[session\] subject_pattern") as e:
        check_pseudonym(subject)
    assert SUBJECT_PATTERN in str(e.value)


def test_a_configured_pattern_is_the_one_checked():
    SubjectInfo(subject="2026-007").validate(r"\d{4}-\d{3}")
    with pytest.raises(CaptureError, match=r"\\d\{4\}"):
        SubjectInfo(subject="S01").validate(r"\d{4}-\d{3}")


def test_record_refuses_a_name_as_subject_in_one_line(capsys, tmp_path):
    code = cli.main(["record", "--subject", "Anna_Schmidt", "--out", str(tmp_path)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1
    assert "'Anna_Schmidt'" in err[0] and SUBJECT_PATTERN in err[0]
    assert not list(tmp_path.iterdir())


def test_the_configured_pattern_reaches_record(capsys, tmp_path):
    toml = tmp_path / "walkcap.toml"
    toml.write_text('[session]\nsubject_pattern = "^X[0-9]{3}$"\n')
    code = cli.main(["--config", str(toml), "record", "--subject", "S01", "--out", str(tmp_path)])
    assert code != 0 and "^X[0-9]{3}$" in capsys.readouterr().err


def test_a_pattern_that_is_no_regular_expression_is_a_config_error(capsys, tmp_path):
    toml = tmp_path / "walkcap.toml"
    toml.write_text('[session]\nsubject_pattern = "[A-Z"\n')
    code = cli.main(["--config", str(toml), "config"])
    assert code != 0 and "subject_pattern" in capsys.readouterr().err


def test_note_warnings_catch_names_dates_of_birth_and_places():
    note = "Anna Schmidt, transfemoral, born 12.03.1975, came from Uniklinik ward 3"
    assert note_warnings(note) == ["a name", "a date of birth", "a place"]
    assert note_warnings("Dr Meier fitted the socket") == ["a name"]
    assert note_warnings("lives in Hamburg") == ["a place"]
    for fine in ("socket checked", "new shoes, wet floor", "stumbled at the stairs", "in LG"):
        assert note_warnings(fine) == [], fine


async def test_the_form_refuses_a_name_and_warns_of_a_personal_note():
    app = WalkcapApp(Config(), session=FakeSession())
    async with app.run_test(size=SIZE) as pilot:
        await wait_for_app(pilot, lambda: isinstance(app.screen, SessionScreen))
        form = app.screen
        assert "never names" in rendered(form.query_one("#notes-help"))
        form.query_one("#f-notes", Input).focus()
        await pilot.press(*"Anna Schmidt from Uniklinik")
        warning = form.query_one("#notes-warning")
        await wait_for_app(pilot, lambda: "a name" in rendered(warning))
        assert "a place" in rendered(warning)
        subject = form.query_one("#f-subject", Input)
        subject.value = "Anna_Schmidt"
        await pilot.pause()
        await pilot.press("ctrl+s")
        error = form.query_one("#form-error")
        await wait_for_app(pilot, lambda: "subject_pattern" in rendered(error))
        assert isinstance(app.screen, SessionScreen)  # not started
