"""The terminal UI driven by Textual's Pilot, on a fake session: every key, every screen."""

import json
import threading
from pathlib import Path

from capture.config import Config
from capture.live.trials import SubjectInfo
from devices.base import DeviceEvent
from devices.clock import now_ns
from tests.tui.screens import SIZE, live_app, open_live, rendered, screen_text
from tests.tui_fake_session import FakeSession
from tests.waiting import wait_for_app
from tui.app import WalkcapApp
from tui.live_screen import REFRESH_HZ, LiveScreen
from tui.session_screen import SessionScreen, last_session_path, save_last_session
from tui.widgets.device_panel import DevicePanel
from tui.widgets.help_screen import HelpScreen
from tui.widgets.marker_dialog import MarkerDialog
from tui.widgets.quit_dialog import QuitDialog


async def test_form_remembers_validates_and_leads_to_the_live_screen():
    save_last_session(
        SubjectInfo(subject="A03", condition="outdoor", trial=5, amputee=True, side="right")
    )
    fake = FakeSession()
    app = WalkcapApp(Config(), session=fake)
    async with app.run_test(size=SIZE) as pilot:
        await wait_for_app(pilot, lambda: isinstance(app.screen, SessionScreen))
        form = app.screen
        values = form.values()
        assert values["subject"] == "A03" and values["trial"] == "5" and values["side"] == "right"
        form.query_one("#f-height_m").value = "7"  # metres: out of range
        await pilot.press("enter")
        assert isinstance(app.screen, SessionScreen)
        assert "height" in str(form.query_one("#form-error").render())
        form.query_one("#f-height_m").value = "1.7"
        await pilot.press("enter")
        await wait_for_app(pilot, lambda: isinstance(app.screen, LiveScreen))
        assert app.subject.height_m == 1.7 and app.subject.subject == "A03"
    assert json.loads(last_session_path().read_text())["subjects"]["A03"]["height_m"] == 1.7


async def test_starting_devices_is_shown_and_a_start_error_is_a_message_not_a_crash():
    from devices.errors import DeviceNotAvailable

    gate = threading.Event()
    fake = FakeSession(
        start_error=DeviceNotAvailable("royale SDK not found: install it (see README)"),
        start_gate=gate,
    )
    app = WalkcapApp(Config(), session=fake, ask_subject=False)
    async with app.run_test(size=SIZE) as pilot:
        await pilot.pause()
        assert "starting devices" in app.status
        assert "starting devices" in screen_text(app)
        gate.set()
        await wait_for_app(pilot, lambda: app.start_error is not None)
        assert "royale SDK not found" in app.status and app.status_is_error
        await pilot.pause()
        assert "royale SDK not found" in screen_text(app)
        await pilot.press("1")  # no session: a warning, no exception
        assert fake.labels == []
        await pilot.press("q")
    assert app.return_code == 1


async def test_the_factory_builds_the_session_in_a_worker():
    built = []

    def factory(config):
        built.append(config)
        return FakeSession()

    config = Config()
    app = WalkcapApp(config, session_factory=factory, ask_subject=False)
    async with app.run_test(size=SIZE) as pilot:
        await wait_for_app(pilot, lambda: app.ready)
        assert built == [config] and app.session.started.is_set()


async def test_label_keys_stamp_the_mode_at_once_and_undo_takes_it_back():
    async with live_app() as (app, fake, pilot, live):
        for key, mode in zip("12345", ("LG", "US", "DS", "UR", "DR")):
            pressed = now_ns()
            await pilot.press(key)
            assert fake.labels[-1].mode == mode
            assert fake.labels[-1].time_ns - pressed < 50_000_000  # within 50 ms of the press
        assert "true DR" in screen_text(app)
        await pilot.press("u")
        assert fake.undos == 1 and fake.label == "UR"
        assert [c.mode for c in fake.labels] == ["LG", "US", "DS", "UR"]


async def test_keys_come_from_the_configuration():
    config = Config()
    config.keys.mode_lg, config.keys.undo = "a", "z"
    async with live_app(config) as (app, fake, pilot, live):
        await pilot.press("1")
        assert fake.labels == []
        await pilot.press("a")
        assert [c.mode for c in fake.labels] == ["LG"]
        await pilot.press("z")
        assert fake.undos == 1
        help_keys = dict(app.screen.key_help())
        assert "true mode LG" in help_keys["a"] and "undo" in help_keys["z"]


async def test_marker_with_a_note_and_cancelled():
    async with live_app() as (app, fake, pilot, live):
        pressed = now_ns()
        await pilot.press("m")
        assert isinstance(app.screen, MarkerDialog)
        await pilot.pause(0.2)  # the operator types slowly
        typed = now_ns()
        await pilot.press(*"tripped", "enter")
        assert [note for _, note in fake.markers] == ["tripped"]
        assert pressed <= fake.markers[0][0] < typed  # stamped at the key press
        assert isinstance(app.screen, LiveScreen)
        await pilot.press("m", "escape")
        assert len(fake.markers) == 1
        await pilot.press("m", "enter")  # a marker without a note
        assert [note for _, note in fake.markers] == ["tripped", ""]


async def test_record_key_starts_and_stops_a_trial_and_the_trial_advances():
    save_last_session(SubjectInfo(subject="S02", trial=1))
    async with live_app() as (app, fake, pilot, live):
        await pilot.press("r")
        await wait_for_app(pilot, lambda: app.recording_path is not None)
        assert fake.recording and fake.recordings_started[0].subject == "S02"
        assert fake.recordings_started[0].trial == 1
        await wait_for_app(pilot, lambda: "REC" in rendered(live.query_one("#recording")))
        assert "S02_indoor_t01.mcap" in rendered(live.query_one("#banner"))
        await pilot.press("s")  # no form while recording
        assert isinstance(app.screen, LiveScreen)
        await pilot.press("r")
        await wait_for_app(pilot, lambda: not fake.recording and app.subject.trial == 2)
        assert fake.recordings_stopped == 1
        assert json.loads(last_session_path().read_text())["trial"] == 2
        await pilot.press("r")
        await wait_for_app(pilot, lambda: fake.recording)
        assert fake.recordings_started[1].trial == 2


async def test_a_remote_root_is_the_remote_trials_folder_only():
    from capture.labtools.remote import TrialRequest

    save_last_session(SubjectInfo(subject="S02", trial=1))
    fake = FakeSession()
    config = Config()
    operators = config.session.recordings
    app = WalkcapApp(config, session=fake)
    async with app.run_test(size=SIZE) as pilot:
        await open_live(pilot)
        app.remote_start(TrialRequest(root="/data/study", subject="P07"))
        await wait_for_app(pilot, lambda: app.recording_path is not None)
        assert app.recording_path.parent == Path("/data/study")
        assert config.session.recordings == operators  # the operator's folder stays
        app.remote_stop()
        await wait_for_app(pilot, lambda: not fake.recording and app.recording_path is None)
        await pilot.press("r")  # the operator's own next trial
        await wait_for_app(pilot, lambda: fake.recording)
        assert app.recording_path.parent == fake.recordings


async def test_session_form_from_the_live_screen():
    async with live_app() as (app, fake, pilot, live):
        await pilot.press("s")
        assert isinstance(app.screen, SessionScreen)
        app.screen.query_one("#f-trial").value = "9"
        await pilot.press("escape")  # back without changes
        assert isinstance(app.screen, LiveScreen) and app.subject.trial == 1
        await pilot.press("s")
        app.screen.query_one("#f-trial").value = "9"
        await pilot.press("ctrl+s")
        await wait_for_app(pilot, lambda: isinstance(app.screen, LiveScreen))
        assert app.subject.trial == 9


async def test_freeze_stops_the_refresh_but_not_the_labels():
    async with live_app() as (app, fake, pilot, live):
        await pilot.press("space")
        await pilot.pause()
        assert live.frozen and "FROZEN" in screen_text(app)
        before = live.refreshes
        await pilot.pause(0.3)
        assert live.refreshes == before
        await pilot.press("3")
        assert fake.labels[-1].mode == "DS" and live.refreshes == before
        await pilot.press("space")
        await pilot.pause(0.2)
        assert not live.frozen and live.refreshes > before


async def test_the_view_pulls_one_snapshot_per_tick_of_a_20_hz_timer(monkeypatch):
    timers = []
    set_interval = LiveScreen.set_interval

    def held(screen, interval, callback=None, **kw):
        if callback == screen.refresh_view:  # Textual's own timers run as they are
            timers.append(interval)
            kw["pause"] = True  # ticked by the test
        return set_interval(screen, interval, callback, **kw)

    monkeypatch.setattr(LiveScreen, "set_interval", held)
    fake = FakeSession()
    app = WalkcapApp(Config(), session=fake, ask_subject=False)
    async with app.run_test(size=SIZE) as pilot:
        await wait_for_app(pilot, lambda: app.ready and isinstance(app.screen, LiveScreen))
        live = app.screen
        assert REFRESH_HZ == 20 and timers == [1 / REFRESH_HZ]
        start = fake.snapshots
        await pilot.pause(0.2)
        assert fake.snapshots == start  # the timer held: nothing else pulls snapshots
        for _ in range(3):
            live.refresh_view()  # a tick
        assert fake.snapshots == start + 3


async def test_help_lists_the_keys():
    async with live_app() as (app, fake, pilot, live):
        await pilot.press("question_mark")
        assert isinstance(app.screen, HelpScreen)
        await pilot.pause()
        text = screen_text(app)
        for expected in ("true mode LG", "undo", "marker", "record", "freeze", "quit"):
            assert expected in text
        assert "replay" not in text  # replay keys only show for a replay
        await pilot.press("escape")
        assert isinstance(app.screen, LiveScreen)


async def test_quit_when_not_recording_stops_the_session():
    async with live_app() as (app, fake, pilot, live):
        await pilot.press("q")
        await wait_for_app(pilot, lambda: fake.stopped == 1)
    assert app.return_code == 0


async def test_quit_while_recording_asks_and_a_yes_finalises_the_file():
    async with live_app() as (app, fake, pilot, live):
        await pilot.press("r")
        await wait_for_app(pilot, lambda: fake.recording)
        await pilot.press("q")
        assert isinstance(app.screen, QuitDialog)
        await pilot.press("n")
        assert isinstance(app.screen, LiveScreen) and fake.recording and fake.stopped == 0
        await pilot.press("q")
        await pilot.press("y")
        await wait_for_app(pilot, lambda: fake.stopped == 1)
        await pilot.pause(0.1)
    assert fake.recordings_stopped == 1 and not fake.recording
    assert app.return_code == 0


async def test_a_device_fault_shows_at_once_and_the_rest_goes_on():
    async with live_app() as (app, fake, pilot, live):
        await pilot.press("r")
        await wait_for_app(pilot, lambda: fake.recording)
        fake.imu.state, fake.imu.message = "lost", "no data for 0.5 s (unplugged?)"
        fake.events.append(DeviceEvent(now_ns(), "imu", "lost", "no data for 0.5 s (unplugged?)"))
        await pilot.pause(0.2)  # a few refresh periods
        panel = rendered(live.query_one(DevicePanel))
        assert "lost" in panel and "unplugged" in panel
        assert any("IMU lost" in n.text for n in app.notices)
        assert fake.recording  # the other streams keep recording
        await pilot.press("2")
        assert fake.labels[-1].mode == "US"
