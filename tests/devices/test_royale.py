"""The royale backend against the stand-ins of pmd's roypy binding in fake_royale.py, one
per generation (3.x, 4.x, 5.x): opening, frames, lens, use cases, recordings, and an unplug
through the camera layer's loss rule."""

import sys
import time
import types

import numpy as np
import pytest

from devices.camera import open_camera
from devices.config import CameraConfig
from devices.errors import DeviceInitError, DeviceNotAvailable
from devices.royale import RoyaleCamera, choose_use_case, use_case_fps
from tests.devices.fake_royale import (
    GENERATIONS,
    USE_CASES,
    FakeDevice,
    FakeDevice4,
    FakeDevice5,
    H,
    W,
    install,
    make_roypy,
    sdk_points,
)
from tests.waiting import wait_for


@pytest.fixture
def roypy(monkeypatch):
    return install(monkeypatch, make_roypy())


@pytest.fixture(params=GENERATIONS, ids=lambda g: f"roypy{g}")
def generation(request, monkeypatch):
    """Install a stand-in of each binding generation in turn; returns a maker."""

    def make(**kw):
        return install(monkeypatch, make_roypy(generation=request.param, **kw))

    make.generation = request.param
    return make


def royale(**kw) -> CameraConfig:
    return CameraConfig(backend="royale", **kw)


def frames_from(cam, n, timeout=2.0):
    frames = []
    deadline = time.monotonic() + timeout
    while len(frames) < n and time.monotonic() < deadline:
        f = cam.recv(0.1)
        if f is not None:
            frames.append(f)
    return frames


# ---- without the SDK -----------------------------------------------------------------------


def test_without_roypy_choosing_royale_fails_with_one_line(monkeypatch):
    monkeypatch.setitem(sys.modules, "roypypack", None)  # neither import works
    monkeypatch.setitem(sys.modules, "roypy", None)
    with pytest.raises(DeviceNotAvailable) as e:
        open_camera(royale())
    message = str(e.value)
    assert "\n" not in message
    assert "roypy" in message and "royale SDK" in message and "PYTHONPATH" in message


def test_the_cli_shows_it_as_one_line(monkeypatch, tmp_path, capsys):
    """What a user sees when a command opens the camera: one line naming the fix."""
    from tui.cli import main

    monkeypatch.setitem(sys.modules, "roypypack", None)
    monkeypatch.setitem(sys.modules, "roypy", None)
    (tmp_path / "walkcap.toml").write_text('[camera]\nbackend = "royale"\n')
    assert main(["calibrate", "--dry-run"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "PYTHONPATH" in err and "Traceback" not in err


# ---- use cases -----------------------------------------------------------------------------


def test_use_case_names_carry_the_frame_rate():
    assert use_case_fps("MODE_9_15FPS_700") == 15.0
    assert use_case_fps("Low_Noise_Extended") is None


@pytest.mark.parametrize(
    "fps, expected",
    [
        (15, "MODE_9_15FPS_700"),
        (45, "MODE_5_45FPS_500"),
        (5, "MODE_9_5FPS_2000"),
        (30, "MODE_5_35FPS_600"),
        (60, "MODE_5_45FPS_500"),
    ],
)
def test_the_use_case_nearest_the_configured_fps_is_chosen(fps, expected):
    assert choose_use_case(USE_CASES, fps) == expected


def test_a_use_case_the_camera_lacks_is_an_error_listing_the_offered():
    with pytest.raises(DeviceInitError, match="MODE_X.*offered: MODE_9_5FPS_2000"):
        choose_use_case(USE_CASES, 15, "MODE_X")


# ---- a live camera -------------------------------------------------------------------------


def test_opens_the_first_camera_with_the_use_case_for_15_fps(roypy):
    cam = open_camera(royale(fps=15))
    try:
        device = roypy.devices[0]
        assert device.initialized and device.source == "0005-1203-0034-2011"
        assert device.use_case == "MODE_9_15FPS_700"
        g = cam.geometry
        assert (g.width, g.height, g.fx, g.fy, g.cx, g.cy) == (W, H, 210.0, 211.0, 113.0, 84.5)
        assert g.name == "PICOFLEXX" and g.serial == "0005-1203-0034-2011"
        assert cam.status().details["use_case"] == "MODE_9_15FPS_700"
    finally:
        cam.close()


def test_a_packaged_roypy_is_found_as_pmds_samples_import_it(monkeypatch):
    """pmd's 5.x samples: `from roypypack import roypy`, then `import roypy`."""
    install(monkeypatch, make_roypy(generation="5", frames=2), packaged=True)
    with open_camera(royale()) as cam:
        assert cam.status().details["roypy"] == "5.12.0.3089"
        cam.start()
        assert frames_from(cam, 2, timeout=5.0)


def test_the_lens_map_gives_the_intrinsics_in_every_generation(generation):
    """getLensParameters() is the no-argument LensParamMap in every interface file."""
    generation()
    with open_camera(royale()) as cam:
        assert (cam.geometry.fx, cam.geometry.fy, cam.geometry.cx, cam.geometry.cy) == (
            210.0,
            211.0,
            113.0,
            84.5,
        )
        assert cam.status().details["intrinsics"] == "device"


def test_each_generation_opens_streams_and_closes(generation):
    roypy = generation(frames=3)
    cam = open_camera(royale(fps=15))
    try:
        device = roypy.devices[0]
        assert device.initialized and device.use_case == "MODE_9_15FPS_700"
        cam.start()
        frames = frames_from(cam, 3, timeout=5.0)
    finally:
        cam.close()
    assert [f.index for f in frames] == [0, 1, 2]
    for k, f in enumerate(frames):
        assert f.xyz.shape == (H, W, 3) and f.xyz.dtype == np.float32
        np.testing.assert_allclose(f.xyz[1:, :, 2], 1.0 + k / 100, rtol=1e-6)
        assert f.gray[5, 5] == 300 + k and f.confidence[5, 5] == 200
        assert np.all(f.xyz[0] == 0)
    assert not device.capturing.is_set()
    details = cam.status().details
    assert details["intrinsics"] == "device" and cam.geometry.fx == 210.0
    expected = {"3": "points() a point at a time", "4": "npoints (numpy)", "5": "npoints (numpy)"}
    assert details["frame_path"] == expected[generation.generation]


def test_a_failing_lens_call_costs_only_the_intrinsics(monkeypatch):
    def broken(self):
        raise RuntimeError("DEVICE_IS_BUSY")

    monkeypatch.setattr(FakeDevice4, "getLensParameters", broken)
    install(monkeypatch, make_roypy(generation="4"))
    with open_camera(royale()) as cam:
        details = cam.status().details
        assert details["intrinsics"] == "nominal: getLensParameters failed: DEVICE_IS_BUSY"
        cam.start()
        assert frames_from(cam, 1)  # the camera streams all the same


def test_the_fastest_frame_path_of_each_generation(generation):
    from devices.royale import frame_path

    sdk = generation()
    data = sdk.DepthData(sdk_points(0, sdk.channels), 0)
    assert frame_path(data) == {"3": "points", "4": "npoints", "5": "npoints"}[sdk.generation]


class SessionClock:
    """The session clock as the test moves it (ns): frames are stamped with it and the
    camera layer's watchdog measures silence on it."""

    def __init__(self) -> None:
        self.t = 10**12

    def __call__(self) -> int:
        return self.t


def advance(cam, clock, seconds: float, step_s: float = 0.1) -> None:
    """The session clock on by `seconds` in the watchdog's steps, a check after each (one
    jump past a second would read as the host's own stall, which excuses silence)."""
    for _ in range(round(seconds / step_s)):
        clock.t += round(step_s * 1e9)
        cam._check(clock.t)


# how the unplug is seen: (generation, isConnected offered, words of the "lost" event)
UNPLUGS = {
    "event": ("5", True, "USB Device disconnected."),
    "isConnected": ("4", True, "camera disconnected"),
    "silence": ("4", False, "no frame for 2.1 s"),
}


@pytest.mark.parametrize("detection", list(UNPLUGS))
def test_an_unplug_is_lost_and_reopened_by_the_camera_layers_rule(detection, monkeypatch):
    """Royale says what it knows (the unplug event, isConnected()); the rest is the rule
    every backend shares: a camera that says nothing is lost after `lost_after_s` without
    a frame (a stall first), and a lost camera is reopened every `lost_after_s` until it
    is back: "reconnected" with the gap, frames numbered on. Scripted clock, no timing."""
    gen, is_connected, words = UNPLUGS[detection]
    if not is_connected:
        monkeypatch.delattr(FakeDevice, "isConnected")
    roypy = install(monkeypatch, make_roypy(generation=gen, frames=100_000))
    roypy.frame_s = 0.005
    clock = SessionClock()
    cam = open_camera(royale(lost_after_s=2.0), clock=clock)
    try:
        cam.start()
        seen = frames_from(cam, 3, timeout=30.0)
        assert len(seen) == 3
        first = roypy.devices[0]
        before = cam.status().details
        roypy.unplug()
        first.thread.join(30.0)  # the SDK delivers no more
        assert not first.thread.is_alive()
        while (frame := cam.recv(0)) is not None:
            seen.append(frame)
        if detection == "silence":
            advance(cam, clock, 1.9)
            assert cam.status().state == "degraded"  # a stall, not lost yet
            advance(cam, clock, 0.2)
        else:
            cam._check(clock.t)  # the next check: no silence needed
        lost_at = clock.t
        assert cam.status().state == "lost"
        assert "no pmd camera connected" in cam.status().message  # the reopen tried at once
        roypy.replug()
        advance(cam, clock, 1.9)
        assert len(roypy.devices) == 1  # the next reopen after lost_after_s
        advance(cam, clock, 0.1)
        assert len(roypy.devices) == 2 and roypy.devices[1].source == first.getId()
        wait_for(lambda: cam.status().state == "ok", what="frames from the reopened camera")
        after = frames_from(cam, 1, timeout=30.0)
        details = cam.status().details
        assert details["frame_path"] == "npoints (numpy)"  # kept across the reopen
        assert details["unplug_detection"] == before["unplug_detection"]
        events = [e for e in cam.poll_events() if e.kind in ("stall", "lost", "reconnected")]
    finally:
        cam.close()
    assert after and after[0].index > seen[-1].index  # numbered on from before the loss
    stall = ["stall"] if detection == "silence" else []
    assert [e.kind for e in events] == [*stall, "lost", "reconnected"]
    assert words in events[-2].message
    gap_s = (clock.t - lost_at) * 1e-9 + (2.1 if detection == "silence" else 0.0)
    assert events[-1].details["gap_s"] == pytest.approx(gap_s)
    assert not roypy.devices[1].capturing.is_set()  # stopped on close


@pytest.mark.realtime
def test_an_event_listener_that_cannot_be_made_is_a_warning_not_a_failed_start(monkeypatch):
    """A binding whose only event listener is the abstract IEventListener: the camera
    starts, says so once, and watches isConnected() instead."""
    roypy = install(monkeypatch, make_roypy(generation="5", python_event_listener=False))
    roypy.frames, roypy.frame_s = 100_000, 0.01
    cam = open_camera(royale())
    try:
        cam.start()
        assert frames_from(cam, 1, timeout=5.0)
        detection = cam.status().details["unplug_detection"]
        assert detection.startswith("isConnected and silence") and "abstract" in detection
        roypy.unplug()
        wait_for(lambda: cam.status().state == "lost", what="the camera lost")
        events = cam.poll_events()
    finally:
        cam.close()
    assert [e.kind for e in events].count("no_events") == 1


def test_a_failing_register_event_listener_is_a_warning_not_a_failed_start(monkeypatch):
    def refuse(self, listener):
        raise RuntimeError("NOT_IMPLEMENTED")

    monkeypatch.setattr(FakeDevice5, "registerEventListener", refuse)
    install(monkeypatch, make_roypy(generation="5", frames=2))
    with open_camera(royale()) as cam:
        cam.start()
        assert frames_from(cam, 2, timeout=5.0)
        assert "NOT_IMPLEMENTED" in cam.status().details["unplug_detection"]


def test_a_roypy_without_numpy_streams_a_point_at_a_time_and_says_so(monkeypatch):
    """npoints() raises in a build without numpy: found out once, then per point."""
    install(monkeypatch, make_roypy(generation="5", numpy_support=False, frames=3))
    cam = open_camera(royale())
    try:
        cam.start()
        frames = frames_from(cam, 3, timeout=30.0)
        status = cam.status()
        events = cam.poll_events()
    finally:
        cam.close()
    assert [f.index for f in frames] == [0, 1, 2] and status.errors == 0
    for k, f in enumerate(frames):
        np.testing.assert_allclose(f.xyz[1:, :, 2], 1.0 + k / 100, rtol=1e-6)
        assert f.gray[5, 5] == 300 + k and f.confidence[5, 5] == 200
    path = status.details["frame_path"]
    assert path.startswith("getX(i)") and "without numpy" in path
    assert cam.details["frame_path"] == path  # the recording's camera_details
    assert [e.kind for e in events].count("frame_path") == 1
    from capture.live.preflight import device_item

    assert f"frames via {path}" in device_item("camera", status).summary


def test_frames_are_copied_out_of_the_sdk_buffer(roypy):
    cam = open_camera(royale())
    try:
        cam.start()
        frames = frames_from(cam, 5)
        device = roypy.devices[0]
    finally:
        cam.close()
    assert [f.index for f in frames] == [0, 1, 2, 3, 4]
    for k, f in enumerate(frames):  # the SDK overwrote its buffer after each callback
        assert f.xyz.dtype == np.float32 and f.xyz.shape == (H, W, 3)
        np.testing.assert_allclose(f.xyz[1:, :, 2], 1.0 + k / 100)
        assert f.gray.dtype == np.uint16 and f.gray[5, 5] == 300 + k
        assert f.confidence.dtype == np.uint8 and f.confidence[5, 5] == 200
        assert np.all(f.confidence[0] == 0) and np.all(f.xyz[0] == 0)  # invalid: xyz 0
    # the camera's timestamps (us), mapped onto the session clock by the smallest
    # host-minus-device offset seen so far: one offset that only ever moves earlier, and no
    # frame stamped after it reached the host (bounds by state, not by this host's timing)
    mapped = np.array([f.device_time_ns for f in frames]) - np.array(device.stamps_us) * 1000
    assert np.all(np.diff(mapped) <= 0)
    assert all(f.host_time_ns >= f.device_time_ns for f in frames)
    assert not device.capturing.is_set()  # stopCapture was called


def test_five_channel_points_of_royale5(monkeypatch):
    install(monkeypatch, make_roypy(channels=5, frames=2))
    cam = open_camera(royale())
    try:
        cam.start()
        f = frames_from(cam, 2)[1]
    finally:
        cam.close()
    assert f.gray[5, 5] == 301 and f.confidence[5, 5] == 200


@pytest.mark.realtime
def test_a_slow_consumer_costs_counted_frames_not_a_blocked_sdk(monkeypatch):
    sdk = make_roypy(frames=30)
    install(monkeypatch, sdk)
    cam = open_camera(royale(buffer_frames=4))
    try:
        cam.start()
        device = sdk.devices[0]
        deadline = time.monotonic() + 5.0
        while len(device.callback_s) < 30 and time.monotonic() < deadline:  # nobody receives
            time.sleep(0.01)
        status = cam.status()
    finally:
        cam.close()
    assert status.delivered == 30 and status.dropped == 26


def test_a_camera_id_that_is_not_connected_lists_the_connected(roypy):
    with pytest.raises(DeviceNotAvailable, match="'nope' is not connected.*0005-1203"):
        open_camera(royale(camera_id="nope"))


def test_no_camera_connected(monkeypatch):
    install(monkeypatch, make_roypy(cameras=()))
    with pytest.raises(DeviceNotAvailable, match="no pmd camera connected"):
        open_camera(royale())


def test_a_use_case_the_camera_refuses_is_an_init_error(roypy):
    with pytest.raises(DeviceInitError, match="MODE_9_99FPS"):
        open_camera(royale(use_case="MODE_9_99FPS"))


# ---- a recording ---------------------------------------------------------------------------


def test_plays_an_rrf_recording_through_the_sdk(generation, tmp_path):
    """4.x/5.x: asReplay, loop(False), frameCount; 3.x has none: the frames stopping for a
    second (on the scripted session clock) ends the playback."""
    clock = SessionClock()
    roypy = generation(frames=3)
    rrf = tmp_path / "stairs.rrf"
    rrf.write_bytes(b"\0")
    cam = RoyaleCamera(royale(camera_id=str(rrf)), clock=clock)
    with cam:
        device = roypy.devices[0]
        assert device.source == str(rrf) and device.use_case is None  # no use case on replay
        if roypy.generation != "3":
            assert roypy.replay_loop is False
        cam.start()
        frames = frames_from(cam, 3, timeout=60.0)
        if roypy.generation != "3":  # frameCount: the SDK's thread ends it after frame 3
            wait_for(lambda: cam.status().state == "stopped", what="the end of the recording")
        advance(cam, clock, 1.2)  # more than a second without a frame
        state = cam.status().state
    assert len(frames) == 3 and state == "stopped"
    events = [e for e in cam.poll_events() if e.kind == "end_of_recording"]
    assert len(events) == 1 and "after 3 frames" in events[0].message
    assert "lost" not in [e.kind for e in cam.poll_events()]


def test_a_missing_recording_is_named(roypy, tmp_path):
    with pytest.raises(DeviceNotAvailable, match="recording not found: .*gone.rrf"):
        open_camera(royale(camera_id=str(tmp_path / "gone.rrf")))


def test_device_timestamps_as_int_or_chrono_duration_or_arrival_time():
    from devices.royale import device_time_us

    class Duration:
        def count(self):
            return 1234

    assert device_time_us(types.SimpleNamespace(timeStamp=99)) == 99
    assert device_time_us(types.SimpleNamespace(timeStamp=Duration())) == 1234
    assert device_time_us(types.SimpleNamespace(timeStamp=object())) is None


def test_the_rate_comes_from_the_cameras_timestamps_not_arrivals(roypy):
    """A host stall delays onNewData, not the camera's timestamps: the measured rate stays
    the camera's 15 Hz while the backlog comes in (scripted times, no wall clock)."""
    from tests.devices.test_camera import StepClock, stalled_arrivals

    clock = StepClock()
    cam = open_camera(royale(), clock=clock)
    rates = []
    try:
        for k, (device, arrival) in enumerate(stalled_arrivals()):
            clock.t = arrival
            stamp_us = device // 1000 - 5_000_000  # the camera's clock: 5 s behind
            cam._on_data(roypy.DepthData(sdk_points(k, roypy.channels), stamp_us))
            if k >= 30:  # from the stall's end on
                rates.append(cam.status().measured_rate_hz)
    finally:
        cam.close()
    assert min(rates) == pytest.approx(15.0, rel=0.01)
    assert max(rates) == pytest.approx(15.0, rel=0.01)
