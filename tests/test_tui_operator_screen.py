"""The live screen as an operator on a laptop meets it: notices beside the panels, never over
them; the true strip as the labels stand; mode keys that label with a dialog open; plain
fault text; clear form states; a log of what happened; every size class keeps the
essentials in view."""

from test_tui_app import screen_text, wait_for
from tui_fake_session import FakeSession

from capture.config import Config
from tui.app import WalkcapApp
from tui.live_screen import LiveScreen


async def _live(pilot):
    app = pilot.app
    await wait_for(pilot, lambda: app.ready and isinstance(app.screen, LiveScreen), timeout=30)
    for _ in range(600):
        await pilot.pause(0.05)
        if app.screen.settled():
            break
    await pilot.pause()
    return app.screen


async def test_notices_never_cover_the_strips_or_the_decision():
    fake = FakeSession()
    app = WalkcapApp(Config(), session=fake, ask_subject=False)
    async with app.run_test(size=(100, 30)) as pilot:
        await _live(pilot)
        before = screen_text(app).splitlines()
        app.notify("saved S01_indoor_t01.mcap (12.3 MB)", timeout=10)
        app.notify("IMU unplugged; retrying /dev/ttyUSB0", severity="error", timeout=10)
        await wait_for(pilot, lambda: "IMU unplugged" in screen_text(app), timeout=30)
        await pilot.pause(0.1)
        after = screen_text(app).splitlines()
        notice_rows = [i for i, line in enumerate(after) if "IMU unplugged" in line]
        assert len(notice_rows) == 1  # one line, not a toast over the panels
        changed = [i for i, (a, b) in enumerate(zip(before, after)) if a != b]
        assert changed == notice_rows, "a notice drew over the live panels"
        assert [n.text for n in app.notices][-2:] == [
            "saved S01_indoor_t01.mcap (12.3 MB)",
            "IMU unplugged; retrying /dev/ttyUSB0",
        ]
