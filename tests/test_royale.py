"""The royale backend against a stand-in module shaped like pmd's roypy binding."""

import threading
import time
import types

import numpy as np
import pytest

from devices.camera import open_camera
from devices.config import CameraConfig
from devices.errors import DeviceInitError, DeviceNotAvailable
from devices.frames import CameraGeometry
from devices.royale import RoyaleCamera, choose_use_case, use_case_fps

USE_CASES = [
    "MODE_9_5FPS_2000",
    "MODE_9_10FPS_1000",
    "MODE_9_15FPS_700",
    "MODE_9_25FPS_450",
    "MODE_5_35FPS_600",
    "MODE_5_45FPS_500",
]
W, H = 224, 171


GENERATIONS = ["3", "4", "5"]


def sdk_points(k: int, channels: int = 6) -> np.ndarray:
    """x, y, z, [noise,] gray, confidence of frame k: a wall at 1 + k/100 m, one bad row."""
    p = np.zeros((H, W, channels), np.float32)
    p[..., 0] = np.linspace(-1, 1, W)[None, :]
    p[..., 1] = np.linspace(-0.7, 0.7, H)[:, None]
    p[..., 2] = 1.0 + k / 100
    p[..., -2] = 300 + k  # gray
    p[..., -1] = 200  # confidence
    p[0, :, -1] = 0  # an invalid row; royale leaves xyz as they are here only in this fake
    return p


def _swig_property(i):
    """A SWIG member: a property whose getter is a call (into C++ in the real binding)."""
    return property(lambda self: self._row[i])


class DepthPoint3:
    """royale 3.x DepthPoint: x, y, z, noise, grayValue, depthConfidence."""

    __slots__ = ("_row",)
    x, y, z, noise, grayValue, depthConfidence = (_swig_property(i) for i in range(6))

    def __init__(self, row):
        self._row = row


class DepthData3:
    """royale 3.x DepthData: points() (a vector of DepthPoint) and per-index getters; no
    npoints() (binding A's signatures)."""

    def __init__(self, points, time_stamp_us):
        self.width, self.height = W, H
        self.timeStamp = time_stamp_us
        self._flat = points.reshape(-1, points.shape[-1])

    def points(self):
        return [DepthPoint3(row) for row in self._flat.tolist()]

    def getNumPoints(self):
        return len(self._flat)

    def getX(self, idx):
        return float(self._flat[idx, 0])

    def getY(self, idx):
        return float(self._flat[idx, 1])

    def getZ(self, idx):
        return float(self._flat[idx, 2])

    def getNoise(self, idx):
        return float(self._flat[idx, 3])

    def getGrayValue(self, idx):
        return int(self._flat[idx, 4])

    def getDepthConfidence(self, idx):
        return int(self._flat[idx, 5])


class DepthData4(DepthData3):
    """royale 4.x: the same plus npoints() (h, w, 6), which the backend prefers."""

    def __init__(self, points, time_stamp_us):
        super().__init__(points, time_stamp_us)
        self._points = points

    def npoints(self):
        return self._points


class DepthData5:
    """royale 5.x as pmd's tutorial shows it: npoints() (h, w, 5), no noise channel."""

    def __init__(self, points, time_stamp_us):
        self.width, self.height = W, H
        self.timeStamp = time_stamp_us
        self._points = points

    def npoints(self):
        return self._points


class Event5:
    def __init__(self, kind, text):
        self._kind, self._text = kind, text

    def type(self):
        return self._kind

    def severity(self):
        return 3  # ROYALE_FATAL

    def describe(self):
        return self._text


class FakeDevice:
    def __init__(self, sdk, source):
        self.sdk, self.source = sdk, source
        self.use_case = None
        self.listener = None
        self.event_listener = None
        self.capturing = threading.Event()
        self.initialized = False
        self.connected = True
        self.callback_s = []
        self.stamps_us = []

    def initialize(self):
        self.initialized = True

    def getUseCases(self):
        return list(USE_CASES)

    def setUseCase(self, name):
        if name not in USE_CASES:
            raise RuntimeError("INVALID_VALUE")
        self.use_case = name

    def getCameraName(self):
        return "PICOFLEXX"

    def getId(self):
        return self.source if not self.source.endswith(".rrf") else "0005-1203-0034-2011"

    def getMaxSensorWidth(self):
        return W

    def getMaxSensorHeight(self):
        return H

    def isConnected(self):
        return self.connected

    def registerDataListener(self, listener):
        assert isinstance(listener, self.sdk.IDepthDataListener)
        self.listener = listener

    def unregisterDataListener(self):
        self.listener = None

    def registerEventListener(self, listener):
        self.event_listener = listener

    def startCapture(self):
        self.capturing.set()
        threading.Thread(target=self._produce, daemon=True).start()

    def stopCapture(self):
        self.capturing.clear()

    def _produce(self):
        sdk = self.sdk
        buffer = sdk_points(0, sdk.channels)  # one buffer, reused like the SDK does
        for k in range(sdk.frames):
            if not self.capturing.is_set() or not self.connected:
                return
            buffer[...] = sdk_points(k, sdk.channels)
            stamp = time.monotonic_ns() // 1000 - 5_000_000  # the camera's clock: 5 s behind
            self.stamps_us.append(stamp)
            data = sdk.DepthData(buffer, stamp)
            t0 = time.perf_counter()
            self.listener.onNewData(data)
            self.callback_s.append(time.perf_counter() - t0)
            time.sleep(sdk.frame_s)


class FakeDevice3(FakeDevice):
    def getLensParameters(self, param):  # 3.x: fills the struct it is given
        raise TypeError("in method 'ICameraDevice_getLensParameters', argument 2 of type ...")


class FakeDevice4(FakeDevice):
    def getLensParameters(self):
        if self.sdk.lens_style == "royale5":
            return {"fx": 210.0, "fy": 211.0, "cx": 113.0, "cy": 84.5, "k1": 0.1}
        return {
            "principalPoint": (113.0, 84.5),
            "focalLength": (210.0, 211.0),
            "distortionTangential": (0.0, 0.0),
            "distortionRadial": (0.1, 0.0, 0.0),
        }

    def asReplay(self):
        sdk = self.sdk

        class Replay:
            def loop(self, on):
                sdk.replay_loop = on

            def frameCount(self):
                return sdk.frames

        return Replay()


def make_roypy(
    cameras=("0005-1203-0034-2011",), frames=5, channels=None, lens_style=None, generation="4"
):
    """A stand-in roypy shaped like one binding generation (3.x, 4.x or 5.x)."""
    sdk = types.ModuleType("roypy")
    sdk.generation = generation
    sdk.frames = frames
    sdk.channels = channels or {"3": 6, "4": 6, "5": 5}[generation]
    sdk.lens_style = lens_style or ("royale5" if generation == "5" else "royale4")
    sdk.frame_s = 0.002 if generation != "3" else 0.0
    sdk.DepthData = {"3": DepthData3, "4": DepthData4, "5": DepthData5}[generation]
    sdk.devices = []
    sdk.connected = list(cameras)
    device_class = FakeDevice3 if generation == "3" else FakeDevice4

    class IDepthDataListener:
        def __init__(self):
            pass

    class CameraManager:
        def getConnectedCameraList(self):
            return list(sdk.connected)

        def createCamera(self, source):
            device = device_class(sdk, source)
            sdk.devices.append(device)
            return device

    def unplug():
        device = sdk.devices[-1]
        device.connected = False
        sdk.connected = []
        if device.event_listener is not None:
            device.event_listener.onEvent(
                Event5(sdk.EventType_DEVICE_DISCONNECTED, "USB Device disconnected.")
            )

    def replug():
        sdk.connected = list(cameras)

    sdk.IDepthDataListener = IDepthDataListener
    sdk.CameraManager = CameraManager
    sdk.unplug, sdk.replug = unplug, replug
    if generation == "3":
        sdk.getVersionString = lambda: "3.21.1.70"
    if generation == "5":  # the C++ IEventListener, as a binding would wrap it

        class IEventListener:
            def __init__(self):
                pass

        sdk.IEventListener = IEventListener
        sdk.EventType_DEVICE_DISCONNECTED = 1
    return sdk


@pytest.fixture
def roypy(monkeypatch):
    sdk = make_roypy()
    monkeypatch.setitem(__import__("sys").modules, "roypy", sdk)
    return sdk


@pytest.fixture(params=GENERATIONS, ids=lambda g: f"roypy{g}")
def generation(request, monkeypatch):
    """Install a stand-in of each binding generation in turn; returns a maker."""

    def install(**kw):
        sdk = make_roypy(generation=request.param, **kw)
        monkeypatch.setitem(__import__("sys").modules, "roypy", sdk)
        return sdk

    install.generation = request.param
    return install


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
    monkeypatch.setitem(__import__("sys").modules, "roypy", None)  # import roypy fails
    with pytest.raises(DeviceNotAvailable) as e:
        open_camera(royale())
    message = str(e.value)
    assert "\n" not in message
    assert "roypy" in message and "royale SDK" in message and "PYTHONPATH" in message


def test_the_cli_shows_it_as_one_line(monkeypatch, tmp_path, capsys):
    """What a user sees when a command opens the camera: one line naming the fix."""
    from tui.cli import main

    monkeypatch.setitem(__import__("sys").modules, "roypy", None)
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


def test_royale5_lens_parameters_are_understood(monkeypatch):
    monkeypatch.setitem(__import__("sys").modules, "roypy", make_roypy(lens_style="royale5"))
    with open_camera(royale()) as cam:
        assert (cam.geometry.fx, cam.geometry.cy) == (210.0, 84.5)


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
    intrinsics = cam.status().details["intrinsics"]
    if generation.generation == "3":  # getLensParameters(param), no LensParameters class
        assert intrinsics.startswith("nominal: ") and "LensParameters" in intrinsics
        assert (cam.geometry.fx, cam.geometry.cx) == (CameraGeometry().fx, CameraGeometry().cx)
    else:
        assert intrinsics == "device" and cam.geometry.fx == 210.0


def test_royale3_lens_parameters_through_the_struct_when_the_binding_has_it(monkeypatch):
    sdk = make_roypy(generation="3")

    class LensParameters:
        def __init__(self):
            self.focalLength, self.principalPoint = (0.0, 0.0), (0.0, 0.0)

    def fill(self, param):
        param.focalLength, param.principalPoint = (205.0, 206.0), (112.0, 86.0)

    sdk.LensParameters = LensParameters
    monkeypatch.setattr(FakeDevice3, "getLensParameters", fill)
    monkeypatch.setitem(__import__("sys").modules, "roypy", sdk)
    with open_camera(royale()) as cam:
        assert (cam.geometry.fx, cam.geometry.cy) == (205.0, 86.0)
        assert cam.status().details["intrinsics"] == "device"


def test_a_failing_lens_call_costs_only_the_intrinsics(monkeypatch):
    def broken(self):
        raise RuntimeError("DEVICE_IS_BUSY")

    monkeypatch.setattr(FakeDevice4, "getLensParameters", broken)
    monkeypatch.setitem(__import__("sys").modules, "roypy", make_roypy(generation="4"))
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


def test_unplug_is_reported_within_a_second_and_the_camera_reopened(generation):
    roypy = generation(frames=100_000)
    roypy.frame_s = 0.01
    cam = open_camera(royale())
    try:
        cam.start()
        assert frames_from(cam, 1, timeout=5.0)
        expected = "event listener" if roypy.generation == "5" else "isConnected and silence"
        assert cam.status().details["unplug_detection"] == expected
        roypy.unplug()
        t0 = time.monotonic()
        while cam.status().state != "lost" and time.monotonic() - t0 < 3:
            time.sleep(0.01)
        assert time.monotonic() - t0 < 1.0
        roypy.replug()
        t0 = time.monotonic()
        while cam.status().state != "ok" and time.monotonic() - t0 < 3:
            time.sleep(0.02)
        for _ in range(64):  # frames from before the unplug, still buffered (not new ones)
            if cam.recv(0.0) is None:
                break
        assert frames_from(cam, 1, timeout=5.0), "no frames after the camera came back"
        kinds = [e.kind for e in cam.poll_events()]
    finally:
        cam.close()
    assert "lost" in kinds and "reconnected" in kinds
    assert len(roypy.devices) == 2  # opened again


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
    # the camera's timestamps (us), mapped onto the session clock by one offset
    mapped = np.array([f.device_time_ns for f in frames]) - np.array(device.stamps_us) * 1000
    assert np.ptp(mapped) < 2e6
    assert all(0 <= f.host_time_ns - f.device_time_ns < 5e6 for f in frames)
    assert max(device.callback_s) < 0.05  # onNewData copies and returns
    assert not device.capturing.is_set()  # stopCapture was called


def test_five_channel_points_of_royale5(monkeypatch):
    monkeypatch.setitem(__import__("sys").modules, "roypy", make_roypy(channels=5, frames=2))
    cam = open_camera(royale())
    try:
        cam.start()
        f = frames_from(cam, 2)[1]
    finally:
        cam.close()
    assert f.gray[5, 5] == 301 and f.confidence[5, 5] == 200


def test_a_slow_consumer_costs_counted_frames_not_a_blocked_sdk(monkeypatch):
    sdk = make_roypy(frames=30)
    monkeypatch.setitem(__import__("sys").modules, "roypy", sdk)
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
    monkeypatch.setitem(__import__("sys").modules, "roypy", make_roypy(cameras=()))
    with pytest.raises(DeviceNotAvailable, match="no pmd camera connected"):
        open_camera(royale())


def test_a_use_case_the_camera_refuses_is_an_init_error(roypy):
    with pytest.raises(DeviceInitError, match="MODE_9_99FPS"):
        open_camera(royale(use_case="MODE_9_99FPS"))


# ---- a recording ---------------------------------------------------------------------------


def test_plays_an_rrf_recording_through_the_sdk(generation, tmp_path, monkeypatch):
    """4.x/5.x: asReplay, loop(False), frameCount; 3.x has none: the frames stopping ends
    the playback."""
    import devices.royale

    # The session clock stands still until the frames are in, then moves on: silence is
    # what the test makes it, not what a loaded machine's scheduler happens to leave.
    clock = [time.monotonic_ns()]
    monkeypatch.setattr(devices.royale, "now_ns", lambda: clock[0])
    roypy = generation(frames=3)
    rrf = tmp_path / "stairs.rrf"
    rrf.write_bytes(b"\0")
    cam = RoyaleCamera(royale(camera_id=str(rrf)))
    with cam:
        device = roypy.devices[0]
        assert device.source == str(rrf) and device.use_case is None  # no use case on replay
        if roypy.generation != "3":
            assert roypy.replay_loop is False
        cam.start()
        frames = frames_from(cam, 3, timeout=60.0)
        clock[0] += 2_000_000_000  # two seconds without a frame
        deadline = time.monotonic() + 60
        while cam.status().state != "stopped" and time.monotonic() < deadline:
            time.sleep(0.01)
        state = cam.status().state
    assert len(frames) == 3 and state == "stopped"
    events = [e for e in cam.poll_events() if e.kind == "end_of_recording"]
    assert len(events) == 1 and "after 3 frames" in events[0].message


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


def test_without_events_or_is_connected_a_second_of_silence_is_a_lost_camera(monkeypatch):
    monkeypatch.delattr(FakeDevice, "isConnected")
    roypy = make_roypy(generation="4", frames=100_000)
    roypy.frame_s = 0.01
    monkeypatch.setitem(__import__("sys").modules, "roypy", roypy)
    cam = open_camera(royale())
    try:
        cam.start()
        assert frames_from(cam, 1, timeout=5.0)
        roypy.unplug()
        t0 = time.monotonic()
        while cam.status().state != "lost" and time.monotonic() - t0 < 3:
            time.sleep(0.01)
        assert time.monotonic() - t0 < 1.2  # 0.8 s of silence, checked every 0.2 s
        assert "no frame" in cam.status().message
    finally:
        cam.close()
