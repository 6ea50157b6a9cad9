"""What every device backend shares: a bounded buffer with counted drops, and a status.

Backends produce on their own thread and call `_deliver`; consumers call `recv`.
The buffer never blocks the producer: when full, the oldest item is dropped and counted,
so a slow consumer costs data that is accounted for, never a stalled device.
"""

from __future__ import annotations

import collections
import importlib
import threading
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Generic, TypeVar

from devices import clock
from devices.clock import now_ns
from devices.errors import DeviceNotAvailable

T = TypeVar("T")


class DeviceState(StrEnum):
    """A device's state: a str equal to its text ("ok", ...) in comparisons, f-strings, JSON."""

    OK = "ok"
    DEGRADED = "degraded"  # delivering, but stalled, slow or with recent errors
    LOST = "lost"  # gone while running (unplugged, no answer)
    STOPPED = "stopped"


# The backends' short names for the states
OK, DEGRADED, LOST, STOPPED = (
    DeviceState.OK,
    DeviceState.DEGRADED,
    DeviceState.LOST,
    DeviceState.STOPPED,
)


@dataclass
class DeviceStatus:
    backend: str
    state: DeviceState = DeviceState.STOPPED
    message: str = ""
    configured_rate_hz: float = 0.0
    measured_rate_hz: float = 0.0
    delivered: int = 0
    dropped: int = 0  # overwritten in the buffer because the consumer was slow
    errors: int = 0  # device-side errors (checksum errors, missing packets, ...)
    details: dict = field(default_factory=dict)


@dataclass
class DeviceEvent:
    """Something the session must know and record: a fault, a gap, a reconnect."""

    time_ns: int  # session clock
    device: str  # "camera" | "imu"
    kind: str  # e.g. "lost", "reconnected", "gap", "checksum_error", "stall", "drop"
    message: str
    details: dict = field(default_factory=dict)


class BoundedBuffer(Generic[T]):
    """A thread-safe FIFO of bounded size that drops the oldest item when full."""

    def __init__(self, maxlen: int = 256) -> None:
        self._items: collections.deque[T] = collections.deque()
        self._maxlen = maxlen
        self._cond = threading.Condition()
        self.dropped = 0

    def put(self, item: T) -> None:
        with self._cond:
            if len(self._items) >= self._maxlen:
                self._items.popleft()
                self.dropped += 1
            self._items.append(item)
            self._cond.notify()

    def get(self, timeout: float | None = None) -> T | None:
        with self._cond:
            if not self._items:
                self._cond.wait(timeout)
            return self._items.popleft() if self._items else None

    def __len__(self) -> int:
        return len(self._items)


class Producer:
    """A device's own thread (a daemon running `target`: a backend's producer, a reader, a
    watchdog) and the event that halts it: started, halted and joined alike everywhere."""

    def __init__(self, name: str, target) -> None:
        self.name = name
        self.target = target
        self.halt = threading.Event()  # set: the producer returns at its next check
        self.thread: threading.Thread | None = None

    def start(self) -> None:
        self.halt.clear()
        self.thread = threading.Thread(target=self.target, name=self.name, daemon=True)
        self.thread.start()

    @property
    def running(self) -> bool:
        return self.thread is not None and self.thread.is_alive()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Halt and join (unless called from the thread itself, which returns on its own)."""
        self.halt.set()
        if self.thread is not None and self.thread is not threading.current_thread():
            self.thread.join(timeout=timeout_s)
        self.thread = None


class RateMeter:
    """Items per second over the last `window_s` seconds, by the times the items carry.

    Fed with sample times (when each sample was taken, on the session clock), a burst of
    samples that arrive together after a gap counts at the times they were taken: it
    cannot read as a rate above the device's."""

    def __init__(self, window_s: float = 2.0) -> None:
        self._times: collections.deque[int] = collections.deque()
        self._window_ns = clock.to_ns(window_s)

    def tick(self, t_ns: int | None = None) -> None:
        t = now_ns() if t_ns is None else t_ns
        if self._times and t < self._times[-1] - self._window_ns:
            self._times.clear()  # the clock went back (a device clock refitted): start over
        self._times.append(t)
        while t - self._times[0] > self._window_ns:
            self._times.popleft()

    def rate(self, t_ns: int | None = None) -> float:
        t = now_ns() if t_ns is None else t_ns
        while self._times and t - self._times[0] > self._window_ns:
            self._times.popleft()
        if len(self._times) < 2:
            return 0.0
        first, last = min(self._times), max(self._times)
        span = clock.seconds(last - first)
        return (len(self._times) - 1) / span if span > 0 else 0.0


def load_backend(kind: str, backends: dict[str, str], name: str) -> type:
    """The class registered as "module:Class" under `name` in a backend registry, its module
    imported now: a missing vendor SDK costs nothing until its backend is chosen."""
    try:
        target = backends[name]
    except KeyError:
        known = ", ".join(sorted(backends))
        raise DeviceNotAvailable(f"unknown {kind} backend {name!r} (known: {known})") from None
    module_name, _, class_name = target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as e:
        raise DeviceNotAvailable(f"{kind} backend {name!r} cannot be loaded: {e}") from None
    return getattr(module, class_name)
