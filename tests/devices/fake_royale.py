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


def _swig_getter(column, kind):
    """A %extend'ed per-index getter, getX(i) ...: point i's value in `column`."""
    return lambda self, idx: kind(self._flat[idx, column])


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

    getX, getY, getZ, getNoise = (_swig_getter(i, float) for i in range(4))
    getGrayValue, getDepthConfidence = _swig_getter(4, int), _swig_getter(5, int)


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

    getX, getY, getZ = (_swig_getter(i, float) for i in range(3))
    getGrayValue, getDepthConfidence = _swig_getter(3, int), _swig_getter(4, int)


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
        self.thread: threading.Thread | None = None  # the SDK's capture thread

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
        self.thread = threading.Thread(target=self._produce, daemon=True)
        self.thread.start()

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
