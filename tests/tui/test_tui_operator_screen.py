"""The live screen as an operator on a laptop meets it: notices beside the panels, never over
them; the true strip as the labels stand; mode keys that label with a dialog open; plain
fault text; clear form states; a log of what happened; every size class keeps the
essentials in view."""

import numpy as np
import pytest

from capture.config import Config
from capture.live.timeline import TimelineEntry
from capture.live.trials import SubjectInfo
from capture.recording.labels import LabelChange
from devices.base import DeviceEvent, DeviceState, DeviceStatus
from tests.tui.screens import screen_text
from tests.tui_fake_session import NOW_NS, FakeSession
from tests.waiting import wait_for_app
from tui.app import WalkcapApp
from tui.live_screen import LiveScreen
from tui.session_screen import SessionScreen
from tui.widgets.device_panel import device_rows, event_sentence
from tui.widgets.help_screen import HelpScreen
from tui.widgets.marker_dialog import MarkerDialog
from tui.widgets.quit_dialog import QuitDialog


async def _live(pilot):
    app = pilot.app
    await wait_for_app(
        pilot, lambda: app.ready and isinstance(app.screen, LiveScreen), timeout_s=30
    )
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
        await wait_for_app(pilot, lambda: "IMU unplugged" in screen_text(app), timeout_s=30)
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


async def test_the_decision_panel_names_the_fusion_method_it_shows():
    """The live session's configured method (or a replay's recorded one), not always HMM."""
    fake = FakeSession()
    fake.fusion_method = "steady+slope"
    app = WalkcapApp(Config(), session=fake, ask_subject=False)
    async with app.run_test(size=(160, 48)) as pilot:
        await _live(pilot)
        text = screen_text(app)
        assert "fused: steady + slope" in text and "(HMM)" not in text


async def test_the_true_strip_shows_the_labels_as_they_stand_after_an_undo():
    fake = LabelledFrames()
    app = WalkcapApp(Config(), session=fake, ask_subject=False)
    async with app.run_test(size=(120, 40)) as pilot:
        await _live(pilot)
        frames = len(fake.timeline)
        await wait_for_app(pilot, lambda: len(fake.timeline) > frames + 20, timeout_s=30)
        await pilot.press("3")
        frames = len(fake.timeline)
        await wait_for_app(pilot, lambda: len(fake.timeline) > frames + 40, timeout_s=30)
        await wait_for_app(pilot, lambda: "DS" in _row(app, "true"), timeout_s=30)
        await pilot.press("u")
        assert fake.label == "US"
        frames = len(fake.timeline)
        await wait_for_app(pilot, lambda: len(fake.timeline) > frames + 20, timeout_s=30)
        await pilot.pause(0.1)
        true = _row(app, "true")
        assert "US" in true and "DS" not in true  # as in the file, export and replay
        await pilot.press("3")  # a new change shows again from its own time
        frames = len(fake.timeline)
        await wait_for_app(pilot, lambda: len(fake.timeline) > frames + 20, timeout_s=30)
        await wait_for_app(pilot, lambda: "DS" in _row(app, "true"), timeout_s=30)


async def test_mode_keys_label_while_a_dialog_is_open_during_a_trial():
    fake = FakeSession()
    app = WalkcapApp(Config(), session=fake, ask_subject=False)
    async with app.run_test(size=(120, 40)) as pilot:
        await _live(pilot)
        await pilot.press("r")
        await wait_for_app(pilot, lambda: fake.recording, timeout_s=30)
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
        await wait_for_app(pilot, lambda: not fake.recording, timeout_s=30)
        await pilot.press("s")  # the form's fields still take digits
        assert isinstance(app.screen, SessionScreen)
        app.screen.query_one("#f-trial").value = ""
        app.screen.query_one("#f-trial").focus()
        await pilot.press("1", "2")
        assert app.screen.query_one("#f-trial").value == "12" and len(fake.labels) == 3


def test_a_fault_is_one_plain_sentence_and_the_counts_agree():
    status = DeviceStatus(
        backend="serial",
        state=DeviceState.OK,
        configured_rate_hz=100.0,
        measured_rate_hz=99.9,
        errors=0,
        details={"reconnects": 3, "checksum_errors": 0},
    )
    lost = DeviceEvent(1, "imu", "lost", "IMU lost (unplugged, or its port closed); retrying X")
    assert event_sentence(lost) == "IMU lost (unplugged, or its port closed); retrying X"
    stall = DeviceEvent(1, "camera", "stall", "no frame for 1.4 s")
    assert event_sentence(stall) == "camera stall: no frame for 1.4 s"
    rows = device_rows("imu", status)
    assert rows == device_rows("imu", status)


def test_an_unplugged_imu_says_so_plainly_and_its_counts_add_up():
    import time

    from devices.imu import EmulatedImu

    def wait(predicate, timeout=20.0):
        deadline = time.monotonic() + timeout
        while not predicate():
            assert time.monotonic() < deadline, "timed out"
            time.sleep(0.02)

    imu = EmulatedImu(rate_hz=100)
    try:
        imu.open()
        imu.start()
        wait(lambda: imu.delivered > 20)
        imu.emulator.inject("disconnect")
        wait(lambda: imu.status().state == "lost")
        status = imu.status()
        assert status.message == f"unplugged, or its port closed; retrying {imu.port}"
        imu.emulator.inject("reconnect")
        wait(lambda: imu.status().state in ("ok", "degraded"))
        events = [e for e in imu.poll_events() if e.kind == "lost"]
        assert events[0].message == f"IMU lost (unplugged, or its port closed); retrying {imu.port}"
        assert event_sentence(events[0]) == events[0].message  # the device named once
        status = imu.status()
        d = status.details
        assert d["reconnects"] == 1
        assert status.errors == d["checksum_errors"] + d["missing_packets"] + d["reconnects"]
        rows = device_rows("imu", status)
        assert "reconnects: 1" in [value for _, value, _ in rows]
    finally:
        imu.close()


def test_a_catch_up_burst_after_a_gap_is_no_faster_rate(monkeypatch):
    """100 Hz for 1 s, then 3 s without samples arriving; the samples taken in the last
    1.5 s of it arrive in one burst (the device sent them, the host read them late)."""
    from devices import base
    from devices.frames import ImuSample
    from devices.imu import Imu

    t0 = 10_000_000_000
    imu = Imu()

    def sample(taken_ns, arrived_ns):
        return ImuSample(host_time_ns=arrived_ns, time_ns=taken_ns, quaternion=np.ones(4))

    for k in range(100):  # 1 s streaming
        imu._deliver(sample(t0 + k * 10_000_000, t0 + k * 10_000_000))
    burst_at = t0 + 4_000_000_000
    for k in range(250, 400):  # all arriving within 2 ms
        imu._deliver(sample(t0 + k * 10_000_000, burst_at + (k - 250) * 10_000))
    monkeypatch.setattr(base, "now_ns", lambda: burst_at + 2_000_000)
    assert 95.0 <= imu._measured_rate() <= 101.0


async def test_the_amputee_box_reads_yes_or_no_without_colour():
    app = WalkcapApp(Config(), session=FakeSession())
    async with app.run_test(size=(120, 40)) as pilot:
        await wait_for_app(pilot, lambda: isinstance(app.screen, SessionScreen), timeout_s=30)
        box = app.screen.query_one("#f-amputee")
        await pilot.pause(0.1)
        row = next(line for line in screen_text(app).splitlines() if "Amputee" in line)
        assert "X" not in row and row.split("Amputee")[1].split()[-1] == "no"
        box.focus()
        await pilot.press("space")
        await pilot.pause(0.1)
        row = next(line for line in screen_text(app).splitlines() if "Amputee" in line)
        assert "✔" in row and row.rstrip().endswith("yes") and box.value


def test_an_out_that_is_a_file_is_a_usage_error_that_says_so(tmp_path, capsys):
    from capture.live import preflight
    from tui import cli

    file = tmp_path / "recordings"
    file.write_text("not a folder")
    with pytest.raises(SystemExit) as exit_:
        cli.main(["record", "--out", str(file), "--duration", "1"])
    assert exit_.value.code == 2  # a usage error
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and f"{file} is a file, not a folder" in err
    assert "File exists" not in err
    item = preflight.folder_item(file / "sub")  # a configured folder inside a file
    assert not item.ok and f"{file} is a file, not a folder" in item.reason


async def test_the_log_holds_what_happened_with_times(tmp_path):
    import re

    from devices.clock import now_ns
    from tui.logfile import logging_to_file

    path = tmp_path / "tui.log"
    fake = FakeSession()
    app = WalkcapApp(Config(), session=fake, ask_subject=False, drills=True)
    with logging_to_file(str(path)):
        async with app.run_test(size=(120, 40)) as pilot:
            await _live(pilot)
            await pilot.press("r")
            await wait_for_app(pilot, lambda: app.recording_path is not None, timeout_s=30)
            t = now_ns()
            fake.events += [
                DeviceEvent(t, "imu", "lost", "IMU lost (no data for 0.6 s); retrying /dev/x"),
                DeviceEvent(t + 1, "camera", "stall", "no frame for 1.4 s"),
                DeviceEvent(t + 2, "imu", "gap", "IMU: 2 packets missing"),
                DeviceEvent(t + 3, "imu", "reconnected", "IMU back after a gap of 2.01 s"),
            ]
            await wait_for_app(pilot, lambda: "IMU back" in screen_text(app), timeout_s=30)
            await pilot.press("r")
            await wait_for_app(pilot, lambda: len(app.trials) == 1, timeout_s=30)
            await wait_for_app(pilot, lambda: "saved" in screen_text(app), timeout_s=30)
    lines = path.read_text().splitlines()
    for said in (
        "recording S01_indoor_t01.mcap",
        "IMU lost (no data for 0.6 s); retrying /dev/x",
        "camera stall: no frame for 1.4 s",
        "IMU: 2 packets missing",
        "IMU back after a gap of 2.01 s",
        "saved S01_indoor_t01.mcap",
    ):
        found = [line for line in lines if said in line]
        assert len(found) == 1, (said, lines, _logging_state())
        (line,) = found
        assert re.match(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d", line), line  # with its time


LONG_FOLDER = "/home/lab/walking-study-2026/subject-sessions/recordings"
LONG_NAME = "S03_indoor_t05_20261202-071746.mcap"


@pytest.mark.parametrize("size", [(80, 24), (100, 30), (160, 48)])
async def test_every_size_class_keeps_what_the_operator_needs(size):
    """Device state, the banner with the file name, the five probabilities, the fused
    decision and the true / fused strips, at a laptop's 80 x 24 as on a large screen."""
    import re
    from pathlib import Path

    fake = FakeSession()
    for entry in fake.timeline:  # mock devices: the simulator's truth is a fourth strip
        entry.truth = entry.label
    fake.imu.state, fake.imu.message = "lost", "unplugged, or its port closed; retrying /dev/x"
    fake.imu.details["reconnects"] = 2
    fake.events.append(DeviceEvent(1, "imu", "lost", "IMU lost (unplugged); retrying /dev/x"))
    fake.start_recording(SubjectInfo(subject="S03", trial=5))
    fake._recording_path = Path(LONG_FOLDER) / LONG_NAME
    app = WalkcapApp(
        Config(), session=fake, subject=SubjectInfo(subject="S03", trial=5), ask_subject=False
    )
    async with app.run_test(size=size) as pilot:
        app.recording_path = fake._recording_path
        await _live(pilot)
        await pilot.pause(0.2)
        lines = screen_text(app).splitlines()
        text = "\n".join(lines)
        box = app.screen.query_one("#decision").region
        strips = app.screen._compositor.render_strips()[box.y : box.bottom]
        segments = []
        for strip in strips:
            segments += list(strip.crop(box.x, box.right))
    # the decision in its mode's colour: block letters, or its letters on a band of it
    blue = "#2f7ff0"
    colours = [(s.text, s.style.color, s.style.bgcolor) for s in segments if s.style]
    assert any(
        ("US" in t and bg is not None and bg.triplet.hex == blue)
        or ("██" in t and fg is not None and fg.triplet.hex == blue)
        for t, fg, bg in colours
    )
    assert len(lines) == size[1]
    banner = lines[1]
    assert "● REC" in banner and "trial 5" in banner and LONG_NAME in banner
    for device, state in (("camera", "ok"), ("IMU", "lost")):
        assert re.search(rf"│ {device} +{state}  mock", text), device
    assert "unplugged" in text
    assert len(re.findall(r"│ rate +\d", text)) == 2 and len(re.findall(r"│ drops +\d", text)) == 2
    for mode, p in zip(("LG", "US", "DS", "UR", "DR"), ("0.05", "0.82", "0.03", "0.07", "0.03")):
        assert re.search(rf"{mode} [ ▏▎▍▌▋▊▉█]+ {p}", text), mode
    assert "up stairs" in text and re.search(r"CNN US +true US", text)
    for strip in ("true", "CNN", "fused", "sim"):
        assert re.search(rf"^│? ?{strip} +[LGUSDR ]", text, re.M), strip
    assert re.search(r"-20 s .* now", text)
    if size[1] >= 40:  # a large screen shows the details as well
        for title in ("recording", "profile", "terrain geometry", "trials this session"):
            assert f"─ {title} " in text, title
        assert "pipeline" in text and "reconnects: 2" in text


def _fit(drift_ppm: float, jitter_ms: float, seconds: float, seed: int):
    """A DeviceClock fed `seconds` of 100 Hz samples whose receive delay is 0.3 ms plus
    exponential jitter, now and then a sample 20 ms late."""
    from devices.imu.clock import TICK_NS, DeviceClock

    rng = np.random.default_rng(seed)
    clock = DeviceClock()
    n = int(seconds * 100)
    delays = 0.3e6 + rng.exponential(jitter_ms * 1e6, n)
    delays += (rng.random(n) < 0.02) * rng.exponential(20e6, n)
    for k in range(n):
        device_ns = k * 10_000_000
        host = 5e9 + device_ns / (1 + drift_ppm * 1e-6) + delays[k]
        clock.update(device_ns // TICK_NS, int(host))
    return clock.state()


def test_the_drift_comes_with_its_uncertainty_and_holds_within_it():
    assert _fit(50.0, 1.0, 1.5, 0).drift_uncertainty_ppm is None  # under 2 s: not fitted
    short = [_fit(50.0, 2.0, 3.0, seed) for seed in range(40)]
    inside = [abs(s.drift_ppm - 50.0) <= s.drift_uncertainty_ppm for s in short]
    assert sum(inside) >= 36  # about 95 in 100
    long = [_fit(50.0, 2.0, 20.0, seed) for seed in range(5)]
    assert max(s.drift_uncertainty_ppm for s in long) < min(s.drift_uncertainty_ppm for s in short)


def test_check_stream_and_panel_say_the_drift_with_its_uncertainty():
    from capture.live import preflight
    from tui.commands.imu import _stream_line

    details = {
        "drift_ppm": 48.2,
        "drift_uncertainty_ppm": 12.4,
        "residual_ms": 0.5,
        "checksum_errors": 0,
        "missing_packets": 0,
    }
    status = _imu_at_100_hz(details)
    assert "clock drift +48 ± 12 ppm" in preflight.device_item("imu", status).summary
    assert "drift +48 ± 12 ppm" in _stream_line(None, status)
    assert ("drift", "+48 ± 12 ppm", "") in device_rows("imu", status)
    details["drift_uncertainty_ppm"] = None  # the first 2 s: held at zero, and said so
    assert "drift not fitted yet" in _stream_line(None, status)
    assert "clock drift not fitted yet" in preflight.device_item("imu", status).summary


def _imu_at_100_hz(details: dict) -> DeviceStatus:
    """A mock IMU streaming at its configured 100 Hz, with `details`."""
    return DeviceStatus(
        backend="mock",
        state="ok",
        configured_rate_hz=100.0,
        measured_rate_hz=100.0,
        details=details,
    )


def _logging_state() -> dict:
    import logging

    names = ("tui", "tui.app", "tui.live_screen", "capture", "capture.live.session")
    return {
        "disable": logging.root.manager.disable,
        "root": logging.getLogger().level,
        **{n: (logging.getLogger(n).level, logging.getLogger(n).disabled) for n in names},
    }


def test_the_stream_and_the_live_screen_show_the_thighs_steps_and_cadence():
    from capture.live.session import Snapshot
    from tests.inference.test_gait import samples, walking
    from tui.commands.imu import _stream_line
    from tui.live_screen import pipeline_rows

    details = {"drift_ppm": 0.0, "residual_ms": 0.5, "checksum_errors": 0, "missing_packets": 0}
    status = _imu_at_100_hz(details)
    from inference.gait import GaitDetector

    gait = GaitDetector()
    assert "steps 0 (still)" in _stream_line(None, status, gait)
    for s in samples(walking):
        gait.push(s)
    assert f"steps {2 * gait.heel_contacts} (100/min)" in _stream_line(None, status, gait)
    snap = Snapshot(0, True, None, None, {}, None, None, [], [], None, None, 0, {})
    assert not [r for r in pipeline_rows(snap) if r[0] == "steps"]  # a replay knows none
    snap.steps, snap.cadence_spm = 20, 104.4
    assert ("steps", "20, 104 steps/min", "") in pipeline_rows(snap)
    snap.cadence_spm = None
    assert ("steps", "20, standing", "") in pipeline_rows(snap)
