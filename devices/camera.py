"""The depth camera: one interface for every backend, and a registry of backends by name.

    camera = open_camera(config.camera, config.simulator)   # constructed and opened
    with camera:                                            # close() on the way out
        camera.start()
        frame = camera.recv(timeout=0.5)                    # DepthFrame or None
        camera.status(); camera.poll_events()
        camera.stop()

A backend subclasses `Camera`, implements the hooks `_open`, `_start`, `_stop`, `_close`,
and hands frames from its own thread (or the SDK's) to `_deliver`. The base class does the
rest: a bounded buffer that drops the oldest frame when the consumer is slow (and counts
it), the measured rate (by the frames' device times: the camera's own clock), events, the
life cycle and the context manager, and a watchdog: a silent camera is a "stall" (and
"resumed", with the gap, when frames come again); silent for `lost_after_s` it is "lost"
and reopened (`_restart`) until frames come ("reconnected"). That rule is the same for
every backend; a backend that can tell more than silence (an unplug event, the device
saying it is disconnected, the end of a recording) says so through `_watch_device`.
Backends are named in `BACKENDS` and imported only when chosen, so a missing vendor SDK
costs nothing until someone asks for that camera (as python-can does).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator

from devices import clock
from devices.base import (
    DEGRADED,
    LOST,
    OK,
    STOPPED,
    BoundedBuffer,
    DeviceEvent,
    DeviceState,
    DeviceStatus,
    Producer,
    RateMeter,
    load_backend,
)
from devices.clock import now_ns
from devices.frames import CameraGeometry, DepthFrame
from devices.watchdog import EventThrottle, SilenceWatch

BACKENDS: dict[str, str] = {
    "mock": "devices.simulator.camera:MockCamera",
    "royale": "devices.royale:RoyaleCamera",
}


def register_backend(name: str, target: str) -> None:
    """Add a backend, "module:Class", imported only when chosen (higher layers add theirs)."""
    BACKENDS[name] = target


def camera_class(name: str) -> type[Camera]:
    """The backend class registered under `name`, its module imported now."""
    return load_backend("camera", BACKENDS, name)


def open_camera(camera_config=None, simulator_config=None, **kw) -> Camera:
    """Construct the configured backend and open it (not started yet).

    `camera_config` is a devices.config.CameraConfig (default: mock at 15 fps); the mock
    backend also takes the SimulatorConfig; other keywords go to the backend.
    """
    if camera_config is None:
        from devices.config import CameraConfig

        camera_config = CameraConfig()
    camera = camera_class(camera_config.backend).from_config(camera_config, simulator_config, **kw)
    try:
        camera.open()
    except BaseException:
        camera.close()
        raise
    return camera


HOST_STALL_NS = 1_000_000_000  # the watchdog not run for this long: the host stalled


class Camera:
    """Base of every depth camera backend. Thread-safe between one producer and consumers."""

    backend = "camera"
    # False where something else watches for silence (the mock rig's child process):
    # stalls and resumed frames are still reported.
    watchdog = True

    def __init__(
        self,
        config=None,
        *,
        geometry: CameraGeometry | None = None,
        clock: Callable[[], int] = now_ns,
    ) -> None:
        if config is None:
            from devices.config import CameraConfig

            config = CameraConfig()
        self.config = config
        self.geometry = geometry or CameraGeometry()
        # The session clock; a backend on an injected clock (tests) passes its own, so the
        # watchdog measures silence on the clock the frames are stamped with.
        self._now = clock
        self._buffer: BoundedBuffer[DepthFrame] = BoundedBuffer(max(1, config.buffer_frames))
        self._events: BoundedBuffer[DeviceEvent] = BoundedBuffer(256)
        self._rate = RateMeter()
        self._lock = threading.Lock()
        self._opened = False
        self._running = False
        self._state = STOPPED
        self._message = "closed"
        self._delivered = 0
        self._errors = 0
        self._last_frame_ns = 0
        self._started_ns = 0
        self._seen_drops = 0
        self._drops = EventThrottle(self._report_drops)  # on the frames' clock
        self._stalled = False
        self._watch_lock = threading.RLock()  # the watchdog's and the producer's transitions
        self._resume_pending: tuple[int, int] | None = None  # (frame time, last frame before)
        self._watchdog = Producer("walkcap-camera-watchdog", self._watchdog_run)
        self._watch_stop = self._watchdog.halt
        self._next_reopen_ns = 0
        self._lost_at_ns = 0
        self._silence = SilenceWatch(HOST_STALL_NS)  # the watchdog's checks (see _check)
        self.reopens = 0
        # After a reopen a device may number its frames from 0 again: they go on from here.
        self._last_index = -1
        self._index_base: int | None = None
        self._index_shift = 0
        self.details: dict = {}  # backend facts for status(): camera name, use case, ...

    @classmethod
    def from_config(cls, camera_config, simulator_config=None, **kw) -> Camera:
        """Construct from the configuration; backends needing more override this."""
        return cls(camera_config, **kw)

    # ---- backend hooks ------------------------------------------------------------------

    def _open(self) -> None:
        """Connect and configure the device; raise DeviceError subclasses on failure."""

    def _start(self) -> None:
        """Begin producing frames (from a thread or an SDK callback) into `_deliver`."""

    def _stop(self) -> None:
        """Stop producing; after it returns no more `_deliver` calls come."""

    def _close(self) -> None:
        """Release the device."""

    def _watch_device(self, silent_s: float) -> str | None:
        """Why the streaming device is lost now, before `lost_after_s` of silence (an unplug
        the device reported), or None. Called by the watchdog with the lock held, every
        check while streaming; a backend may also end the stream here (`_finish`)."""
        return None

    def _restart(self) -> None:
        """Get a silent device streaming again (raise DeviceError if it cannot be yet)."""
        self._stop()
        self._close()
        self._open()
        self._start()

    # ---- life cycle ---------------------------------------------------------------------

    def open(self) -> None:
        """Connect to the device. Idempotent."""
        if self._opened:
            return
        self._open()
        self._opened = True
        self._message = "open"

    def start(self) -> None:
        """Start streaming (opens first if needed). Idempotent."""
        self.open()
        if self._running:
            return
        self._started_ns = self._now()
        self._last_frame_ns = 0
        self._stalled = False
        self._set_state(OK, "streaming")
        self._running = True
        try:
            self._start()
        except BaseException:
            self._running = False
            self._set_state(STOPPED, "failed to start")
            raise
        if self.watchdog:
            self._watchdog.start()

    def stop(self) -> None:
        """Stop streaming; frames already buffered can still be received. Idempotent."""
        self._watchdog.stop()
        if self._running:
            self._running = False
            with self._watch_lock:  # not while the watchdog reopens the device
                self._stop()
        if self._state != STOPPED:
            self._set_state(STOPPED, "stopped")

    def close(self) -> None:
        """Stop and release the device. Idempotent."""
        try:
            self.stop()
        finally:
            if self._opened:
                self._opened = False
                self._close()
            self._message = "closed"

    def __enter__(self) -> Camera:
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def running(self) -> bool:
        """Started and still producing (False after stop() or the end of a course)."""
        return self._running and self._state != STOPPED

    # ---- consumer side ------------------------------------------------------------------

    def recv(self, timeout: float | None = None) -> DepthFrame | None:
        """The oldest buffered frame, waiting up to `timeout` s; None when there is none."""
        return self._buffer.get(timeout)

    def __iter__(self) -> Iterator[DepthFrame]:
        """Frames until the camera has stopped and its buffer is empty."""
        while True:
            frame = self.recv(0.1)
            if frame is not None:
                yield frame
            elif self._state == STOPPED and len(self._buffer) == 0:
                return

    def status(self) -> DeviceStatus:
        t = self._now()
        self._check(t)
        state, message = self._state, self._message
        if state == OK:
            since = self._silence.since(self._last_frame_ns or self._started_ns)
            silent_s = clock.seconds(t - since)
            if silent_s > self._stall_after_s():
                state, message = DEGRADED, f"no frame for {silent_s:.1f} s"
        with self._lock:
            rate = self._rate.rate(t)
        return DeviceStatus(
            backend=self.backend,
            state=state,
            message=message,
            configured_rate_hz=float(self.config.fps),
            measured_rate_hz=rate,
            delivered=self._delivered,
            dropped=self._buffer.dropped,
            errors=self._errors,
            details=dict(self.details),
        )

    def poll_events(self) -> list[DeviceEvent]:
        """Events since the last call (faults, gaps, drops, end of course), oldest first."""
        events = []
        while (e := self._events.get(0)) is not None:
            events.append(e)
        return events

    # ---- producer side (backends) -------------------------------------------------------

    def _stall_after_s(self) -> float:
        return max(1.0, 5.0 / max(self.config.fps, 1e-3))

    def _lost_after_s(self) -> float:
        return max(self._stall_after_s(), float(getattr(self.config, "lost_after_s", 5.0)))

    def _watchdog_run(self) -> None:
        while not self._watch_stop.wait(0.1):
            try:
                self._check(self._now())
            except Exception as e:  # the watchdog must outlive an odd device
                self._message = f"watchdog: {e}"

    def _check(self, t: int) -> None:
        """Stall, lost and reopen: from the watchdog thread (and status())."""
        with self._watch_lock:
            with self._lock:
                pending, self._resume_pending = self._resume_pending, None
            if pending is not None and (self._stalled or self._state == LOST):
                self._resume(*pending)
            # Checks run every 0.1 s: a longer pause is the host's own stall (stopped,
            # swapped, starved), not the camera's silence. The frames the camera kept
            # sending meanwhile are still on their way: silence counts from here.
            self._silence.check(t)
            if self._state == OK and self._running:
                since = self._silence.since(self._last_frame_ns or self._started_ns)
                silent_s = clock.seconds(t - since)
                if silent_s > self._stall_after_s() and not self._stalled:
                    self._stalled = True
                    self._event("stall", f"no frame for {silent_s:.1f} s")
                if not self.watchdog:
                    return
                reason = self._watch_device(silent_s)
                if self._state != OK:  # the backend ended the stream
                    return
                if reason is None and silent_s > self._lost_after_s():
                    reason = f"no frame for {silent_s:.1f} s"
                if reason is not None:
                    self._fail(reason)
                    self._next_reopen_ns = t
            if (
                self._state == LOST
                and self._running
                and self.watchdog
                and t >= self._next_reopen_ns
            ):
                self._next_reopen_ns = t + clock.to_ns(self._lost_after_s())
                # Before the restart: its first frame may come (from the backend's thread)
                # before _restart returns.
                self._index_base, self._index_shift = self._last_index + 1, -1
                try:
                    self._restart()
                except Exception as e:  # not back yet: again after lost_after_s
                    self._message = f"lost: {e}; retrying"
                    return
                self.reopens += 1
                self._message = f"lost: reopened ({self.reopens}), waiting for frames"

    def _deliver(self, frame: DepthFrame) -> None:
        """Hand a frame to consumers; never blocks (the oldest buffered frame is dropped)."""
        if self._index_base is not None:
            if self._index_shift < 0:  # the first frame since a reopen
                self._index_shift = max(0, self._index_base - frame.index)
            frame.index += self._index_shift
        if self._stalled or self._state == LOST:
            self._resumed(frame.host_time_ns)
        with self._lock:
            # the camera's own clock: a host stall delays arrivals, not the frames' times,
            # and must not read as a change of frame rate (silence is the watchdog's, above)
            self._rate.tick(frame.device_time_ns)
            self._delivered += 1
            self._last_frame_ns = frame.host_time_ns
            self._last_index = frame.index
        self._buffer.put(frame)
        dropped = self._buffer.dropped
        if dropped > self._seen_drops:  # reported at most once a second, with the count
            new, self._seen_drops = dropped - self._seen_drops, dropped
            self._drops.add("drop", new, frame.host_time_ns)
        else:
            self._drops.flush(frame.host_time_ns)

    def _report_drops(self, kind: str, count: int, t: int) -> None:
        self._event(
            kind,
            f"{count} frames dropped: the consumer is slower than the camera",
            dropped=self._seen_drops,
        )

    def _resumed(self, t: int) -> None:
        """Frames again after a stall or a loss, from the producer's thread. It never waits
        for the watchdog: while the watchdog reopens the device it holds the lock, and a
        backend's stop (royale's stopCapture) may wait for this very callback to return.
        The watchdog's next check takes a resume it held up."""
        last = self._last_frame_ns or self._started_ns
        if not self._watch_lock.acquire(blocking=False):
            with self._lock:
                if self._resume_pending is None:
                    self._resume_pending = (t, last)
            return
        try:
            self._resume(t, last)
        finally:
            self._watch_lock.release()

    def _resume(self, t: int, last: int) -> None:
        gap_s = clock.seconds(t - last)
        if self._state == LOST and self._running:
            self._set_state(OK, "streaming")
            self._event(
                "reconnected",
                f"camera back after a gap of {gap_s:.2f} s ({self.reopens} reopens)",
                gap_s=gap_s,
                gap_start_ns=last,
                gap_end_ns=t,
            )
        elif self._stalled:
            self._event(
                "resumed",
                f"frames again after a gap of {gap_s:.2f} s",
                gap_s=gap_s,
                gap_start_ns=last,
                gap_end_ns=t,
            )
        self._stalled = False

    def _event(self, kind: str, message: str, **details) -> None:
        self._events.put(DeviceEvent(self._now(), "camera", kind, message, details))

    def _set_state(self, state: DeviceState, message: str) -> None:
        self._state, self._message = state, message

    def _count_error(self, n: int = 1) -> None:
        self._errors += n

    def _finish(self, kind: str, message: str) -> None:
        """The producer ended on its own (end of course or recording): stopped, one event."""
        self._set_state(STOPPED, message)
        self._event(kind, message)

    def _fail(self, message: str) -> None:
        """The device was lost while running."""
        self._set_state(LOST, message)
        self._event("lost", message)
