"""pmd depth cameras (pico flexx) through the royale SDK's Python binding, `roypy`.

roypy is not on the package registry: install pmd's royale SDK and put its `python` folder
on PYTHONPATH. Without it, choosing this backend fails with one line saying so.

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
"""

from __future__ import annotations

import logging
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
    "the royale backend needs the royale SDK's Python binding (roypy): install "
    "pmd's royale SDK and add its python folder to PYTHONPATH "
    "(e.g. export PYTHONPATH=/opt/royale/python:$PYTHONPATH)"
)


def import_roypy():
    try:
        import roypy
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


def geometry_from_lens(
    lens: Any, width: int, height: int, name: str = "", serial: str = ""
) -> CameraGeometry:
    """CameraGeometry from getLensParameters() (royale 3/4 or royale 5 key names)."""
    try:
        if "fx" in lens:
            fx, fy, cx, cy = (float(lens[k]) for k in ("fx", "fy", "cx", "cy"))
        else:
            fx, fy = (float(v) for v in lens["focalLength"])
            cx, cy = (float(v) for v in lens["principalPoint"])
    except (KeyError, TypeError, ValueError) as e:
        log.warning("lens parameters not understood (%s): nominal pico flexx intrinsics", e)
        d = CameraGeometry()
        fx, fy, cx, cy = d.fx, d.fy, d.cx, d.cy
    return CameraGeometry(
        width=width,
        height=height,
        fx=fx,
        fy=fy,
        cx=cx,
        cy=cy,
        name=name or "pmd camera",
        serial=serial,
    )


def depth_data_arrays(data: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(xyz float32 (h, w, 3), confidence uint8, gray uint16) copied out of royale DepthData.

    `npoints()` gives x, y, z, noise, grayValue, depthConfidence per pixel (royale 3/4) or
    x, y, z, grayValue, depthConfidence (royale 5); older bindings only have getters.
    """
    h, w = int(data.height), int(data.width)
    if hasattr(data, "npoints"):
        points = np.asarray(data.npoints(), dtype=np.float32).reshape(h, w, -1)
        if points.shape[-1] < 5:
            raise DeviceOperationError(f"unexpected royale point layout {points.shape}")
        gray_channel = 4 if points.shape[-1] >= 6 else 3
        xyz = points[..., :3].copy()
        gray = points[..., gray_channel]
        confidence = points[..., -1]
    else:  # per-pixel getters: slow, but some bindings have nothing else
        n = h * w
        xyz = np.array(
            [(data.getX(i), data.getY(i), data.getZ(i)) for i in range(n)], dtype=np.float32
        ).reshape(h, w, 3)
        gray = np.array([data.getGrayValue(i) for i in range(n)], np.float32).reshape(h, w)
        confidence = np.array([data.getDepthConfidence(i) for i in range(n)], np.float32).reshape(
            h, w
        )
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


class RoyaleCamera(Camera):
    backend = "royale"

    def __init__(self, config=None, *, source: str | None = None) -> None:
        super().__init__(config)
        self.source = self.config.camera_id if source is None else source
        self._roypy = None
        self._manager = None
        self._device = None
        self._listener = None
        self._recording_frames = 0  # a .rrf playback ends after this many (0: unknown)
        self._offset_ns: int | None = None
        self._index = 0

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
            if self.source and self.source not in connected:
                raise DeviceNotAvailable(
                    f"pmd camera {self.source!r} is not connected "
                    f"(connected: {', '.join(connected)})"
                )
            device = self._sdk(
                "opening the camera", self._manager.createCamera, self.source or connected[0]
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
        self.geometry = geometry_from_lens(
            self._sdk("getLensParameters", device.getLensParameters), width, height, name, serial
        )
        self.details = {
            "camera": name,
            "id": serial,
            "use_case": use_case,
            "source": self.source or serial,
        }

    def _start(self) -> None:
        self._index = 0
        self._offset_ns = None
        self._listener = _make_listener(self._roypy, self._on_data)
        self._sdk("registerDataListener", self._device.registerDataListener, self._listener)
        self._sdk("startCapture", self._device.startCapture)

    def _stop(self) -> None:
        device = self._device
        if device is None:
            return
        try:
            device.stopCapture()
            if hasattr(device, "unregisterDataListener"):
                device.unregisterDataListener()
        except Exception as e:  # an unplugged camera cannot stop: nothing left to do
            log.warning("royale stopCapture: %s", e)
        self._listener = None

    def _close(self) -> None:
        self._device = None
        self._manager = None

    def _on_data(self, data) -> None:
        host = now_ns()
        try:
            xyz, confidence, gray = depth_data_arrays(data)
        except Exception as e:
            self._count_error()
            self._event("bad_frame", f"royale frame not understood: {e}")
            return
        device_ns = int(data.timeStamp) * 1000  # microseconds
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
            self._finish(
                "end_of_recording", f"end of {Path(self.source).name} after {self._index} frames"
            )
