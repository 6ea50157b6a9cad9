"""The live screen as an operator on a laptop meets it: notices beside the panels, never over
them; the true strip as the labels stand; mode keys that label with a dialog open; plain
fault text; clear form states; a log of what happened; every size class keeps the
essentials in view."""

from test_tui_app import screen_text, wait_for
from tui_fake_session import NOW_NS, FakeSession

from capture.config import Config
from capture.session import LabelChange, TimelineEntry
from tui.app import WalkcapApp
from tui.live_screen import LiveScreen
from tui.session_screen import SessionScreen
from tui.widgets.help_screen import HelpScreen
from tui.widgets.marker_dialog import MarkerDialog
from tui.widgets.quit_dialog import QuitDialog


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


class LabelledFrames(FakeSession):
    """Frames carry the label in force when they are taken, as the session's do; its clock
    moves on one frame (1/15 s) with each snapshot, so nothing depends on the wall clock."""

    def __init__(self) -> None:
        super().__init__()
        self.clock = NOW_NS
        self.timeline = []
        self.set_label("US")  # keyed before the screen opened

    def set_label(self, mode, source="operator", time_ns=None):
        return super().set_label(mode, source, self.clock if time_ns is None else time_ns)

    def undo_label(self):
        change = super().undo_label()
        return None if change is None else LabelChange(self.clock, change.mode, change.source)

    def snapshot(self):
        self.clock += int(1e9 / 15)
        self.timeline.append(
            TimelineEntry(len(self.timeline), self.clock, self._label, 1, 1, None, None)
        )
        del self.timeline[:-300]
        snap = super().snapshot()
        snap.time_ns = self.clock
        return snap


def _row(app, name: str) -> str:
    return next(line for line in screen_text(app).splitlines() if f"│ {name} " in line)


async def test_the_true_strip_shows_the_labels_as_they_stand_after_an_undo():
    fake = LabelledFrames()
    app = WalkcapApp(Config(), session=fake, ask_subject=False)
    async with app.run_test(size=(120, 40)) as pilot:
        await _live(pilot)
        frames = len(fake.timeline)
        await wait_for(pilot, lambda: len(fake.timeline) > frames + 20, timeout=30)
        await pilot.press("3")
        frames = len(fake.timeline)
        await wait_for(pilot, lambda: len(fake.timeline) > frames + 40, timeout=30)
        await wait_for(pilot, lambda: "DS" in _row(app, "true"), timeout=30)
        await pilot.press("u")
        assert fake.label == "US"
        frames = len(fake.timeline)
        await wait_for(pilot, lambda: len(fake.timeline) > frames + 20, timeout=30)
        await pilot.pause(0.1)
        true = _row(app, "true")
        assert "US" in true and "DS" not in true  # as in the file, export and replay
        await pilot.press("3")  # a new change shows again from its own time
        frames = len(fake.timeline)
        await wait_for(pilot, lambda: len(fake.timeline) > frames + 20, timeout=30)
        await wait_for(pilot, lambda: "DS" in _row(app, "true"), timeout=30)


async def test_mode_keys_label_while_a_dialog_is_open_during_a_trial():
    fake = FakeSession()
    app = WalkcapApp(Config(), session=fake, ask_subject=False)
    async with app.run_test(size=(120, 40)) as pilot:
        await _live(pilot)
        await pilot.press("r")
        await wait_for(pilot, lambda: fake.recording, timeout=30)
        await pilot.press("question_mark")
        assert isinstance(app.screen, HelpScreen)
        await pilot.press("3")
        assert [c.mode for c in fake.labels] == ["DS"] and isinstance(app.screen, HelpScreen)
        await pilot.press("escape", "m")
        assert isinstance(app.screen, MarkerDialog)
        assert "still label the trial" in screen_text(app)  # it says so plainly
        await pilot.press(*"step", "4", *"ok", "enter")
        assert [c.mode for c in fake.labels] == ["DS", "UR"]
        assert [note for _, note in fake.markers] == ["stepok"]  # the key labelled, not typed
        await pilot.press("q")
        assert isinstance(app.screen, QuitDialog)
        await pilot.press("5", "n")
        assert [c.mode for c in fake.labels] == ["DS", "UR", "DR"] and fake.recording
        await pilot.press("r")
        await wait_for(pilot, lambda: not fake.recording, timeout=30)
        await pilot.press("s")  # the form's fields still take digits
        assert isinstance(app.screen, SessionScreen)
        app.screen.query_one("#f-trial").value = ""
        app.screen.query_one("#f-trial").focus()
        await pilot.press("1", "2")
        assert app.screen.query_one("#f-trial").value == "12" and len(fake.labels) == 3
