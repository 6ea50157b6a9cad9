"""Screenshots of the layouts (SVG under tests/tui/__snapshots__/), from a fake session whose
snapshot never changes: no clock, no randomness in what is drawn.
Update after an intended change: pytest tests/tui/test_tui_snapshots.py --snapshot-update"""

from textual.widgets import Input

from capture.config import Config
from capture.live.trials import SubjectInfo
from tests.tui.screens import FILLED_SUBJECT
from tests.tui_fake_session import FakeSession
from tui.app import WalkcapApp
from tui.live_screen import LiveScreen
from tui.session_screen import save_last_session


async def _until_live(pilot) -> None:
    app = pilot.app
    # Generous bounds: a loaded CI machine may take seconds to start and redraw.
    for _ in range(1500):
        if app.ready and isinstance(app.screen, LiveScreen):
            break
        await pilot.pause(0.02)
    for _ in range(600):
        await pilot.pause(0.05)
        if app.screen.settled():
            break
    await pilot.pause()


async def _no_blink(pilot) -> None:
    for widget in pilot.app.screen.query(Input):
        widget.cursor_blink = False
    await pilot.pause()


def _recording_app() -> WalkcapApp:
    """The app of a session that records trial 4 of S03."""
    fake = FakeSession()
    fake.start_recording(SubjectInfo(subject="S03", trial=4))
    return WalkcapApp(
        Config(), session=fake, subject=SubjectInfo(subject="S03", trial=4), ask_subject=False
    )


def _help_matches(snap_compare, size) -> bool:
    app = WalkcapApp(Config(), session=FakeSession(), ask_subject=False)
    return snap_compare(app, terminal_size=size, run_before=_until_live, press=["question_mark"])


def test_session_form(snap_compare):
    save_last_session(FILLED_SUBJECT)
    app = WalkcapApp(Config(), session=FakeSession())
    assert snap_compare(app, terminal_size=(120, 40), run_before=_no_blink)


def test_live_screen(snap_compare):
    app = WalkcapApp(Config(), session=FakeSession(), ask_subject=False)
    assert snap_compare(app, terminal_size=(120, 40), run_before=_until_live)


def test_live_screen_small_terminal(snap_compare):
    app = WalkcapApp(Config(), session=FakeSession(), ask_subject=False)
    assert snap_compare(app, terminal_size=(100, 30), run_before=_until_live)


def test_live_screen_recording_wide_terminal(snap_compare):
    app = _recording_app()
    assert snap_compare(app, terminal_size=(160, 45), run_before=_until_live)


def test_help_screen(snap_compare):
    assert _help_matches(snap_compare, (120, 40))


def test_live_screen_recording_80x24(snap_compare):
    app = _recording_app()
    assert snap_compare(app, terminal_size=(80, 24), run_before=_until_live)


def test_help_screen_80x24(snap_compare):
    assert _help_matches(snap_compare, (80, 24))
