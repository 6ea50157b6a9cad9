"""The session clock: one clock for every timestamp walkcap writes.

Host times are `time.monotonic_ns()`: steady, never stepped by NTP, shared by every
thread of the process. Device times are mapped onto it (see the IMU clock estimator).
"""

from __future__ import annotations

import time

now_ns = time.monotonic_ns


def seconds(ns: int) -> float:
    return ns * 1e-9
