"""Device time onto host time: SampleTimeFine (10 kHz, wraps at 2**32) onto the session clock.

A sample reaches the host some transport delay after the device took it: never less than
a minimum (wire, driver) and often more (USB latency timer, scheduling). So the host
receive times, plotted against device time, lie on or above a line whose slope is the
clock rate ratio (drift) and whose intercept is the offset. The estimator fits that
lower envelope over a sliding window: the minimum per short bucket of device time, the
lower convex hull of those minima, and the hull edge under the middle of the window (the
line below every point closest to them on average). Jitter only ever lifts points above
the envelope, so it is rejected rather than averaged in. Until the window spans two
seconds the slope is held at zero: over a shorter span jitter would dominate it.
The host times given are receive times minus the message's wire time (the driver knows
the baud rate), so the offset holds only the unknowable fixed part of the latency.

Pure and single-threaded: the IMU reader thread owns one.
"""

from __future__ import annotations

import collections
import logging
import threading
from dataclasses import dataclass

from devices import clock

log = logging.getLogger(__name__)

TICK_NS = 100_000  # one SampleTimeFine tick (10 kHz)
# The median scatter of bucket minima above the envelope, times this, stands for their
# spread in the drift's standard error: 95 % coverage on simulated jitter at 3 s spans.
_UNCERTAINTY_SCALE = 2.5
WRAP = 2**32


@dataclass(frozen=True)
class ClockState:
    offset_ms: float  # mapped host time minus device time, at the latest sample
    drift_ppm: float  # > 0: the device clock runs fast against the host clock
    residual_ms: float  # recent mean receive delay above the envelope (transport jitter)
    span_s: float  # device time covered by the fit's window
    points: int  # bucket minima in the window
    resets: int
    # how far the drift may be off, ppm (see DeviceClock.drift_uncertainty_ppm); None while
    # the window is too short to fit a slope (the drift is held at zero)
    drift_uncertainty_ppm: float | None = None


class DeviceClock:
    """Maps device ticks onto host nanoseconds; see the module docstring."""

    def __init__(
        self,
        tick_ns: int = TICK_NS,
        wrap: int = WRAP,
        window_s: float = 30.0,
        bucket_s: float = 0.25,
        max_drift_ppm: float = 1000.0,
        jump_ms: float = 50.0,
        max_delay_s: float = 1.0,
        min_span_s: float = 2.0,
    ) -> None:
        self.tick_ns = tick_ns
        self.wrap = wrap
        self.window_ns = clock.to_ns(window_s)
        self.bucket_ns = clock.to_ns(bucket_s)
        self.max_slope = max_drift_ppm * 1e-6
        self.jump_ns = jump_ms * 1e6  # arriving this much before the envelope: clock jumped
        self.max_delay_ns = max_delay_s * 1e9  # this late for long: the device clock restarted
        # Over a shorter span jitter dominates the slope: assume no drift until then.
        self.min_span_ns = clock.to_ns(min_span_s)
        self.resets = 0  # fits forgotten because the device clock jumped or restarted
        self._excused_until = 0  # samples taken before this host time: a stall's backlog
        # The reader thread updates the fit while status() reads it from another thread.
        self._lock = threading.RLock()
        self._clear()

    def reset(self) -> None:
        """Forget the fit (a device that restarted its clock)."""
        with self._lock:
            self.resets += 1
            self._clear()

    def _clear(self) -> None:
        self._last_raw: int | None = None
        self._ticks = 0  # unwrapped ticks of the latest sample
        self._ref_ticks = 0
        self._ref_host = 0
        # (bucket, x, y) with x = device ns since the reference, y = host - reference - x
        self._buckets: collections.deque[tuple[int, int, float]] = collections.deque()
        self._a = 0.0  # envelope y = a + b * x
        self._b = 0.0
        self._residual = 0.0
        self._late = 0
        self._x = 0

    # ---- estimator --------------------------------------------------------------------

    def _unwrap(self, raw: int) -> int | None:
        """Unwrapped ticks, or None when the device clock went backwards."""
        if self._last_raw is None:
            return raw
        step = (raw - self._last_raw) % self.wrap
        if step >= self.wrap // 2:
            return None
        return self._ticks + step

    def update(self, raw_ticks: int, host_ns: int) -> int:
        """Add a sample taken at raw_ticks and received at host_ns; its mapped time."""
        with self._lock:
            return self._update(raw_ticks, host_ns)

    def _update(self, raw_ticks: int, host_ns: int) -> int:
        ticks = self._unwrap(raw_ticks)
        if ticks is None:
            log.info(
                "device clock went backwards (%d after %d): refitting", raw_ticks, self._last_raw
            )
            self.reset()
            ticks = raw_ticks
        if self._last_raw is None:
            self._ref_ticks, self._ref_host = ticks, host_ns
        self._last_raw, self._ticks = raw_ticks, ticks
        x = (ticks - self._ref_ticks) * self.tick_ns
        y = float(host_ns - self._ref_host - x)
        residual = y - (self._a + self._b * x)
        backlog = self._ref_host + x + self._a + self._b * x < self._excused_until
        if backlog and self._buckets and residual >= -self.jump_ns:
            self._x = x
            return self.to_host_ns(raw_ticks)  # mapped on the fit, which it leaves alone
        if self._buckets and (residual < -self.jump_ns or self._too_late(residual)):
            log.info("device clock jumped (residual %.1f ms): refitting", residual * 1e-6)
            self.reset()
            return self._update(raw_ticks, host_ns)
        self._x = x
        self._add_point(x, y)
        self._residual += 0.05 * (max(0.0, y - (self._a + self._b * x)) - self._residual)
        return self.to_host_ns(raw_ticks)

    def excuse(self, until_host_ns: int) -> None:
        """The host stalled until `until_host_ns`: samples the fit places before then arrive
        late by the host's doing, not a restarted device clock, and say nothing of the
        transport delay."""
        with self._lock:
            self._excused_until = max(self._excused_until, until_host_ns)

    def _too_late(self, residual: float) -> bool:
        self._late = self._late + 1 if residual > self.max_delay_ns else 0
        return self._late >= 10

    def _add_point(self, x: int, y: float) -> None:
        buckets = self._buckets
        key = x // self.bucket_ns
        if buckets and buckets[-1][0] == key:
            if y >= buckets[-1][2]:
                return  # not a new minimum: the fit is unchanged
            buckets[-1] = (key, x, y)
        else:
            buckets.append((key, x, y))
            while x - buckets[0][1] > self.window_ns:
                buckets.popleft()
        short = buckets[-1][1] - buckets[0][1] < self.min_span_ns
        self._a, self._b = lower_envelope(
            [p[1] for p in buckets],
            [p[2] for p in buckets],
            self._b,
            0.0 if short else self.max_slope,
        )

    # ---- mapping ----------------------------------------------------------------------

    def to_host_ns(self, raw_ticks: int) -> int:
        """Host time of a sample near the latest one (within half the wrap period)."""
        if self._last_raw is None:
            raise ValueError("no sample yet: call update() first")
        step = (raw_ticks - self._last_raw) % self.wrap
        if step >= self.wrap // 2:
            step -= self.wrap
        x = (self._ticks + step - self._ref_ticks) * self.tick_ns
        return self._ref_host + x + round(self._a + self._b * x)

    @property
    def ready(self) -> bool:
        return self._last_raw is not None

    @property
    def drift_ppm(self) -> float:
        # host = (1 + b) device; a device running fast by d has 1 + b = 1 / (1 + d)
        return (1.0 / (1.0 + self._b) - 1.0) * 1e6

    @property
    def offset_ns(self) -> float:
        return self._ref_host - self._ref_ticks * self.tick_ns + self._a + self._b * self._x

    @property
    def drift_uncertainty_ppm(self) -> float | None:
        """How far the fitted drift may be off, ppm: the standard error of a straight-line
        fit through the window's bucket minima, their scatter above the envelope taken as
        _UNCERTAINTY_SCALE times their median (a bucket that was late as a whole lifts
        neither the envelope nor this). On simulated exponential jitter of 0.1-2 ms, with
        late outliers, the drift's error stayed inside it in 95 of 100 fits for spans of
        3-40 s. None until the window spans min_span_s."""
        buckets = self._buckets
        span = (buckets[-1][1] - buckets[0][1]) if buckets else 0
        if len(buckets) < 4 or span < self.min_span_ns:
            return None
        above = sorted(y - (self._a + self._b * x) for _, x, y in buckets)
        scatter = _UNCERTAINTY_SCALE * above[len(above) // 2]  # robust: a late bucket is rejected
        return scatter * (12.0 / len(buckets)) ** 0.5 / span * 1e6

    def state(self) -> ClockState:
        with self._lock:
            return self._state()

    def _state(self) -> ClockState:
        span = (self._buckets[-1][1] - self._buckets[0][1]) if self._buckets else 0
        return ClockState(
            offset_ms=self.offset_ns * 1e-6 if self.ready else 0.0,
            drift_ppm=self.drift_ppm,
            residual_ms=self._residual * 1e-6,
            span_s=clock.seconds(span),
            points=len(self._buckets),
            resets=self.resets,
            drift_uncertainty_ppm=self.drift_uncertainty_ppm,
        )


def drift_text(drift_ppm: float | None, uncertainty_ppm: float | None) -> str:
    """A drift as the operator reads it: "+48 ± 5 ppm", or that it is not fitted yet."""
    if drift_ppm is None:
        return "unknown"
    if uncertainty_ppm is None:
        return "not fitted yet (under 2 s of samples)"
    digits = 1 if uncertainty_ppm < 1 else 0
    return f"{drift_ppm:+.{digits}f} ± {max(uncertainty_ppm, 0.1):.{digits}f} ppm"


def lower_envelope(
    xs: list[int], ys: list[float], slope_guess: float = 0.0, max_slope: float = 1e-3
) -> tuple[float, float]:
    """The line y = a + b x below every point, closest to them on average.

    xs ascending. It lies along the edge of the lower convex hull under the mean x
    (a linear programme whose optimum is a hull vertex pair). With a single point, or a
    slope beyond +-max_slope, the slope is the guess or the clamp and the line touches
    the lowest point.
    """
    hull: list[tuple[int, float]] = []
    for p in zip(xs, ys):
        while len(hull) >= 2 and _cross(hull[-2], hull[-1], p) <= 0:
            hull.pop()
        hull.append(p)
    if len(hull) < 2:
        b = slope_guess
    else:
        mean_x = sum(xs) / len(xs)
        for (x0, y0), (x1, y1) in zip(hull, hull[1:]):  # noqa: B007  (the edge it stops on)
            if x1 >= mean_x:
                break
        b = (y1 - y0) / (x1 - x0)
    b = max(-max_slope, min(max_slope, b))
    a = min(y - b * x for x, y in zip(xs, ys))
    return a, b


def _cross(o: tuple[int, float], a: tuple[int, float], b: tuple[int, float]) -> float:
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
