"""Heel contact and toe off from the thigh IMU, sample by sample.

The method is Grimmer et al.'s (2019, "Stance and swing detection based on the angular
velocity of lower limb segments during walking", Front. Neurorobot. 13:57): the thigh
flexes through swing and extends through stance, so the sign of its sagittal angular
velocity tells the two apart and its sign changes mark the events. A swing ends at the
thigh's peak flexion (the rate turns from flexing to extending), a stance at its peak
extension (the rate turns back). With IMUs they needed rule sets against noise; here:
- hysteresis: a phase begins only once the rate passes `on_rad_s` the other way, and the
  sign change it began with is the one interpolated between samples;
- a phase counts only when it is one of walking: at least `min_phase_s` long, its rate
  reaching `swing_rad_s` (flexing) or `stance_rad_s` (extending), the thigh's flexion
  changing by `min_range_deg` over it. Standing, shifting weight or turning on the spot
  (a rotation about the vertical, which the thigh's mediolateral axis barely feels) makes
  none;
- the thigh's sign changes lead the events (Grimmer et al. found the IMU-based heel
  strikes early; the thigh peaks in flexion late in swing, before the foot lands, and in
  extension late in stance, before the toes leave): the event is placed a fixed share of
  the current stride after its sign change (`heel_contact_lag`, `toe_off_lag`), and
  emitted once a sample at or after that time arrives;
- a gap (samples missing by the packet counter, or a step in time over `max_gap_s`)
  forgets everything but the stride's length: an event pending is dropped, and a phase
  seen only in part after the gap must meet the same rules on what follows it. No event
  is ever placed inside a gap or on evidence from both sides of one.

Input: ImuSamples (rate of turn in the sensor frame, orientation sensor -> world, time on
the session clock), the sensor's body frame the thigh's (x forward, y left, z up when
standing: devices/frames.py), so flexion turns about -y. Output: GaitEvent(source="imu").
Pure: no clock, no threads; the session, replay and synth feed it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from devices import clock
from devices.frames import GaitEvent, ImuSample

COUNTER_MODULO = 65536  # the Xsens packet counter's wrap


@dataclass(frozen=True)
class GaitParams:
    """The detector's rules (module doc). The lags are shares of a stride; the rest SI."""

    on_rad_s: float = 0.3  # hysteresis: a phase begins once the rate passes this
    swing_rad_s: float = 0.8  # the flexing rate a swing reaches
    stance_rad_s: float = 0.4  # the extending rate a stance reaches
    min_range_deg: float = 8.0  # flexion change over a swing or a stance
    min_phase_s: float = 0.15  # the shortest swing or stance
    heel_contact_lag: float = 0.05  # peak flexion -> heel contact, share of the stride
    toe_off_lag: float = 0.15  # peak extension -> toe off, share of the stride
    max_gap_s: float = 0.04  # a longer step between samples is a gap
    stride_s: float = 1.15  # the stride assumed until two strides are seen
    stride_range_s: tuple[float, float] = (0.6, 3.0)  # strides measured outside are not
    walking_strides: float = 2.5  # cadence is shown while a heel contact is this recent


class GaitDetector:
    """Streaming gait events of the instrumented leg: `push(sample)` -> new GaitEvents."""

    def __init__(self, params: GaitParams | None = None) -> None:
        self.params = params or GaitParams()
        self.stride_s = self.params.stride_s
        self.heel_contacts = 0  # counted since the start (gaps do not reset them)
        self.toe_offs = 0
        self.gaps = 0
        self.last_heel_contact_ns: int | None = None
        self.last_time_ns: int | None = None
        self._counter: int | None = None
        self._forget()

    def _forget(self) -> None:
        """After a gap (or at the start): nothing of the signal before it is used."""
        self._prev: tuple[int, float, float] | None = None  # (time ns, rate, flexion)
        self._state: str | None = None  # "flex" (swing), "ext" (stance), None: unknown
        self._crossing_ns: int | None = None  # the latest sign change of the rate
        self._phase_start_ns: int | None = None
        self._peak_rate = 0.0  # the phase's largest rate in its own direction
        self._flex_lo, self._flex_hi = math.inf, -math.inf  # the phase's flexion range
        self._pending: GaitEvent | None = None
        self._stance = False  # a heel contact began this stride's stance
        self._last_peak_ns: int | None = None  # the last swing's end, for the stride

    def reset(self) -> None:
        self.__init__(self.params)

    # ---- what the screens show ---------------------------------------------------------

    def cadence_spm(self, now_ns: int | None = None) -> float | None:
        """Steps a minute (both legs: two a stride) while walking, else None."""
        now = self.last_time_ns if now_ns is None else now_ns
        last = self.last_heel_contact_ns
        if now is None or last is None:
            return None
        if now - last > self.params.walking_strides * self.stride_s * 1e9:
            return None
        return 120.0 / self.stride_s

    # ---- the stream --------------------------------------------------------------------

    def push(self, sample: ImuSample) -> list[GaitEvent]:
        t = sample.time_ns if sample.time_ns is not None else sample.host_time_ns
        signal = _signal(sample)
        out: list[GaitEvent] = []
        if self._is_gap(t, sample.packet_counter) or signal is None:
            self.gaps += 1
            self._forget()
        self.last_time_ns = t
        if signal is None:
            return out
        rate, flexion = signal
        if rate is None:  # no rate of turn: the orientation's own change
            if self._prev is None or t <= self._prev[0]:
                self._prev = (t, math.nan, flexion)
                return out
            rate = (flexion - self._prev[2]) / clock.seconds(t - self._prev[0])
        pending = self._pending
        if pending is not None and t >= pending.time_ns:
            out.append(self._emit(pending))
        self._step(t, rate, flexion)
        self._prev = (t, rate, flexion)
        return out

    def flush(self) -> list[GaitEvent]:
        """Nothing more comes: an event still pending is not placed (its time is unseen)."""
        self._pending = None
        return []

    def _is_gap(self, t: int, counter: int | None) -> bool:
        prev, last = self._prev, self._counter
        # samples the packet counter says are missing (a repeat or a step back is none)
        step = (counter - last) % COUNTER_MODULO if counter is not None and last is not None else 1
        missing = 1 < step < COUNTER_MODULO // 2
        if counter is not None:
            self._counter = counter
        if prev is None:
            return False
        dt = clock.seconds(t - prev[0])
        limit = self.params.max_gap_s
        return dt <= 0 or dt > limit or (missing and dt > limit / 2)

    def _emit(self, event: GaitEvent) -> GaitEvent:
        self._pending = None
        if event.event == "heel_contact":
            self.heel_contacts += 1
            self.last_heel_contact_ns = event.time_ns
            self._stance = True
        else:
            self.toe_offs += 1
            self._stance = False
        return event

    def _step(self, t: int, rate: float, flexion: float) -> None:
        p = self.params
        prev = self._prev
        if prev is not None and math.isfinite(prev[1]) and (prev[1] < 0) != (rate < 0):
            # the sign change, interpolated between the two samples
            u = prev[1] / (prev[1] - rate) if prev[1] != rate else 1.0
            self._crossing_ns = prev[0] + round(u * (t - prev[0]))
        state = self._state
        if state != "flex" and rate > p.on_rad_s:
            if state == "ext" and self._phase_ok(p.stance_rad_s) and self._stance:
                self._schedule("toe_off", p.toe_off_lag)
            self._begin("flex", t)
        elif state != "ext" and rate < -p.on_rad_s:
            if state == "flex" and self._phase_ok(p.swing_rad_s):
                self._swing_ended()
                self._schedule("heel_contact", p.heel_contact_lag)
            self._begin("ext", t)
        if self._state is not None:
            self._peak_rate = max(self._peak_rate, rate if self._state == "flex" else -rate)
            self._flex_lo = min(self._flex_lo, flexion)
            self._flex_hi = max(self._flex_hi, flexion)

    def _phase_ok(self, rate_needed: float) -> bool:
        p = self.params
        start, end = self._phase_start_ns, self._crossing_ns
        if start is None or end is None or end <= start:
            return False
        return (
            clock.seconds(end - start) >= p.min_phase_s
            and self._peak_rate >= rate_needed
            and math.degrees(self._flex_hi - self._flex_lo) >= p.min_range_deg
        )

    def _swing_ended(self) -> None:
        """Peak flexion: the stride's length from the last one, when it is a stride's."""
        peak = self._crossing_ns
        lo, hi = self.params.stride_range_s
        if self._last_peak_ns is not None and peak is not None:
            stride = clock.seconds(peak - self._last_peak_ns)
            if lo <= stride <= hi:
                self.stride_s = stride
        self._last_peak_ns = peak

    def _schedule(self, event: str, lag: float) -> None:
        at = self._crossing_ns + round(lag * self.stride_s * 1e9)
        self._pending = GaitEvent(int(at), event, "imu")

    def _begin(self, state: str, t: int) -> None:
        # a phase begins at the sign change that led into it (if seen since the last gap)
        crossing = self._crossing_ns
        self._state = state
        self._phase_start_ns = crossing if crossing is not None and self._prev else t
        self._peak_rate = 0.0
        self._flex_lo, self._flex_hi = math.inf, -math.inf


def _signal(sample: ImuSample) -> tuple[float | None, float] | None:
    """(flexion rate rad/s or None, flexion rad) of a sample; None without an orientation."""
    q = sample.quaternion
    if q is None or not all(math.isfinite(float(v)) for v in q):
        return None
    w, x, y, z = (float(v) for v in q)
    norm = w * w + x * x + y * y + z * z
    if norm <= 0:
        return None
    # the body x axis' elevation above the horizon: flexion, whatever the heading
    flexion = math.asin(max(-1.0, min(1.0, 2.0 * (x * z - w * y) / norm)))
    rate = None
    r = sample.rate_of_turn
    if r is not None and math.isfinite(float(r[1])):
        rate = -float(r[1])  # flexion turns about the thigh's -y (left) axis
    return rate, flexion


# ---- judged against a reference (the simulator's truth, or a lab's insoles) -----------------


def detect(samples) -> list[GaitEvent]:
    """Every event of a stream of ImuSamples, in order (one detector, start to end)."""
    detector = GaitDetector()
    return [event for sample in samples for event in detector.push(sample)]


def match_events(truth_ns, detected_ns, tolerance_ns: int) -> list[tuple[int, int]]:
    """(truth index, detection index) pairs, one-to-one, each within `tolerance_ns`: in time
    order, each true event takes the nearest detection not taken yet."""
    import numpy as np

    truth = np.asarray(truth_ns, dtype=np.int64)
    found = np.asarray(detected_ns, dtype=np.int64)
    order = np.argsort(found, kind="stable")
    found_sorted = found[order]
    taken = np.zeros(len(found), dtype=bool)
    pairs = []
    for i in np.argsort(truth, kind="stable"):
        j = int(np.searchsorted(found_sorted, truth[i]))
        best = None
        for k in range(max(0, j - 2), min(len(found_sorted), j + 2)):
            d = abs(int(found_sorted[k]) - int(truth[i]))
            if not taken[k] and d <= tolerance_ns and (best is None or d < best[0]):
                best = (d, k)
        if best is not None:
            taken[best[1]] = True
            pairs.append((int(i), int(order[best[1]])))
    return pairs


@dataclass(frozen=True)
class EventScore:
    """One event kind's detection against a reference: counts and timing (detected - true)."""

    true: int
    detected: int
    matched: int
    errors_ms: tuple[float, ...]

    @property
    def recall(self) -> float | None:
        """Share of the true events detected within the tolerance."""
        return self.matched / self.true if self.true else None

    @property
    def precision(self) -> float | None:
        """Share of the detected events that are a true one within the tolerance."""
        return self.matched / self.detected if self.detected else None

    def __add__(self, other: EventScore) -> EventScore:
        return EventScore(
            self.true + other.true,
            self.detected + other.detected,
            self.matched + other.matched,
            self.errors_ms + other.errors_ms,
        )


def score_events(truth_ns, detected_ns, tolerance_ns: int) -> EventScore:
    pairs = match_events(truth_ns, detected_ns, tolerance_ns)
    errors = tuple((int(detected_ns[j]) - int(truth_ns[i])) * 1e-6 for i, j in pairs)
    return EventScore(len(truth_ns), len(detected_ns), len(pairs), errors)
