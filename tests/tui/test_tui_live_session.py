"""One run of the UI on the real Session with mock devices (camera simulator, IMU emulator
on a pty): devices start in the background, labels and a trial reach the MCAP file.
A stand-in classifier keeps it fast (the CNN has its own tests)."""

import pytest

from capture.config import Config
from capture.corpus.trials import read_trial
from capture.recording.gaps import recording_loss
from capture.recording.reader import open_recording
from tests.tui.screens import drill_app
from tests.waiting import wait_for_app
from tui.live_screen import LiveScreen

pytestmark = pytest.mark.timeout(30)


@pytest.mark.realtime
@pytest.mark.slow
async def test_real_session_on_mock_devices(tmp_path, busy_pilot):
    config = Config()
    config.session.recordings = str(tmp_path / "recordings")
    sessions = []
    app = drill_app(config, sessions)
    async with app.run_test(size=(120, 40)) as pilot:
        await wait_for_app(pilot, lambda: app.ready, 15)
        session = sessions[0]
        await wait_for_app(pilot, lambda: session.snapshot().frames >= 5, 5)
        # the pre-flight check (a probe trial, deleted) passes before a trial can record
        await wait_for_app(pilot, lambda: app.preflight_state == "ok", 15)
        assert not list((tmp_path / "recordings").iterdir())
        await pilot.press("2")
        assert session.label == "US"
        await pilot.press("r")
        await wait_for_app(pilot, lambda: app.recording_path is not None, 5)
        await pilot.pause(1.2)
        await pilot.press("4")
        await pilot.pause(0.3)
        live = app.screen
        assert isinstance(live, LiveScreen) and live.refreshes > 10
        assert "● REC" in str(live.query_one("#banner").render())
        await pilot.press("ctrl+u")  # drill: the IMU unplugged for 2 s, in the middle of a trial
        alarms = live.query_one("#alarms")
        await wait_for_app(pilot, lambda: "ALARM IMU: no data" in str(alarms.render()), 2)
        await wait_for_app(pilot, lambda: session.alarms.counters["imu"].longest_s > 1.5, 6)
        await pilot.pause(0.5)
        await pilot.press("r")
        await wait_for_app(pilot, lambda: app.recording_path is None and not session.recording, 5)
        await pilot.press("q")
        await wait_for_app(pilot, lambda: not app.is_running, 5)
    files = list((tmp_path / "recordings").glob("S09_indoor_t01_*.mcap"))
    assert len(files) == 1
    trial = read_trial(files[0])
    assert len(trial.frames.index) >= 10
    assert [c[1] for c in trial.label_changes] == ["US", "UR"]
    assert trial.meta.session.subject == "S09"
    assert app.subject.trial == 2
    # the gaps the screen counted are the ones `walkcap info` finds in the file
    loss = recording_loss(open_recording(files[0]))
    assert loss["/imu"].longest_s > 1.5  # the unplug: samples the IMU counted, lost
    (record,) = app.trials
    assert record.gaps["imu"] == len(loss["/imu"].gaps)
    assert record.gaps["camera"] == len(loss["/camera/depth"].gaps)
    assert str(files[0].resolve()) in app.trials_summary()[1]
