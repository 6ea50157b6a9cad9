"""What every IMU backend offers, and the registry of backends by name.

Like python-can's bus: `Imu` is the surface every backend shares (open, start, recv,
stop, close, status, poll_events, a context manager); backends are named in `BACKENDS`
and imported only when chosen.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from devices.base import (
    STOPPED,
    BoundedBuffer,
    DeviceEvent,
    DeviceStatus,
    RateMeter,
    load_backend,
)
from devices.clock import now_ns
from devices.frames import ImuSample

log = logging.getLogger(__name__)

# name -> "module:Class", imported only when chosen (as devices.camera's BACKENDS).
BACKENDS: dict[str, str] = {
    "mock": "devices.imu.emulated:EmulatedImu",
    "serial": "devices.imu.driver:XbusImu",
}


def register_backend(name: str, target: str) -> None:
    """Add a backend, "module:Class", imported only when chosen (higher layers add theirs)."""
    BACKENDS[name] = target


def open_imu(config: Any, orientation_at: Callable[[float], np.ndarray] | None = None) -> Imu:
    """The IMU a configuration asks for (an ImuConfig or anything with its attributes).

    Not yet opened: call open() (or start(), or use it as a context manager).
    """
    backend = getattr(config, "backend", "mock")
    cls = load_backend("IMU", BACKENDS, backend)
    return cls.from_config(config, orientation_at=orientation_at)


class Imu:
    """What every IMU backend offers. Backends deliver samples with `_deliver`."""

    backend = "?"

    def __init__(self, buffer_size: int = 1024) -> None:
        self._buffer: BoundedBuffer[ImuSample] = BoundedBuffer(buffer_size)
        self._events: list[DeviceEvent] = []
        self._lock = threading.Lock()
        self._rate = RateMeter()
        self.delivered = 0
        self.info: dict[str, Any] = {}

    def open(self) -> None:
        raise NotImplementedError

    def start(self) -> None:
        raise NotImplementedError

    def stop(self) -> None:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError

    def status(self) -> DeviceStatus:
        raise NotImplementedError

    def recv(self, timeout: float | None = None) -> ImuSample | None:
        """The oldest sample not yet received; None after `timeout` seconds without one."""
        return self._buffer.get(timeout)

    def poll_events(self) -> list[DeviceEvent]:
        """Events since the last call (lost, reconnected, checksum errors, ...)."""
        with self._lock:
            events, self._events = self._events, []
        return events

    def __enter__(self) -> Imu:
        self.open()
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __iter__(self) -> Iterator[ImuSample]:
        while self.status().state != STOPPED:
            sample = self.recv(0.2)
            if sample is not None:
                yield sample

    def _deliver(self, sample: ImuSample) -> None:
        self._buffer.put(sample)
        with self._lock:  # by sample time: a catch-up burst after a gap is no faster rate
            self._rate.tick(sample.host_time_ns if sample.time_ns is None else sample.time_ns)
        self.delivered += 1

    def _event(self, kind: str, message: str, t_ns: int | None = None, **details: Any) -> None:
        # a message that names the device is a sentence already ("IMU lost (...)")
        log.info("%s", message if message.startswith("IMU") else f"IMU {kind}: {message}")
        event = DeviceEvent(now_ns() if t_ns is None else t_ns, "imu", kind, message, details)
        with self._lock:
            self._events.append(event)
            del self._events[:-1000]  # nobody polls: keep the latest

    def _measured_rate(self) -> float:
        with self._lock:
            return self._rate.rate()
