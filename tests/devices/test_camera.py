"""The camera interface, the backend registry and the mock camera."""

import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from devices.camera import BACKENDS, camera_class, open_camera
from devices.clock import now_ns
from devices.config import CameraConfig, SimulatorConfig
from devices.errors import DeviceNotAvailable
from devices.simulator import MockCamera, Simulator, make_course
from tests.devices.scripted_camera import ScriptedCamera, blank_frame

# ---- base class ----------------------------------------------------------------------------


def test_life_cycle_is_idempotent_and_a_context_manager():
    cam = ScriptedCamera()
    with cam:
        cam.open()
        cam.start()
        cam.start()
        assert cam.running and cam.status().state == "ok"
        cam.stop()
        cam.stop()
        assert cam.status().state == "stopped"
    cam.close()
    assert cam.calls == ["open", "start", "stop", "close"]


def test_a_slow_consumer_loses_the_oldest_frames_counted_never_blocking_the_producer():
    cam = ScriptedCamera(CameraConfig(buffer_frames=4))
    cam.start()
    t0 = time.perf_counter()
    for i in range(10):
        cam._deliver(blank_frame(i))
    assert time.perf_counter() - t0 < 0.1
    assert [cam.recv(0).index for _ in range(4)] == [6, 7, 8, 9]
    assert cam.recv(0.01) is None
    status = cam.status()
    assert status.delivered == 10 and status.dropped == 6
    events = cam.poll_events()
    assert [e.kind for e in events] == ["drop"] and events[0].details["dropped"] > 0
    assert cam.poll_events() == []


def test_recv_waits_for_a_frame_from_another_thread():
    cam = ScriptedCamera()
    cam.start()
    threading.Timer(0.05, cam._deliver, args=(blank_frame(0),)).start()
    assert cam.recv(timeout=2.0).index == 0


def test_a_silent_camera_is_reported_degraded_once():
    cam = ScriptedCamera(CameraConfig(fps=45))
    cam.start()
    cam._started_ns -= int(3e9)  # as if started 3 s ago without a frame
    status = cam.status()
    assert status.state == "degraded" and "no frame" in status.message
    cam.status()
    assert [e.kind for e in cam.poll_events()] == ["stall"]
    cam._deliver(blank_frame(0))
    assert cam.status().state == "ok"


def test_measured_rate_follows_deliveries():
    cam = ScriptedCamera()
    cam.start()
    t = now_ns()
    for i in range(11):
        f = blank_frame(i)
        f.device_time_ns = f.host_time_ns = t - int((10 - i) * 1e8)  # 10 Hz, the last second
        cam._deliver(f)
    assert cam.status().measured_rate_hz == pytest.approx(10.0, rel=0.01)


class StepClock:
    """The session clock as the test sets it (ns)."""

    def __init__(self) -> None:
        self.t = 0

    def __call__(self) -> int:
        return self.t


def stalled_arrivals(fps: float = 15.0, n: int = 60, stall_at: int = 30, stall_s: float = 0.6):
    """(device time, arrival) of frames taken at a steady `fps`: the host stalls for
    `stall_s` when frame `stall_at` is taken; the frames queued meanwhile arrive one after
    another, 20 ms apart, once it ends, until the backlog is gone."""
    period = int(1e9 / fps)
    base = 10**12
    stall_end = base + stall_at * period + int(stall_s * 1e9)
    out, previous = [], 0
    for i in range(n):
        device = base + i * period
        arrival = max(device + 2_000_000, previous + 20_000_000 if previous else 0)
        if i >= stall_at:
            arrival = max(arrival, stall_end)
        out.append((device, arrival))
        previous = arrival
    return out


@pytest.mark.parametrize("status_at", [30, 35, 45, 59])
def test_a_host_stall_is_no_change_of_frame_rate(status_at):
    """The rate comes from the frames' device times: arrivals that stall and then come in
    a burst read as the camera's steady 15 Hz, just after the burst and later on."""
    clock = StepClock()
    cam = ScriptedCamera(clock=clock)
    cam.start()
    arrivals = stalled_arrivals()
    for k, (device, arrival) in enumerate(arrivals):
        f = blank_frame(k)
        f.device_time_ns, f.host_time_ns = device, arrival
        clock.t = arrival
        cam._deliver(f)
        if k == status_at:
            break
    assert cam.status().measured_rate_hz == pytest.approx(15.0, rel=0.01)


# ---- registry ------------------------------------------------------------------------------


def test_registry_names_the_three_backends():
    import capture  # noqa: F401  (registers the replay camera, which reads recordings)

    assert set(BACKENDS) == {"mock", "royale", "replay"}
    assert camera_class("mock") is MockCamera


@pytest.mark.subprocess
def test_devices_alone_register_only_their_own_backends():
    code = "import devices.camera as c; print(sorted(c.BACKENDS))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "['mock', 'royale']"


def test_unknown_backend_is_one_clear_error():
    with pytest.raises(DeviceNotAvailable, match="unknown camera backend 'kinect'.*mock"):
        camera_class("kinect")


def test_a_backend_module_that_cannot_be_imported_is_reported(monkeypatch):
    monkeypatch.setitem(BACKENDS, "broken", "devices.no_such_module:Nothing")
    with pytest.raises(DeviceNotAvailable, match="'broken' cannot be loaded"):
        open_camera(CameraConfig(backend="broken"))


@pytest.mark.subprocess
def test_backends_are_imported_only_when_chosen():
    code = (
        "import sys, devices.camera, capture; "
        "print(any(m in sys.modules for m in ('open3d', 'devices.royale', "
        "'devices.simulator', 'capture.live.replay_camera', 'capture.recording.reader')))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


# ---- mock camera ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def short_sim():
    return Simulator(make_course("indoor", 0, modes=["LG"]), seed=0)


def test_open_camera_builds_the_mock_from_the_configuration():
    cam = open_camera(
        CameraConfig(backend="mock", fps=30),
        SimulatorConfig(course="outdoor", seed=4, realtime=False),
    )
    try:
        assert isinstance(cam, MockCamera)
        assert cam.simulator.course.preset == "outdoor" and cam.simulator.course.seed == 4
        assert cam.realtime is False and cam.status().details["course"] == "outdoor"
    finally:
        cam.close()


def test_bad_simulator_configuration_names_the_key():
    from devices.errors import DeviceConfigError

    with pytest.raises(DeviceConfigError, match="simulator.*beach"):
        open_camera(CameraConfig(backend="mock"), SimulatorConfig(course="beach"))


@pytest.mark.realtime
def test_mock_runs_to_the_end_of_the_course_then_stops(short_sim):
    cam = MockCamera(CameraConfig(fps=15, buffer_frames=2), simulator=short_sim, realtime=False)
    with cam:
        cam.start()
        frames = list(cam)  # as fast as consumed, nothing dropped
    expected = int(short_sim.duration_s * 15) + 1
    assert [f.index for f in frames] == list(range(expected))
    status = cam.status()
    assert status.state == "stopped" and status.dropped == 0 and status.delivered == expected
    assert "end_of_course" in [e.kind for e in cam.poll_events()]
    assert not cam.running


@pytest.mark.realtime
def test_mock_frames_share_the_time_base_of_the_imu_orientation(short_sim):
    cam = MockCamera(CameraConfig(fps=15), simulator=short_sim, realtime=False)
    with cam:
        cam.start()
        start = cam.start_time_ns
        frames = [cam.recv(2.0) for _ in range(5)]
    for f in frames:
        t = (f.device_time_ns - start) * 1e-9
        assert t == pytest.approx(f.index / 15, abs=1e-9)
        np.testing.assert_allclose(cam.orientation_at(t), f.truth["thigh_quaternion"])
        np.testing.assert_allclose(short_sim.thigh_quaternion(t), f.truth["thigh_quaternion"])
        assert f.host_time_ns >= start


@pytest.mark.realtime
def test_mock_keeps_a_start_time_chosen_before_start(short_sim):
    cam = MockCamera(simulator=short_sim, realtime=False)
    chosen = now_ns() - int(1e6)
    cam.start_time_ns = chosen
    with cam:
        cam.start()
        assert cam.recv(2.0).device_time_ns == chosen


class SteppedClock:
    """A session clock that moves only when the camera sleeps on it (or a test moves it)."""

    def __init__(self, t_ns: int = 10**12, sleeps_until_stop: int | None = None) -> None:
        self.t = self.start = t_ns
        self.sleeps: list[float] = []
        self._sleeps_until_stop = sleeps_until_stop

    def __call__(self) -> int:
        return self.t

    def sleep(self, seconds: float) -> bool:
        self.sleeps.append(seconds)
        self.t += round(seconds * 1e9)
        return len(self.sleeps) == self._sleeps_until_stop  # True: stopped meanwhile


@pytest.mark.realtime
def test_mock_sends_frame_k_at_k_periods_on_its_clock(short_sim):
    clock = SteppedClock(sleeps_until_stop=7)  # stopped while waiting for frame 7
    cam = MockCamera(
        CameraConfig(fps=20), simulator=short_sim, realtime=True, clock=clock, sleep=clock.sleep
    )
    with cam:
        cam.start()
        # Bounded waits on the frames and on the producer's end, never on a wall-clock gap.
        frames = [cam.recv(60.0) for _ in range(7)]
        cam._producer.thread.join(60.0)
        assert not cam._producer.thread.is_alive() and cam.recv(0) is None
    assert [f.index for f in frames] == list(range(7))
    assert [f.device_time_ns - clock.start for f in frames] == [k * 50_000_000 for k in range(7)]
    assert [f.host_time_ns for f in frames] == [f.device_time_ns for f in frames]  # when due
    np.testing.assert_allclose(clock.sleeps, 0.05)  # one period before each frame after 0


@pytest.mark.realtime
def test_the_watchdog_measures_silence_on_the_cameras_own_clock(short_sim):
    """A camera on an injected clock is judged on it: the real clock running on while the
    camera's stands still (a test, a loaded machine) is no silence of the camera."""
    clock = SteppedClock(t_ns=1, sleeps_until_stop=3)  # far behind the real clock
    cam = MockCamera(
        CameraConfig(fps=20), simulator=short_sim, realtime=True, clock=clock, sleep=clock.sleep
    )
    with cam:
        cam.start()
        frames = [cam.recv(60.0) for _ in range(3)]
        status = cam.status()
    assert [f.index for f in frames] == [0, 1, 2]
    assert status.state == "ok", status.message
    assert not {"stall", "lost"} & {e.kind for e in cam.poll_events()}


@pytest.mark.realtime
def test_a_mock_too_slow_for_its_rate_skips_to_the_current_frame_counted(short_sim, monkeypatch):
    clock = SteppedClock()
    render = short_sim.render

    def slow_render(*args, **kw):
        clock.t += 250_000_000  # five periods at 20 fps
        return render(*args, **kw)

    monkeypatch.setattr(short_sim, "render", slow_render)
    cam = MockCamera(
        CameraConfig(fps=20, buffer_frames=64),
        simulator=short_sim,
        realtime=True,
        clock=clock,
        sleep=clock.sleep,
    )
    with cam:
        cam.start()
        frames = list(cam)  # to the end of the course (frames 0 to n - 1)
    n = int(short_sim.duration_s * 20) + 1
    sent = list(range(0, n, 5))  # each render ends 4 periods late: those 4 frames are skipped
    late = [s for s in sent if s + 1 < n]  # the end of the course comes before the next
    assert [f.index for f in frames] == sent
    assert [f.device_time_ns - clock.start for f in frames] == [k * 50_000_000 for k in sent]
    assert [f.host_time_ns - clock.start for f in frames] == [
        (i + 1) * 250_000_000 for i in range(len(sent))
    ]
    gaps = [e for e in cam.poll_events() if e.kind == "gap"]
    assert [e.details["skipped"] for e in gaps] == [4] * len(late)
    assert cam.status().errors == 4 * len(late) and clock.sleeps == []


@pytest.mark.realtime
def test_mock_loops_when_asked(short_sim):
    cam = MockCamera(
        CameraConfig(fps=15, buffer_frames=2), simulator=short_sim, realtime=False, loop=True
    )
    n = int(short_sim.duration_s * 15) + 10
    with cam:
        cam.start()
        frames = [cam.recv(2.0) for _ in range(n)]
    assert [f.index for f in frames] == list(range(n))
    assert frames[-1].truth["segment"] == 0 and cam.status().state == "stopped"
    assert "end_of_course" not in [e.kind for e in cam.poll_events()]
    t = n - 1
    looped = cam.walk_time(t / 15)
    assert looped < short_sim.duration_s
    np.testing.assert_allclose(cam.orientation_at(t / 15), short_sim.thigh_quaternion(looped))


def test_a_frame_while_the_watchdog_reopens_never_waits_and_its_resume_is_kept():
    """A backend's stop may wait for its frame callback to return (royale's stopCapture
    does): a frame that arrives while the watchdog holds its lock to reopen the device is
    delivered at once, and the watchdog's next check reports the camera back, with the gap
    measured to that frame."""
    import threading

    clock = StepClock()
    cam = ScriptedCamera(clock=clock)
    cam.start()
    cam._watch_stop.set()  # the test runs the checks
    cam._watchdog.thread.join(5)
    first = blank_frame(0)
    first.host_time_ns = first.device_time_ns = clock.t = 10**9
    cam._deliver(first)
    assert cam.recv(timeout=1.0) is first
    clock.t = 10**9 + int((cam._lost_after_s() + 1) * 1e9)
    cam._check(clock.t)
    assert cam.status().state == "lost"
    cam.poll_events()

    held, release = threading.Event(), threading.Event()

    def reopening():  # the watchdog inside a reopen: its lock held
        with cam._watch_lock:
            held.set()
            release.wait(60)

    watchdog = threading.Thread(target=reopening, daemon=True)
    watchdog.start()
    assert held.wait(10)
    back = blank_frame(1)
    back.host_time_ns = back.device_time_ns = clock.t = clock.t + 10**8
    delivered = threading.Thread(target=cam._deliver, args=(back,), daemon=True)
    delivered.start()
    delivered.join(5)
    assert not delivered.is_alive()  # the frame did not wait for the watchdog
    assert cam.recv(timeout=1.0) is back
    release.set()
    watchdog.join(10)

    cam._check(clock.t)
    (event,) = [e for e in cam.poll_events() if e.kind == "reconnected"]
    assert event.details["gap_start_ns"] == first.host_time_ns
    assert event.details["gap_end_ns"] == back.host_time_ns
    assert cam.status().state == "ok"
    cam.stop()
