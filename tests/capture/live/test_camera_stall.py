"""A camera stall is reported when it starts and when frames resume (with the gap); silent
for `[camera] lost_after_s` the camera is lost and reopened until frames come again."""

from __future__ import annotations

import time

import numpy as np
import pytest

from capture.live.trials import SubjectInfo
from devices.clock import now_ns
from devices.config import CameraConfig
from tests.capture.live.sessions import events_of, session_in
from tests.devices.scripted_camera import ScriptedCamera, blank_frame
from tests.waiting import wait_for


def test_frames_after_a_stall_are_an_event_with_the_gap():
    cam = ScriptedCamera(CameraConfig(fps=15))
    cam.start()
    try:
        cam._deliver(blank_frame(0))
        cam._last_frame_ns -= int(2e9)  # the last frame came 2 s ago
        cam._check(now_ns())
        cam._deliver(blank_frame(1))
        events = cam.poll_events()
        assert [e.kind for e in events] == ["stall", "resumed"]
        assert 2.0 <= events[1].details["gap_s"] < 2.5 and "2." in events[1].message
        assert cam.status().state == "ok"
    finally:
        cam.close()


def test_a_long_stall_is_lost_then_reopened_and_numbered_on():
    cam = ScriptedCamera(CameraConfig(fps=15, lost_after_s=3.0))
    cam.start()
    try:
        for i in range(5):
            cam._deliver(blank_frame(i))
        cam.calls.clear()
        cam._last_frame_ns -= int(6e9)  # a 6 s stall
        cam._check(now_ns())
        assert cam.status().state == "lost"
        assert cam.calls == ["stop", "close", "open", "start"]  # reopened at once
        frame = blank_frame(0)  # the device numbers from 0 again
        cam._deliver(frame)
        assert frame.index == 5 and cam.status().state == "ok"
        kinds = [e.kind for e in cam.poll_events()]
        assert kinds == ["stall", "lost", "reconnected"]
    finally:
        cam.close()


def test_a_reopen_that_fails_is_retried():
    class Stubborn(ScriptedCamera):
        fails = 0

        def _open(self):
            super()._open()
            if self.fails:
                self.fails -= 1
                raise OSError("USB device not found")

    cam = Stubborn(CameraConfig(fps=15, lost_after_s=1.0))
    cam.open()
    cam.fails = 1
    cam.start()
    try:
        cam._last_frame_ns = now_ns() - int(2e9)
        cam._check(now_ns())
        assert "retrying" in cam.status().message and cam.reopens == 0
        cam._next_reopen_ns = 0
        cam._check(now_ns())
        assert cam.reopens == 1
    finally:
        cam.close()


@pytest.mark.realtime
def test_a_stall_in_a_session_is_lost_reopened_and_back(tmp_path):
    session = session_in(tmp_path)
    session.config.camera.lost_after_s = 1.0
    session.start()
    try:
        path = session.start_recording(SubjectInfo())
        time.sleep(0.5)
        session._camera.inject("stall", seconds=2.5)
        wait_for(lambda: session.snapshot().camera.state == "lost", 3.0)
        wait_for(lambda: session.snapshot().camera.state == "ok", 5.0)
        time.sleep(0.5)
    finally:
        session.stop()
    events = [e for e in events_of(path) if e["device"] == "camera"]
    kinds = [e["kind"] for e in events]
    assert kinds[:3] == ["stall", "lost", "reconnected"], kinds
    assert 2.0 < events[2]["details"]["gap_s"] < 4.0
    from capture.recording.reader import open_recording

    index = [m.sequence for m in open_recording(path).messages(["/camera/depth"])]
    assert np.all(np.diff(index) > 0)  # numbered on after the reopen: no frame twice


def test_a_host_stall_is_not_the_cameras_silence_and_its_frames_are_taken():
    """The host stopped 6 s (SIGSTOP, swap): nothing of walkcap ran, the watchdog neither.
    The frames the camera kept meanwhile arrive after it: no 'lost', no reopen."""
    clock = [10**12]
    cam = ScriptedCamera(CameraConfig(fps=15, lost_after_s=5.0), clock=lambda: clock[0])
    cam.start()

    def frame(i):
        f = blank_frame(i)
        f.device_time_ns = f.host_time_ns = clock[0]
        return f

    try:
        for i in range(5):
            cam._deliver(frame(i))
            clock[0] += 66_666_667
            cam._check(clock[0])  # the watchdog, every period
        cam.calls.clear()
        clock[0] += 6_000_000_000  # the host stalls: no check, no frame for 6 s
        cam._check(clock[0])  # the watchdog runs again first
        assert cam.status().state == "ok" and cam.calls == []
        for i in range(5, 13):  # what the camera kept while the host stood still
            cam._deliver(frame(i))
        assert [cam.recv(0).index for _ in range(8)] == list(range(5, 13))
        assert not {"stall", "lost"} & {e.kind for e in cam.poll_events()}
        for _ in range(60):  # then the camera itself goes silent: lost after 5 s, as always
            clock[0] += 100_000_000
            cam._check(clock[0])
        assert cam.status().state == "lost"
    finally:
        cam.close()
