"""A laptop's terminal: at 80 x 24 and 100 x 30 the recording's state stays on screen and
the whole help can be read."""

import io

import pytest
from rich.console import Console
from textual.containers import VerticalScroll

from capture.config import Config
from capture.live.trials import SubjectInfo
from tests.tui_fake_session import FakeSession
from tui.app import WalkcapApp
from tui.live_screen import LiveScreen
from tui.widgets.help_screen import HelpScreen
from tui.widgets.recording_panel import RecordingPanel


async def _live(pilot):
    app = pilot.app
    for _ in range(1500):  # a bound, not a measure
        if app.ready and isinstance(app.screen, LiveScreen):
            break
        await pilot.pause(0.02)
    await pilot.pause()


@pytest.mark.parametrize("size", [(80, 24), (100, 30), (120, 40)])
async def test_the_recording_panel_shows_at_every_size(size):
    fake = FakeSession()
    fake.start_recording(SubjectInfo(subject="S03", trial=4))
    app = WalkcapApp(Config(), session=fake, ask_subject=False)
    async with app.run_test(size=size) as pilot:
        await _live(pilot)
        panel = app.screen.query_one(RecordingPanel)
        assert panel.display and panel.region.height >= 1
        assert panel.region.bottom <= app.screen.query_one("#main").region.bottom
        console = Console(width=panel.content_size.width, record=True, file=io.StringIO())
        console.print(panel.render())
        shown = console.export_text()
        assert shown.count("\n") <= panel.content_size.height  # it fits the panel
        assert "● REC" in shown and "0:0" in shown
        if size[1] >= 28:  # three lines or more: the writer's state too
            assert "queue" in shown and "dropped" in shown


async def test_the_help_scrolls_to_its_end_at_80x24():
    app = WalkcapApp(Config(), session=FakeSession(), ask_subject=False)
    async with app.run_test(size=(80, 24)) as pilot:
        await _live(pilot)
        await pilot.press("question_mark")
        await pilot.pause()
        assert isinstance(app.screen, HelpScreen)
        box = app.screen.query_one(VerticalScroll)
        assert box.region.bottom <= 24 and box.max_scroll_y > 0  # cut: it scrolls
        keys = app.screen.query_one("#help-keys")
        assert keys.region.bottom <= box.region.bottom  # every key in view at once
        assert "escape closes" in box.border_subtitle
        for _ in range(box.max_scroll_y):
            await pilot.press("down")
        await pilot.pause()
        assert box.scroll_y == box.max_scroll_y  # the last line can be read
        await pilot.press("escape")
        assert isinstance(app.screen, LiveScreen)
