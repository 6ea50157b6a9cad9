"""pmd depth cameras (pico flexx) through the royale SDK's Python binding, `roypy`.

roypy is not on the package registry: install pmd's royale SDK and put its `python` folder
on PYTHONPATH. It is imported as pmd's samples do: `from roypypack import roypy` (the
packaged binding), else `import roypy`. Without either, choosing this backend fails with
one line saying so.

    [camera]
    backend = "royale"
    camera_id = ""      # empty: the first connected camera; a camera id; or a .rrf recording
    use_case = ""       # empty: the use case whose frame rate is nearest to fps
    fps = 15.0          # the paper ran at 15 fps (MODE_9_15FPS_700 on a pico flexx)

The SDK calls `onNewData` on its own thread and reuses its buffers: the listener copies
the points out and returns at once (a slow callback makes the SDK drop frames). Invalid
pixels (depthConfidence 0) get xyz 0. Device timestamps (microseconds) are mapped onto
the session clock with the smallest host-minus-device offset seen so far: the frame that
arrived with the least delay fixes the mapping.

The binding differs between SDK generations and builds, and the backend takes what each
offers (pmd's public interface file, roypy.i, and its samples):

- frames: `npoints()` (one numpy array a frame) when it works; a binding built without
  numpy support has `npoints()` but it raises ("Roypy was compiled without numpy
  support!"): the first frame finds that out once, and frames are read a point at a time
  from then on, with `points()` (one C-level getter a point) or the per-index getters
  (`getX(i)` ...). `details["frame_path"]` (shown by `walkcap check`, kept in the
  recording's metadata) says which path is in use.
- lens: `getLensParameters()`, a map of cx, cy, fx, fy, p1, p2, k1, k2, k3 in every public
  binding. Any failure costs only the intrinsics: nominal pico flexx values, a warning, and
  `details["intrinsics"]` (in the recording's metadata) says which were used.
- unplug: the event listener as pmd's samples make it: a subclass of
  `roypy.PythonEventListener` whose `onEventPython(severity, description, type)` sees
  `EventType_ROYALE_DEVICE_DISCONNECTED`. `roypy.IEventListener` itself has no director
  (SWIG: "No constructor defined - class is abstract"), so it is tried only where
  PythonEventListener is missing. A binding without a listener that can be made (a warning,
  never a failed start) is watched through `isConnected()`. Either says the camera is lost
  at the camera layer's next check; a camera that says neither is lost by the camera
  layer's rule for every backend, `[camera] lost_after_s` without a frame. The camera layer
  reopens it (`_restart`: the same camera id again) until frames come.
  `details["unplug_detection"]` says which.
- .rrf playback: `asReplay()` with `loop(False)` and `frameCount()` where the binding has
  them; without them playback has ended when frames stop coming for a second.

What is royale's here reaches the camera layer through its hooks: `_watch_device` (an
unplug event, `isConnected()`, the end of a playback) and `_restart`; stalls, loss after
`lost_after_s`, reopening and the events are `devices.camera.Camera`'s.
"""

from __future__ import annotations

import logging
import operator
import re
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from devices.camera import Camera
from devices.clock import now_ns
from devices.errors import DeviceInitError, DeviceNotAvailable, DeviceOperationError
from devices.frames import CameraGeometry, DepthFrame

log = logging.getLogger(__name__)

INSTALL_HINT = (
    "the royale backend needs the royale SDK's Python binding (roypy, or roypypack.roypy): "
    "install pmd's royale SDK and add its python folder to PYTHONPATH "
    "(e.g. export PYTHONPATH=/opt/royale/python:$PYTHONPATH)"
)


def import_roypy():
    """The binding as pmd's samples import it: the package first, then the module."""
    try:
        from roypypack import roypy  # a packaged installation

        return roypy
    except ImportError:
        pass
    try:
        import roypy  # the SDK's python folder on PYTHONPATH
    except ImportError:
        raise DeviceNotAvailable(INSTALL_HINT) from None
    return roypy


def use_case_fps(name: str) -> float | None:
    """Frame rate in a use case name such as MODE_9_15FPS_700 (None when it has none)."""
    m = re.search(r"(\d+(?:\.\d+)?)\s*FPS", name, re.IGNORECASE)
    return float(m.group(1)) if m else None


def choose_use_case(available: list[str], fps: float, requested: str = "") -> str:
    """The requested use case, else the one nearest to fps (ties: the faster one)."""
    if not available:
        raise DeviceInitError("the camera offers no use cases")
    if requested:
        if requested not in available:
            raise DeviceInitError(
                f"use case {requested!r} is not offered by the camera "
                f"(offered: {', '.join(available)})"
            )
        return requested
    rated = [(abs(f - fps), -f, name) for name in available if (f := use_case_fps(name))]
    return min(rated)[2] if rated else available[0]


def lens_geometry(
    lens: Any, width: int, height: int, name: str = "", serial: str = ""
) -> tuple[CameraGeometry, str]:
    """(geometry, "device" or "nominal: why") from what getLensParameters gave (royale 3/4
    or royale 5 key names); a lens this does not understand gives the nominal pico flexx
    intrinsics."""
    source = "device"
    try:
        if hasattr(lens, "asdict"):  # a SWIG map (LensParamMap)
            lens = lens.asdict()
        fx, fy, cx, cy = (float(lens[k]) for k in ("fx", "fy", "cx", "cy"))
    except (KeyError, TypeError, ValueError, AttributeError) as e:
        log.warning("lens parameters not understood (%s): nominal pico flexx intrinsics", e)
        source = f"nominal: lens parameters not understood ({e})"
        d = CameraGeometry()
        fx, fy, cx, cy = d.fx, d.fy, d.cx, d.cy
    geometry = CameraGeometry(
        width=width,
        height=height,
        fx=fx,
        fy=fy,
        cx=cx,
        cy=cy,
        name=name or "pmd camera",
        serial=serial,
    )
    return geometry, source


def read_lens(roypy, device) -> tuple[Any, str]:
    """getLensParameters() (the binding's no-argument map): (lens, "") or (None, why)."""
    try:
        return device.getLensParameters(), ""
    except Exception as e:  # roypy raises RuntimeError with the SDK's status text
        return None, f"getLensParameters failed: {e}"


_POINT_FIELDS = operator.attrgetter("x", "y", "z", "grayValue", "depthConfidence")


def frame_path(data: Any) -> str:
    """How depth_data_arrays reads this binding's DepthData (npoints() when it has it; see
    choose_frame_path for a binding whose npoints() does not work)."""
    if hasattr(data, "npoints"):
        return "npoints"
    return point_path(data)


def point_path(data: Any) -> str:
    """The per-point path: points() where the binding has it, else the getters."""
    return "points" if hasattr(data, "points") else "getters"


FRAME_PATHS = {
    "npoints": "npoints (numpy)",
    "points": "points() a point at a time",
    "getters": "getX(i)... a point at a time",
}


def choose_frame_path(data: Any) -> tuple[str, str]:
    """(path, why) for this binding, decided on its first frame: npoints() if it works, else
    (a roypy built without numpy support) the per-point path."""
    path = frame_path(data)
    if path != "npoints":
        return path, ""
    try:
        data.npoints()
    except Exception as e:  # "Roypy was compiled without numpy support!"
        return point_path(data), f"npoints() failed ({e})"
    return path, ""


def depth_data_arrays(
    data: Any, path: str | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(xyz float32 (h, w, 3), confidence uint8, gray uint16) copied out of royale DepthData.

    `npoints()` gives x, y, z, noise, grayValue, depthConfidence per pixel (royale 4) or
    x, y, z, grayValue, depthConfidence (royale 5); royale 3 has `points()`, a vector of
    DepthPoint read with one C-level getter a point (the fastest path it offers), and
    per-index getters, five Python calls a pixel, as the last resort.
    """
    h, w = int(data.height), int(data.width)
    path = path or frame_path(data)
    if path == "npoints":
        points = np.asarray(data.npoints(), dtype=np.float32).reshape(h, w, -1)
        if points.shape[-1] < 5:
            raise DeviceOperationError(f"unexpected royale point layout {points.shape}")
        gray_channel = 4 if points.shape[-1] >= 6 else 3
        xyz = points[..., :3].copy()
        gray = points[..., gray_channel]
        confidence = points[..., -1]
    else:
        if path == "points":
            rows = list(map(_POINT_FIELDS, data.points()))
        else:
            rows = [
                (
                    data.getX(i),
                    data.getY(i),
                    data.getZ(i),
                    data.getGrayValue(i),
                    data.getDepthConfidence(i),
                )
                for i in range(h * w)
            ]
        points = np.array(rows, dtype=np.float32).reshape(h, w, 5)
        xyz = points[..., :3].copy()
        gray = points[..., 3]
        confidence = points[..., 4]
    confidence = np.clip(confidence, 0, 255).astype(np.uint8)
    xyz[confidence == 0] = 0.0  # royale already does this; make sure of it
    return xyz, confidence, np.clip(gray, 0, 65535).astype(np.uint16)


def _make_listener(roypy, on_data: Callable[[Any], None]):
    class _Listener(roypy.IDepthDataListener):
        def onNewData(self, data):  # the SDK's thread: copy out, never raise into C++
            try:
                on_data(data)
            except Exception:
                log.exception("royale frame")

    return _Listener()


# royale::EventType::ROYALE_DEVICE_DISCONNECTED, the second of the enum (IEvent.hpp); SWIG
# exports it as EventType_ROYALE_DEVICE_DISCONNECTED.
DEVICE_DISCONNECTED = 1


def make_event_listener(roypy, on_lost: Callable[[str], None]) -> tuple[Any, str]:
    """(listener, "") reporting ROYALE_DEVICE_DISCONNECTED, or (None, why none was made).

    As pmd's samples: a subclass of PythonEventListener (a SWIG director whose C++ onEvent
    calls onEventPython(severity, description, type)). IEventListener has no director in
    pmd's interface file: making one raises ("class is abstract"); it is tried only where
    PythonEventListener is missing."""
    disconnected = int(getattr(roypy, "EventType_ROYALE_DEVICE_DISCONNECTED", DEVICE_DISCONNECTED))

    def seen(kind: Any, text: Any) -> None:  # the SDK's thread: never raise into C++
        try:
            if int(kind) == disconnected:
                on_lost(str(text) or "USB device disconnected")
        except Exception:
            log.exception("royale event")

    tried = []
    python_base = getattr(roypy, "PythonEventListener", None)
    if python_base is not None:

        class _PythonEvents(python_base):
            def __init__(self):
                python_base.__init__(self)

            def onEventPython(self, severity, description, type):  # noqa: A002 (pmd's name)
                seen(type, description)

        try:
            return _PythonEvents(), ""
        except Exception as e:
            tried.append(f"PythonEventListener: {e}")
    base = getattr(roypy, "IEventListener", None)
    if base is not None:

        class _Events(base):
            def __init__(self):
                base.__init__(self)

            def onEvent(self, event):
                try:
                    seen(event.type(), event.describe())
                except Exception:
                    log.exception("royale event")

        try:
            return _Events(), ""
        except Exception as e:  # "No constructor defined - class is abstract"
            tried.append(f"IEventListener: {e}")
    return None, "; ".join(tried) or "this roypy has no event listener"


def device_time_us(data: Any) -> int | None:
    """DepthData.timeStamp in microseconds: an int in the bindings, a std::chrono duration
    (`.count()`) where SWIG leaves it wrapped; None when neither reads."""
    stamp = getattr(data, "timeStamp", None)
    for read in (int, lambda s: int(s.count())):
        try:
            return read(stamp)
        except (TypeError, ValueError, AttributeError):
            continue
    return None


RECORDING_END_S = 1.0  # a playback without frameCount(): ended when frames stop this long


class RoyaleCamera(Camera):
    backend = "royale"

    def __init__(
        self, config=None, *, source: str | None = None, clock: Callable[[], int] = now_ns
    ) -> None:
        super().__init__(config, clock=clock)
        self.source = self.config.camera_id if source is None else source
        self._roypy = None
        self._manager = None
        self._device = None
        self._listener = None
        self._recording_frames = 0  # a .rrf playback ends after this many (0: unknown)
        self._offset_ns: int | None = None
        self._index = 0
        self._serial_id = ""
        self._use_case = ""
        self._events_listener = None
        self._lost_reason: str | None = None  # set by the event listener (SDK thread)
        self._warned_stamp = False
        self._frame_path: str | None = None  # decided on the first frame
        self._events_registered = False
        self._warned_events = False

    @property
    def is_recording(self) -> bool:
        return self.source.lower().endswith(".rrf")

    def _sdk(self, what: str, call, *args):
        try:
            return call(*args)
        except Exception as e:  # roypy raises RuntimeError with the SDK's status text
            raise DeviceInitError(f"royale: {what} failed: {e}") from None

    def _open(self) -> None:
        roypy = import_roypy()
        self._roypy = roypy
        self._manager = roypy.CameraManager()
        self._connect()

    def _connect(self) -> None:
        """Create, initialise and configure the camera (after a loss: the same camera id)."""
        if self.is_recording:
            if not Path(self.source).is_file():
                raise DeviceNotAvailable(f"royale recording not found: {self.source}")
            device = self._sdk("opening the recording", self._manager.createCamera, self.source)
        else:
            connected = [str(c) for c in self._manager.getConnectedCameraList()]
            if not connected:
                raise DeviceNotAvailable(
                    "no pmd camera connected (check the USB cable and the royale SDK's udev rules)"
                )
            wanted = self.source or self._serial_id  # the camera streaming before a loss
            if wanted and wanted not in connected:
                raise DeviceNotAvailable(
                    f"pmd camera {wanted!r} is not connected (connected: {', '.join(connected)})"
                )
            device = self._sdk(
                "opening the camera", self._manager.createCamera, wanted or connected[0]
            )
        if device is None:
            raise DeviceNotAvailable(f"royale could not open {self.source or 'the camera'}")
        self._device = device
        self._sdk("initialize", device.initialize)
        use_case = ""
        if self.is_recording:
            replay = getattr(device, "asReplay", None)
            if replay is not None:
                replay = self._sdk("opening the replay", replay)
                if hasattr(replay, "loop"):
                    replay.loop(False)
                if hasattr(replay, "frameCount"):
                    self._recording_frames = int(replay.frameCount())
        else:
            use_case = choose_use_case(
                [str(u) for u in device.getUseCases()], self.config.fps, self.config.use_case
            )
            self._sdk(f"setUseCase({use_case})", device.setUseCase, use_case)
        name = str(self._sdk("getCameraName", device.getCameraName))
        serial = str(self._sdk("getId", device.getId))
        width = int(getattr(device, "getMaxSensorWidth", lambda: 224)())
        height = int(getattr(device, "getMaxSensorHeight", lambda: 171)())
        lens, why = read_lens(self._roypy, device)
        if lens is None:
            log.warning("royale: %s: nominal pico flexx intrinsics", why)
            self.geometry = replace(CameraGeometry(), width=width, height=height, serial=serial)
            self.geometry = replace(self.geometry, name=name or self.geometry.name)
            intrinsics = f"nominal: {why}"
        else:
            self.geometry, intrinsics = lens_geometry(lens, width, height, name, serial)
        self._serial_id = serial
        self._use_case = use_case
        # update, not replace: after a reopen the frame path and unplug detection stay
        self.details.update(
            {
                "camera": name,
                "id": serial,
                "use_case": use_case,
                "source": self.source or serial,
                "intrinsics": intrinsics,
                "roypy": str(
                    getattr(self._roypy, "__version__", "") or _roypy_version(self._roypy)
                ),
            }
        )

    def _start(self) -> None:
        self._index = 0
        self._offset_ns = None
        self._lost_reason = None
        self._capture()

    def _capture(self) -> None:
        """Listeners on, capture started (at start and after a reconnect)."""
        device = self._device
        self._listener = _make_listener(self._roypy, self._on_data)
        self._sdk("registerDataListener", device.registerDataListener, self._listener)
        self._events_listener, why = make_event_listener(self._roypy, self._on_lost_event)
        self._events_registered = False
        if self._events_listener is not None:
            register = getattr(device, "registerEventListener", None)
            try:
                if register is None:
                    raise AttributeError("the camera has no registerEventListener")
                register(self._events_listener)
                self._events_registered = True
            except Exception as e:  # unplug detection falls back to polling, never a failure
                why = f"registerEventListener failed: {e}"
                self._events_listener = None
        if self._events_registered:
            self.details["unplug_detection"] = "event listener"
        else:
            self.details["unplug_detection"] = f"isConnected and silence ({why})"
            if not self._warned_events and "no event listener" not in why:
                self._warned_events = True
                log.warning("royale: no event listener (%s): polling isConnected()", why)
                self._event("no_events", f"camera events unavailable ({why}): polling isConnected")
        self._sdk("startCapture", device.startCapture)

    def _choose_frame_path(self, data) -> None:
        """Once, on the first frame: npoints() if it works, else the per-point path."""
        try:
            path, why = choose_frame_path(data)
        except Exception as e:  # a DepthData no path reads: each frame says so as bad
            log.warning("royale: frame layout not understood: %s", e)
            path, why = frame_path(data), ""
        self._frame_path = path
        self.details["frame_path"] = _frame_path_text(path, why)
        if why:
            log.warning("royale: %s: frames read a point at a time (slower)", why)
            text = f"roypy without numpy support: frames via {FRAME_PATHS[path]}"
            self._event("frame_path", text)

    def _on_lost_event(self, text: str) -> None:
        self._lost_reason = text  # the camera layer's watchdog acts on it (off the SDK's thread)

    def _watch_device(self, silent_s: float) -> str | None:
        """What royale tells beyond silence: an unplug event or isConnected() False (lost
        now); a playback without frameCount() whose frames stopped (ended)."""
        if self.is_recording:
            if silent_s > RECORDING_END_S and not self._recording_frames and self._index:
                self._end_of_recording()
            return None
        reason = self._lost_reason or self._disconnected()
        if reason and self._lost_reason:  # the SDK's own words, if they came meanwhile
            reason = self._lost_reason
        if reason is None:
            return None
        self._lost_reason = None
        return f"camera lost: {reason}; reopening when it is connected"

    def _disconnected(self) -> str | None:
        is_connected = getattr(self._device, "isConnected", None)
        try:
            if is_connected is not None and not is_connected():
                return "camera disconnected"
        except Exception as e:  # a vanished device may raise instead
            return f"camera disconnected ({e})"
        return None

    def _restart(self) -> None:
        """The lost camera's capture stopped, the same camera opened again: the manager is
        kept, a camera not connected yet raises DeviceNotAvailable (retried)."""
        self._stop()
        self._device = None
        self._connect()
        self._start()

    def _stop(self) -> None:
        device = self._device
        if device is None:
            return
        try:
            device.stopCapture()
            if hasattr(device, "unregisterDataListener"):
                device.unregisterDataListener()
            if self._events_registered and hasattr(device, "unregisterEventListener"):
                device.unregisterEventListener()
        except Exception as e:  # an unplugged camera cannot stop: nothing left to do
            log.warning("royale stopCapture: %s", e)
        self._listener = None
        self._events_listener = None
        self._events_registered = False

    def _close(self) -> None:
        self._device = None
        self._manager = None

    def _on_data(self, data) -> None:
        host = self._now()
        if self._frame_path is None:
            self._choose_frame_path(data)
        try:
            xyz, confidence, gray = depth_data_arrays(data, self._frame_path)
        except Exception as e:
            self._count_error()
            self._event("bad_frame", f"royale frame not understood: {e}")
            return
        stamp_us = device_time_us(data)
        if stamp_us is None:  # a binding whose timestamp Python cannot read: arrival time
            stamp_us = host // 1000
            if not self._warned_stamp:
                self._warned_stamp = True
                self._event("no_device_time", "royale timestamps unreadable: arrival times used")
        device_ns = stamp_us * 1000
        offset = host - device_ns
        if self._offset_ns is None or offset < self._offset_ns:
            self._offset_ns = offset
        geometry = self.geometry
        if (geometry.height, geometry.width) != confidence.shape:
            geometry = self.geometry = replace(
                geometry, height=confidence.shape[0], width=confidence.shape[1]
            )
        frame = DepthFrame(
            self._index, device_ns + self._offset_ns, host, xyz, confidence, gray, geometry
        )
        self._index += 1
        self._deliver(frame)
        if self._recording_frames and self._index >= self._recording_frames:
            self._end_of_recording()

    def _end_of_recording(self) -> None:
        self._finish(
            "end_of_recording", f"end of {Path(self.source).name} after {self._index} frames"
        )


def _frame_path_text(path: str, why: str) -> str:
    text = FRAME_PATHS[path]
    return f"{text} ({why}: roypy without numpy support)" if why else text


def _roypy_version(roypy) -> str:
    get = getattr(roypy, "getVersionString", None)
    try:
        return str(get()) if get else "unknown"
    except Exception:
        return "unknown"
