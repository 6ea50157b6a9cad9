"""The royale backend against stand-ins shaped like pmd's roypy binding, one per generation.

The shapes follow pmd's public SWIG interface files (roypy.i) and samples; a stand-in has
no name the binding lacks, and says where the shape is not known from those files:

- 3.x and 4.x (the interface file without events): DepthData with `points()` (DepthPoint
  x, y, z, noise, grayValue, depthConfidence) and the per-index getters `getX(i)`, `getY`,
  `getZ`, `getNoise`, `getGrayValue`, `getDepthConfidence`, `getNumPoints()`;
  `getLensParameters()` returns a LensParamMap (cx, cy, fx, fy, p1, p2, k1, k2, k3); no
  IEvent, so no event listener of any kind. The 4.x stand-in adds `npoints()` with six
  channels (x, y, z, noise, gray, confidence) as a numpy build of 4.x gives it: the
  six-channel layout is taken from pmd's 4.x samples' indexing, not from an interface file.
  The 3.x stand-in has no `asReplay()` (the interface file seen has it; leaving it out
  exercises a binding without it).
- 5.x (the interface file with PythonEventListener.hpp): DepthData with the C++ getters
  (`getX(i)` ... `getGrayValue(i)`, `getDepthConfidence(i)`) and `npoints()`, five channels
  (x, y, z, gray, confidence) with numpy; without numpy `npoints()` raises "Roypy was
  compiled without numpy support!". `IEventListener` is abstract (no director: making one
  raises "No constructor defined - class is abstract"); `PythonEventListener` is a director
  whose C++ `onEvent` calls `onEventPython(severity, description, type)`; the event types
  are `EventType_ROYALE_*` (ROYALE_DEVICE_DISCONNECTED = 1).
"""

import sys
import threading
import time
import types

import numpy as np
import pytest

from devices.camera import open_camera
from devices.config import CameraConfig
from devices.errors import DeviceInitError, DeviceNotAvailable
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
LENS = {"cx": 113.0, "cy": 84.5, "fx": 210.0, "fy": 211.0, "p1": 0.0, "p2": 0.0}
LENS.update({"k1": 0.1, "k2": 0.0, "k3": 0.0})


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


class LensParamMap:
    """SWIG's std::map<std::string, float> (%template(LensParamMap)): [], keys, items,
    asdict."""

    def __init__(self, values):
        self._values = dict(values)

    def __getitem__(self, key):
        return self._values[key]

    def __contains__(self, key):
        return key in self._values

    def keys(self):
        return list(self._values)

    def items(self):
        return list(self._values.items())

    def asdict(self):
        return dict(self._values)


class DepthPoint:
    """royale DepthPoint (3.x/4.x interface): x, y, z, noise, grayValue, depthConfidence."""

    __slots__ = ("_row",)
    x, y, z, noise, grayValue, depthConfidence = (_swig_property(i) for i in range(6))

    def __init__(self, row):
        self._row = row


class DepthData3:
    """3.x/4.x DepthData without numpy: points() (a vector of DepthPoint) and per-index
    getters, all %extend'ed in the interface file."""

    def __init__(self, points, time_stamp_us):
        self.width, self.height = W, H
        self.timeStamp = time_stamp_us
        self._flat = points.reshape(-1, points.shape[-1])

    def points(self):
        return [DepthPoint(row) for row in self._flat.tolist()]

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
    """4.x built with numpy: the same plus npoints() (h, w, 6), which the backend prefers."""

    def __init__(self, points, time_stamp_us):
        super().__init__(points, time_stamp_us)
        self._points = points

    def npoints(self):
        return self._points


class DepthData5:
    """5.x DepthData: the C++ getters (hasDepth, getX(i) ... as fastPoints reads them) and
    npoints() (h, w, 5) with numpy; without numpy npoints() raises."""

    numpy = True

    def __init__(self, points, time_stamp_us):
        self.width, self.height = W, H
        self.timeStamp = time_stamp_us
        self.hasDepth = True
        self._points = points
        self._flat = points.reshape(-1, points.shape[-1])

    def npoints(self):
        if not self.numpy:
            print("Roypy was compiled without numpy support!")
            raise RuntimeError("Roypy was compiled without numpy support!")
        return self._points

    def getX(self, idx):
        return float(self._flat[idx, 0])

    def getY(self, idx):
        return float(self._flat[idx, 1])

    def getZ(self, idx):
        return float(self._flat[idx, 2])

    def getGrayValue(self, idx):
        return int(self._flat[idx, 3])

    def getDepthConfidence(self, idx):
        return int(self._flat[idx, 4])


class DepthData5NoNumpy(DepthData5):
    numpy = False


class Event5:
    """An IEvent as the C++ side hands it to onEvent."""

    def __init__(self, kind, severity, text):
        self._kind, self._severity, self._text = kind, severity, text

    def type(self):
        return self._kind

    def severity(self):
        return self._severity

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

    def getLensParameters(self):  # %extend'ed: the no-argument map in every interface file
        return LensParamMap(LENS)

    def registerDataListener(self, listener):
        assert isinstance(listener, self.sdk.IDepthDataListener)
        self.listener = listener

    def unregisterDataListener(self):
        self.listener = None

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
            listener = self.listener  # unregistered meanwhile: the SDK calls no more
            if listener is None:
                return
            t0 = time.perf_counter()
            listener.onNewData(data)
            self.callback_s.append(time.perf_counter() - t0)
            time.sleep(sdk.frame_s)


class FakeDevice3(FakeDevice):
    """3.x: no asReplay in this stand-in (see the module docstring)."""


class FakeDevice4(FakeDevice):
    def asReplay(self):
        sdk = self.sdk

        class Replay:
            def loop(self, on):
                sdk.replay_loop = on

            def frameCount(self):
                return sdk.frames

        return Replay()


class FakeDevice5(FakeDevice4):
    """5.x: events (IEventListener.hpp is in the interface file)."""

    def registerEventListener(self, listener):
        assert isinstance(listener, self.sdk.IEventListener)
        self.event_listener = listener

    def unregisterEventListener(self):
        self.event_listener = None


def make_roypy(
    cameras=("0005-1203-0034-2011",),
    frames=5,
    channels=None,
    generation="4",
    numpy_support=True,
    python_event_listener=True,
):
    """A stand-in roypy shaped like one binding generation (3.x, 4.x or 5.x); 5.x also
    without numpy support, or without PythonEventListener (a binding whose only event
    listener is the abstract IEventListener: a shape not known from pmd's files, kept to
    show that a listener which cannot be made costs only the events)."""
    sdk = types.ModuleType("roypy")
    sdk.generation = generation
    sdk.frames = frames
    sdk.channels = channels or {"3": 6, "4": 6, "5": 5}[generation]
    sdk.frame_s = 0.002 if generation != "3" else 0.0
    sdk.DepthData = {"3": DepthData3, "4": DepthData4, "5": DepthData5}[generation]
    if generation == "5" and not numpy_support:
        sdk.DepthData = DepthData5NoNumpy
    sdk.devices = []
    sdk.connected = list(cameras)
    device_class = {"3": FakeDevice3, "4": FakeDevice4, "5": FakeDevice5}[generation]

    class IDepthDataListener:  # a SWIG director
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
        if device.event_listener is not None:  # the C++ side calls onEvent
            device.event_listener.onEvent(
                Event5(
                    sdk.EventType_ROYALE_DEVICE_DISCONNECTED,
                    sdk.EventSeverity_ROYALE_FATAL,
                    "USB Device disconnected.",
                )
            )
        device.connected = False  # after the event: a poll then finds the event's words too
        sdk.connected = []

    def replug():
        sdk.connected = list(cameras)

    sdk.IDepthDataListener = IDepthDataListener
    sdk.CameraManager = CameraManager
    sdk.unplug, sdk.replug = unplug, replug
    sdk.LensParamMap = LensParamMap
    sdk.getVersionString = lambda: {"3": "3.21.1.70", "4": "4.24.0.1201", "5": "5.12.0.3089"}[
        generation
    ]
    if generation == "5":

        class IEventListener:  # no director in pmd's interface file
            def __init__(self, *args, **kwargs):
                raise AttributeError("No constructor defined - class is abstract")

        sdk.IEventListener = IEventListener
        if python_event_listener:

            class PythonEventListener(IEventListener):  # a director
                def __init__(self):
                    pass

                def onEvent(self, event):  # PythonEventListener.hpp, on the C++ side
                    self.onEventPython(event.severity(), event.describe(), event.type())

            sdk.PythonEventListener = PythonEventListener
        for i, name in enumerate(
            ("CAPTURE_STREAM", "DEVICE_DISCONNECTED", "OVER_TEMPERATURE", "RAW_FRAME_STATS")
        ):
            setattr(sdk, f"EventType_ROYALE_{name}", i)
        for i, name in enumerate(("INFO", "WARNING", "ERROR", "FATAL")):
            setattr(sdk, f"EventSeverity_ROYALE_{name}", i)
    return sdk


def install(monkeypatch, sdk, packaged=False):
    """The stand-in as `import roypy` finds it, or (packaged) as `from roypypack import
    roypy` does, with no top-level roypy."""
    if packaged:
        package = types.ModuleType("roypypack")
        package.roypy = sdk
        monkeypatch.setitem(sys.modules, "roypypack", package)
        monkeypatch.setitem(sys.modules, "roypypack.roypy", sdk)
        monkeypatch.setitem(sys.modules, "roypy", None)
    else:
        monkeypatch.setitem(sys.modules, "roypypack", None)
        monkeypatch.setitem(sys.modules, "roypy", sdk)
    return sdk


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


@pytest.mark.realtime
def test_unplug_is_reported_and_the_camera_reopened(generation):
    roypy = generation(frames=100_000)
    roypy.frame_s = 0.01
    cam = open_camera(royale())
    try:
        cam.start()
        assert frames_from(cam, 1, timeout=5.0)
        expected = "event listener" if roypy.generation == "5" else "isConnected and silence"
        assert cam.status().details["unplug_detection"].startswith(expected)
        roypy.unplug()
        t0 = time.monotonic()
        while cam.status().state != "lost" and time.monotonic() - t0 < 30:  # a bound only
            time.sleep(0.01)
        assert cam.status().state == "lost"
        if roypy.generation == "5":  # onEventPython saw ROYALE_DEVICE_DISCONNECTED
            assert "USB Device disconnected." in cam.status().message
        roypy.replug()
        t0 = time.monotonic()
        while cam.status().state != "ok" and time.monotonic() - t0 < 30:  # a bound only
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
        deadline = time.monotonic() + 10.0
        while cam.status().state != "lost" and time.monotonic() < deadline:
            time.sleep(0.01)
        assert cam.status().state == "lost"
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


@pytest.mark.realtime
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


@pytest.mark.realtime
def test_without_events_or_is_connected_a_second_of_silence_is_a_lost_camera(monkeypatch):
    monkeypatch.delattr(FakeDevice, "isConnected")
    roypy = make_roypy(generation="4", frames=100_000)
    roypy.frame_s = 0.01
    install(monkeypatch, roypy)
    cam = open_camera(royale())
    try:
        cam.start()
        assert frames_from(cam, 1, timeout=5.0)
        roypy.unplug()
        t0 = time.monotonic()
        while cam.status().state != "lost" and time.monotonic() - t0 < 30:  # a bound only
            time.sleep(0.01)
        assert cam.status().state == "lost"  # after 0.8 s of silence, checked every 0.2 s
        assert "no frame" in cam.status().message
    finally:
        cam.close()


def test_the_rate_comes_from_the_cameras_timestamps_not_arrivals(roypy, monkeypatch):
    """A host stall delays onNewData, not the camera's timestamps: the measured rate stays
    the camera's 15 Hz while the backlog comes in (scripted times, no wall clock)."""
    import devices.royale
    from tests.devices.test_camera import StepClock, stalled_arrivals

    clock = StepClock()
    monkeypatch.setattr(devices.royale, "now_ns", clock)
    cam = open_camera(royale())
    cam._now = clock
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
