"""The session clock: one clock for every timestamp walkcap writes.

Host times are `time.monotonic_ns()`: steady, never stepped by NTP, shared by every
thread of the process. Device times are mapped onto it (see the IMU clock estimator).

`seconds()` and `to_ns()` are the one conversion between the clock's integer ns and
seconds; they take numpy arrays as well as numbers.
"""

from __future__ import annotations

import time

now_ns = time.monotonic_ns


def seconds(ns):
    """Nanoseconds (a time or a span) in seconds."""
    return ns * 1e-9


def to_ns(s: float) -> int:
    """Seconds in whole nanoseconds, the nearest one."""
    return int(round(s * 1e9))
