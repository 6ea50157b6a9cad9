"""The mock subject in a process of its own: the simulated walk with both sensors on it.

Real sensors cost the host nothing: the camera computes depth on its own chip, the IMU
clocks its samples on its own. Run in the host's process, the simulator's renderer and the
IMU emulator compete with the pipeline for Python's GIL, and at 45 fps with a 400 Hz IMU
that shows as latency spikes of 100 ms that no real device would cause. The rig runs both
in a child process; the host sees what it sees of hardware: frames arriving (over a pipe,
stamped on receipt, as the royale callback would be), and Xbus bytes on a serial port (the
emulator's pseudo-terminal, read by the real driver).

    rig = MockRig(config.camera, config.simulator, config.imu)   # the child is running
    camera, imu = rig.camera(), rig.imu()                        # RigCamera, RigImu
    imu.open(); camera.start(); imu.start() ...                  # like any backend
    imu.inject("disconnect"); camera.inject("stall", seconds=2)   # faults, as in-process

The subject stands at the start of the course until the camera starts, then walks; the
IMU feels the same thigh all along. Closing both devices ends the child; so does the
host's death (the pipe breaks).
"""

from __future__ import annotations

import logging
import sys
import threading
import time
from typing import Any

import numpy as np

from devices import clock
from devices.camera import Camera
from devices.child import Child
from devices.clock import now_ns
from devices.errors import DeviceInitError
from devices.frames import DepthFrame
from devices.imu import XbusImu
from devices.rotations import quat_slerp
from devices.scheduling import realtime_priority

log = logging.getLogger(__name__)

# The rig's threads (renderer, IMU emulator, sender) at real-time priority where permitted,
# as hardware runs on its own: the host's load does not make the camera skip frames. Below
# the session's pipeline thread (10 by default), which preempts them.
RIG_PRIORITY = 5
START_TIMEOUT_S = 60.0  # a spawned interpreter imports Open3D and works out the course truth
REPLY_TIMEOUT_S = 5.0


class MockRig:
    """The child process and the pipe to it; shared by one RigCamera and one RigImu."""

    def __init__(self, camera_config, simulator_config, imu_config) -> None:
        self.camera_config = camera_config
        self.imu_config = imu_config
        self._send_lock = threading.Lock()
        self._replies: dict[int, Any] = {}
        self._replied = threading.Condition()
        self._next_id = 0
        self._users = 0
        self._closed = False
        self.camera_device: RigCamera | None = None
        self._child = Child(
            "devices.simulator.rig:_serve", camera_config, simulator_config, imu_config
        )
        self._conn = self._child.conn
        ready = self._conn.poll(START_TIMEOUT_S) and self._receive_quietly()
        if not ready or ready[0] != "ready":
            code = self._child.process.poll()
            message = (
                ready[1]
                if ready
                else (
                    "no answer"
                    if code is None
                    else f"its process exited with code {code} (WALKCAP_DEBUG=1 shows its errors)"
                )
            )
            self._kill()
            raise DeviceInitError(f"mock devices failed to start: {message}")
        info = ready[1]
        self.port: str = info["port"]
        self.geometry = info["geometry"]
        self.details: dict = info["details"]
        self.imu_clock = info["clock"]  # devices.imu.emulator.EmulatorClock
        self._reader = threading.Thread(target=self._read, name="walkcap-rig-reader", daemon=True)
        self._reader.start()

    # ---- the two devices ------------------------------------------------------------------

    @property
    def pid(self) -> int:
        """The rig's process id (its memory and CPU are the devices', not the session's)."""
        return self._child.pid

    def camera(self) -> RigCamera:
        self._users += 1
        self.camera_device = RigCamera(self)
        return self.camera_device

    def imu(self) -> RigImu:
        self._users += 1
        cfg = self.imu_config
        return RigImu(self, self.port, cfg.baudrate, cfg.rate_hz)

    def release(self) -> None:
        """One device closed; the last one ends the child."""
        self._users -= 1
        if self._users <= 0:
            self.close()

    # ---- commands -------------------------------------------------------------------------

    def inject_imu(self, fault: str, **kw) -> None:
        """A fault of the IMU emulator (see ImuEmulator.inject)."""
        self.imu_clock = self._request("inject_imu", fault, kw)

    def inject_camera(self, fault: str, **kw) -> None:
        """A fault of the mock camera (see MockCamera.inject)."""
        self._request("inject_camera", fault, kw)

    def true_time_ns(self, sample_time_fine: int) -> int:
        """When the emulator really took that sample (for sync-accuracy checks)."""
        return self.imu_clock.true_time_ns(sample_time_fine, now_ns())

    def command(self, name: str) -> None:
        self._request(name)

    def _request(self, *message) -> Any:
        with self._replied:
            self._next_id += 1
            request_id = self._next_id
        self._send(("request", request_id) + message)
        with self._replied:
            if (
                not self._replied.wait_for(
                    lambda: request_id in self._replies or self._closed, REPLY_TIMEOUT_S
                )
                or request_id not in self._replies
            ):
                raise DeviceInitError(f"mock devices did not answer {message[0]!r}")
            ok, value = self._replies.pop(request_id)
        if not ok:
            raise DeviceInitError(f"mock devices: {value}")
        return value

    def _send(self, message) -> None:
        try:
            with self._send_lock:
                self._conn.send(message)
        except (OSError, ValueError):
            raise DeviceInitError("the mock devices' process has ended") from None

    # ---- what the child sends -------------------------------------------------------------

    def _receive_quietly(self):
        try:
            return self._conn.recv()
        except (EOFError, OSError):
            return None

    def _read(self) -> None:
        try:
            while True:
                message = self._conn.recv()
                kind = message[0]
                if kind == "frame":
                    self._frame(message[1])
                elif kind == "reply":
                    with self._replied:
                        self._replies[message[1]] = (message[2], message[3])
                        self._replied.notify_all()
                elif kind == "camera_event" and self.camera_device is not None:
                    self.camera_device.on_event(*message[1:])
        except (EOFError, OSError) as e:
            log.debug("mock rig: %s", e)
        except Exception:  # a bug here must show as a lost camera, not a silent stall
            log.exception("mock rig reader")
        finally:
            with self._replied:
                closing = self._closed
                self._closed = True
                self._replied.notify_all()
            if not closing and self.camera_device is not None:
                self.camera_device.on_event("lost", "the mock devices' process ended", {})

    def _frame(self, header: dict) -> None:
        arrays = {}
        for name, dtype, shape in header.pop("arrays"):
            buffer = bytearray(int(np.prod(shape)) * np.dtype(dtype).itemsize)
            self._conn.recv_bytes_into(buffer)
            arrays[name] = np.frombuffer(buffer, dtype=dtype).reshape(shape)
        if self.camera_device is not None:
            self.camera_device.on_frame(
                DepthFrame(
                    index=header["index"],
                    device_time_ns=header["device_time_ns"],
                    host_time_ns=now_ns(),
                    geometry=self.geometry,
                    truth=header["truth"],
                    **arrays,
                )
            )

    # ---- end ------------------------------------------------------------------------------

    def close(self) -> None:
        """End the child (idempotent)."""
        with self._replied:
            if self._closed and not self._child.running():
                return
            self._closed = True
        try:
            with self._send_lock:
                self._conn.send(("quit",))
        except (OSError, ValueError):
            pass
        self._child.end()

    def _kill(self) -> None:
        self._child.end(timeout_s=0)


class RigCamera(Camera):
    """The mock camera as the host sees it: frames arriving from the rig."""

    backend = "mock"

    def __init__(self, rig: MockRig) -> None:
        super().__init__(rig.camera_config, geometry=rig.geometry)
        self.rig = rig
        # frames the renderer skipped because it fell behind (a real camera has no
        # renderer: counted apart from frames lost on their way, see `walkcap bench --soak`)
        self.details = dict(rig.details, process="rig", renderer_skipped=0)
        self._rig_drops = 0  # frames the rig's own buffer dropped (cumulative, as reported)

    def _start(self) -> None:
        self.rig.command("start_camera")

    def _stop(self) -> None:
        try:
            self.rig.command("stop_camera")
        except DeviceInitError:
            pass  # the child is gone: nothing to stop

    def _close(self) -> None:
        self.rig.release()

    def _restart(self) -> None:
        self.rig.command("reopen_camera")

    def inject(self, fault: str, **kw) -> None:
        self.rig.inject_camera(fault, **kw)

    def on_frame(self, frame: DepthFrame) -> None:
        if self._running:
            self._deliver(frame)

    def on_event(self, kind: str, message: str, details: dict) -> None:
        if kind == "end_of_course":
            self._finish(kind, message)
        elif kind == "lost":
            if self._running:
                self._fail(message)
        else:
            if kind == "gap":
                skipped = int(details.get("skipped", 1))
                self._count_error(skipped)
                self.details["renderer_skipped"] += skipped
            elif kind == "drop":  # the rig could not send fast enough: lost frames too
                dropped = int(details.get("dropped", 0))
                self._count_error(max(0, dropped - self._rig_drops))
                self._rig_drops = max(dropped, self._rig_drops)
                # the camera's buffer filled because this host did not read it (slow or
                # stalled), which the camera cannot tell apart
                message = message.replace(
                    "the consumer is slower than the camera", "the host did not take them in time"
                )
            self._event(kind, message, **details)


class RigImu(XbusImu):
    """The real Xbus driver on the rig's emulator port."""

    backend = "mock"

    def __init__(self, rig: MockRig, port: str, baudrate: int, rate_hz: int) -> None:
        super().__init__(port, baudrate, rate_hz)
        self.rig = rig
        self._released = False

    def inject(self, fault: str, **kw) -> None:
        """A fault of the emulated device (see ImuEmulator.inject)."""
        self.rig.inject_imu(fault, **kw)

    def true_time_ns(self, sample_time_fine: int) -> int:
        """When the emulator really took that sample (for sync-accuracy checks)."""
        return self.rig.true_time_ns(sample_time_fine)

    def close(self) -> None:
        try:
            super().close()
        finally:
            if not self._released:
                self._released = True
                self.rig.release()


# ---- the child process ---------------------------------------------------------------------


class StandingBlend:
    """The thigh the IMU feels across the camera's stops: walking, the walk's pose; stopped,
    an ease over EASE_S from where the walk left the thigh to the standing pose at the
    start, where a new walk begins. A jump would be a rate of turn of tens of rad/s in the
    emulator's +-2 ms difference."""

    EASE_S = 0.5

    def __init__(self, orientation_at) -> None:
        self._at = orientation_at  # walk time (s) -> [w, x, y, z]
        self._last: tuple[float, np.ndarray] | None = None  # (IMU time, pose) walking
        self._left: tuple[float, np.ndarray] | None = None  # where the walk stopped

    def __call__(self, t_s: float, walk_s: float | None) -> np.ndarray:
        """The orientation at IMU time t_s: walk time walk_s, or None while stopped."""
        if walk_s is not None:
            q = np.asarray(self._at(walk_s), dtype=np.float64)
            self._last, self._left = (t_s, q), None
            return q
        stand = np.asarray(self._at(0.0), dtype=np.float64)
        if self._last is None:
            return stand
        if self._left is None:
            self._left = self._last
        t0, q0 = self._left
        u = min(max((t_s - t0) / self.EASE_S, 0.0), 1.0)
        return quat_slerp(q0, stand, u * u * (3.0 - 2.0 * u))


def _serve(conn, camera_config, simulator_config, imu_config) -> None:
    """The rig's main: build the walk, camera and IMU emulator; answer requests; stream."""
    logging.basicConfig(level=logging.WARNING)
    scheduling = realtime_priority(0, RIG_PRIORITY)  # every thread started here inherits it
    # The renderer, the emulator and the frame sender share this process's GIL: a short
    # switch interval keeps each one's wait for it short (frames and samples on time).
    sys.setswitchinterval(0.0005)
    send_lock = threading.Lock()

    def send(message, *buffers) -> None:
        with send_lock:
            conn.send(message)
            for b in buffers:
                conn.send_bytes(b)

    try:
        from devices.imu.emulator import ImuEmulator
        from devices.simulator.camera import MockCamera

        camera = MockCamera(camera_config, simulator_config)
        camera.watchdog = False  # the host's camera watches the frames that reach it
        camera.open()

        blend = StandingBlend(camera.orientation_at)

        def thigh(t_s: float) -> np.ndarray:
            # the subject stands at the start until the camera starts, then walks
            start = camera.start_time_ns
            if start is None:
                return blend(t_s, None)
            return blend(t_s, max(0.0, clock.seconds(emulator.start_time_ns - start) + t_s))

        emulator = ImuEmulator(
            rate_hz=imu_config.rate_hz,
            drift_ppm=imu_config.drift_ppm,
            jitter_ms=imu_config.jitter_ms,
            seed=getattr(imu_config, "seed", 0),
            orientation_at=thigh,
            baudrate=imu_config.baudrate,
            model=getattr(imu_config, "emulate", "MTi-3"),
        )
        port = emulator.start()
    except Exception as e:
        conn.send(("failed", f"{type(e).__name__}: {e}"))
        return
    stopping = threading.Event()
    send(
        (
            "ready",
            {
                "port": port,
                "geometry": camera.geometry,
                "details": {**camera.details, "scheduling": scheduling},
                "clock": emulator.clock,
            },
        )
    )
    streamer = threading.Thread(target=_stream, args=(camera, send, stopping), daemon=True)
    streamer.start()
    try:
        while True:
            message = conn.recv()
            if message[0] == "quit":
                break
            _, request_id, name, *args = message
            try:
                value = _handle(name, args, camera, emulator)
                send(("reply", request_id, True, value))
            except Exception as e:
                send(("reply", request_id, False, f"{type(e).__name__}: {e}"))
    except (EOFError, OSError):
        pass  # the host is gone
    finally:
        stopping.set()
        streamer.join(timeout=2.0)
        camera.close()
        emulator.stop()


def _handle(name: str, args: list, camera, emulator):
    if name == "start_camera":
        camera.start()
    elif name == "stop_camera":
        camera.stop()
    elif name == "reopen_camera":
        camera._restart()
    elif name == "inject_imu":
        fault, kw = args
        emulator.inject(fault, **kw)
        return emulator.clock  # a power cycle restarts the device clock
    elif name == "inject_camera":
        fault, kw = args
        camera.inject(fault, **kw)
    else:
        raise ValueError(f"unknown request {name!r}")
    return None


def _stream(camera, send, stopping: threading.Event) -> None:
    """Frames and camera events to the host while the rig runs."""
    try:
        while not stopping.is_set():
            frame = camera.recv(0.05)
            for event in camera.poll_events():
                send(("camera_event", event.kind, event.message, dict(event.details)))
            if frame is None:
                continue
            arrays = [(name, getattr(frame, name)) for name in ("xyz", "confidence", "gray")]
            header = {
                "index": frame.index,
                "device_time_ns": frame.device_time_ns,
                "truth": frame.truth,
                "arrays": [(n, a.dtype.str, a.shape) for n, a in arrays],
            }
            # flat bytes: Connection.send_bytes takes len() of a memoryview, rows for 2-D
            send(
                ("frame", header),
                *(np.ascontiguousarray(a).reshape(-1).view(np.uint8) for _, a in arrays),
            )
    except (OSError, ValueError):
        pass  # the host is gone
    except Exception as e:  # a simulator bug shows on the host as a lost camera
        try:
            send(("camera_event", "lost", f"simulator failed: {type(e).__name__}: {e}", {}))
        except (OSError, ValueError):
            pass
        time.sleep(0.1)
