"""The operator's session on a fake source: pre-flight blocks recording until it passes,
retry in place, the REC banner, alarms, the trials of this session, the form's keys."""

from capture.config import Config
from capture.live.alarms import Alarm, AlarmState
from capture.live.preflight import CheckItem, PreflightReport
from capture.live.trials import SubjectInfo
from devices.errors import DeviceError
from tests.tui.screens import SIZE, open_live, rendered
from tests.tui_fake_session import FakeSession
from tests.waiting import wait_for_app
from tui.app import WalkcapApp
from tui.session_screen import SessionScreen, save_last_session


class Checks:
    """A pre-flight whose result the test decides; counts its runs."""

    def __init__(self, *results: bool) -> None:
        self.results = list(results)
        self.runs = 0

    def __call__(self, session) -> PreflightReport:
        ok = self.results[min(self.runs, len(self.results) - 1)]
        self.runs += 1
        reason = "" if ok else "holds 4 min, below 10 min"
        return PreflightReport([CheckItem("disk", ok, "1.0 GB free", reason)])


async def test_a_failed_preflight_blocks_recording_until_a_retry_passes():
    save_last_session(SubjectInfo(subject="S05", trial=1))
    fake, checks = FakeSession(), Checks(False, True)
    app = WalkcapApp(Config(), session=fake, preflight=checks)
    async with app.run_test(size=SIZE) as pilot:
        live = await open_live(pilot)
        await wait_for_app(pilot, lambda: app.preflight_state == "failed")
        banner = live.query_one("#banner")
        await wait_for_app(
            pilot, lambda: "PRE-FLIGHT FAILED: disk: holds 4 min" in rendered(banner)
        )
        await pilot.press("r")
        await pilot.pause(0.1)
        assert not fake.recordings_started  # blocked, with the reason
        await pilot.press("c")  # check again, in place
        await wait_for_app(pilot, lambda: app.preflight_state == "ok")
        assert checks.runs == 2
        await pilot.press("r")
        await wait_for_app(pilot, lambda: app.recording_path is not None)
        await wait_for_app(pilot, lambda: "● REC  trial 1" in rendered(banner))
        assert "S05_indoor_t01.mcap" in rendered(banner)
        await pilot.press("r")
        await wait_for_app(pilot, lambda: len(app.trials) == 1)
        trials = live.query_one("#trials")
        await wait_for_app(pilot, lambda: "S05_indoor_t01.mcap" in rendered(trials))
        assert "12.3 MB" in rendered(trials) and "trial 1" in rendered(trials)
    summary = app.trials_summary()
    assert summary[0] == "walkcap: 1 trial saved in this session"
    assert str(fake.recordings.resolve() / "S05_indoor_t01.mcap") in summary[1]


async def test_alarms_show_in_words_and_colour():
    fake = FakeSession()
    snapshot = fake.snapshot

    def with_alarms():
        snap = snapshot()
        snap.alarms = AlarmState(
            gaps={"camera": 0, "imu": 2}, alarms=[Alarm("error", "IMU: no data for 1.2 s")]
        )
        return snap

    fake.snapshot = with_alarms
    app = WalkcapApp(Config(), session=fake, ask_subject=False)
    async with app.run_test(size=SIZE) as pilot:
        await wait_for_app(pilot, lambda: app.ready)
        alarms = app.screen.query_one("#alarms")
        await wait_for_app(pilot, lambda: "ALARM IMU: no data for 1.2 s" in rendered(alarms))
        (span,) = [s for s in alarms.render().spans if "on" in str(s.style)]
        assert "on rgb(176,32,32)" in str(span.style)  # red background: seen without reading


async def test_device_failure_retries_in_place_and_keeps_the_form():
    save_last_session(SubjectInfo(subject="P07", trial=3))
    attempts = []

    def factory(config):
        attempts.append(1)
        if len(attempts) == 1:
            return FakeSession(start_error=DeviceError("IMU not found on /dev/ttyUSB0"))
        return FakeSession()

    app = WalkcapApp(Config(), session_factory=factory, preflight=Checks(True))
    async with app.run_test(size=SIZE) as pilot:
        await wait_for_app(pilot, lambda: app.start_error is not None)
        assert "c retries" in app.status and "ctrl+q quits" in app.status
        await pilot.press("q")  # a field takes the q: it never quits nor replaces the text
        form = app.screen
        assert isinstance(form, SessionScreen)
        assert form.values()["subject"] == "P07q"
        await pilot.press("backspace", "ctrl+r")
        await wait_for_app(pilot, lambda: app.ready)
        assert len(attempts) == 2 and app.start_error is None
        assert form.values()["subject"] == "P07"


async def test_the_form_has_an_operator_field_written_to_the_config():
    config = Config()
    config.session.operator = "RA1"
    app = WalkcapApp(config, session=FakeSession())
    async with app.run_test(size=SIZE) as pilot:
        await wait_for_app(pilot, lambda: isinstance(app.screen, SessionScreen))
        field = app.screen.query_one("#f-operator")
        assert field.value == "RA1"
        field.value = "RA2"
        await pilot.press("ctrl+s")
        await wait_for_app(pilot, lambda: not isinstance(app.screen, SessionScreen))
    assert config.session.operator == "RA2"
