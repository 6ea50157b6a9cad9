"""Reading an IMU's stream in tests: samples for a while or until enough, event kinds."""

import time


def collect(imu, seconds: float) -> list:
    """Every sample the IMU gives within `seconds`."""
    samples, deadline = [], time.monotonic() + seconds
    while time.monotonic() < deadline:
        s = imu.recv(0.1)
        if s is not None:
            samples.append(s)
    return samples


def collect_n(imu, n: int, timeout: float = 120.0) -> list:
    """n samples, waiting at most `timeout` s for them (a bound, never the measure)."""
    samples, deadline = [], time.monotonic() + timeout
    while len(samples) < n and time.monotonic() < deadline:
        s = imu.recv(0.1)
        if s is not None:
            samples.append(s)
    return samples


def kinds(events) -> list[str]:
    return [e.kind for e in events]
