"""Loss in a sensor stream, one definition for the live alarms, `walkcap info` and `export`.

A gap is data the device produced and the file lacks: counted on the device's own
sequence, the camera's frame index and the IMU's packet counter (16 bits, it wraps), with
the device's time (a frame's exposure, the IMU's SampleTimeFine on the session clock) to
tell a wrapped or restarted counter from a long silence. Its length is the device-time
interval the missing items fall in.

Late delivery is another figure: items that reach the host more than GAP_PERIODS periods
after the one before while the device's sequence goes on unbroken (the host stalled, the
data is all there).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

from capture.recording.metadata import DevicesRecord
from devices import clock

GAP_PERIODS = 3.0  # late delivery: a receive interval longer than this many periods
MODULUS = {"camera": None, "imu": 1 << 16}  # the sequence's wrap (None: it never wraps)
# Whether the stream's time is the device's own clock (a frame's exposure) or the host's
# estimate of it (the IMU's SampleTimeFine mapped by a fit that a host stall can move):
# only the device's own clock may say more went by than the sequence does.
OWN_CLOCK = {"camera": True, "imu": False}


@dataclass
class Gap:
    start_ns: int  # the device time of the last item before it (session clock)
    length_s: float  # device-time interval from the item before to the item after
    missing: int  # items the device produced in it and the file lacks


@dataclass
class Late:
    start_ns: int  # the host receive time of the item before it
    length_s: float  # the receive interval


@dataclass
class StreamLoss:
    """One stream's loss: gaps (data missing) and late deliveries (nothing missing)."""

    gaps: list[Gap] = field(default_factory=list)
    late: list[Late] = field(default_factory=list)

    @property
    def missing(self) -> int:
        return sum(g.missing for g in self.gaps)

    @property
    def longest_s(self) -> float:
        return max((g.length_s for g in self.gaps), default=0.0)

    @property
    def longest_late_s(self) -> float:
        return max((x.length_s for x in self.late), default=0.0)


def missing_between(
    last_seq: int,
    seq: int,
    device_dt_ns: int | None,
    period_s: float,
    modulus: int | None,
    own_clock: bool = True,
) -> int:
    """Items the device produced between two consecutive received ones.

    The sequence says it exactly; the device time decides how often a counter wrapped,
    and stands in when the sequence restarted (a power-cycled or reopened device): a
    step the time cannot hold, or, on the device's own clock, one shorter than it."""
    by_time = None
    if device_dt_ns is not None and period_s > 0:
        by_time = max(0, round(clock.seconds(device_dt_ns) / period_s) - 1)
    step = seq - last_seq - 1
    if modulus is not None:
        step %= modulus
        if by_time is not None and by_time >= modulus // 2:  # wrapped once or more
            step += modulus * round((by_time - step) / modulus)
    if by_time is not None:
        tolerance = max(2, 0.1 * by_time)
        if step < 0 or step > by_time + tolerance or (own_clock and step < by_time - tolerance):
            return by_time  # a restarted sequence: the device's time says what went by
    return max(0, step)


class LossCounter:
    """Gaps and late deliveries in one stream, counted as items arrive (thread-safe)."""

    def __init__(self, period_s: float, modulus: int | None = None, own_clock: bool = True) -> None:
        self.period_s = period_s
        self.modulus = modulus
        self.own_clock = own_clock
        self._lock = threading.Lock()
        self._last: tuple[int, int | None, int] | None = None  # seq, device ns, host ns
        self.loss = StreamLoss()

    def add(self, seq: int | None, device_ns: int | None, host_ns: int) -> Gap | Late | None:
        """One item as the file gets it; the gap or late delivery it ends, if any."""
        with self._lock:
            last, self._last = self._last, (seq, device_ns, host_ns)
            if last is None:
                return None
            last_seq, last_dev, last_host = last
            dev_dt = device_ns - last_dev if device_ns is not None and last_dev else None
            if seq is None or last_seq is None:  # no sequence: the device time alone
                if dev_dt is None:
                    return None
                missing = max(0, round(clock.seconds(dev_dt) / self.period_s) - 1)
                missing = missing if dev_dt > GAP_PERIODS * self.period_s * 1e9 else 0
            else:
                missing = missing_between(
                    last_seq, seq, dev_dt, self.period_s, self.modulus, self.own_clock
                )
            if missing > 0:
                length = clock.seconds(dev_dt) if dev_dt else (missing + 1) * self.period_s
                gap = Gap(last_dev if last_dev is not None else last_host, length, missing)
                self.loss.gaps.append(gap)
                return gap
            host_dt = host_ns - last_host
            if host_dt > GAP_PERIODS * self.period_s * 1e9:
                late = Late(last_host, clock.seconds(host_dt))
                self.loss.late.append(late)
                return late
            return None


def stream_loss(
    items: list[tuple[int | None, int | None, int]],
    period_s: float,
    modulus: int | None,
    own_clock: bool = True,
) -> StreamLoss:
    """A recorded stream's loss from its (sequence, device time, host time) in file order."""
    counter = LossCounter(period_s, modulus, own_clock)
    for seq, device_ns, host_ns in items:
        counter.add(seq, device_ns, host_ns)
    return counter.loss


# ---- a recording ----------------------------------------------------------------------

TOPICS = {"/camera/depth": "camera", "/imu": "imu"}  # the sensor streams, by topic


def recorded_periods(devices: DevicesRecord) -> dict[str, float]:
    """Each sensor topic's configured period from the file's "devices" record."""
    rates = devices.rates_hz
    return {topic: 1.0 / rates[stream] for topic, stream in TOPICS.items() if stream in rates}


_REORDER = 1024  # items held to put a stream in receive-time order


class RecordedLoss:
    """One recorded stream's loss, counted as its messages are read, in memory that does
    not grow with the file: the items reach the counter in receive-time order through a
    window of _REORDER items (walkcap's writer stores each stream in that order already).
    Without its configured rate (an old file) the period is the median device interval,
    and then every item is kept until the end."""

    def __init__(self, stream: str, period_s: float | None) -> None:
        self.stream = stream
        self.period_s = period_s
        self._heap: list = []
        self._n = 0
        self._kept: list[tuple[int | None, int | None, int]] | None = None
        self._counter: LossCounter | None = None
        if period_s is None:
            self._kept = []
        elif period_s > 0:
            self._counter = LossCounter(period_s, MODULUS[stream], OWN_CLOCK[stream])

    def add(self, seq: int | None, device_ns: int | None, host_ns: int) -> None:
        import heapq

        self._n += 1
        heapq.heappush(self._heap, (host_ns, self._n, seq, device_ns))
        if len(self._heap) > _REORDER:
            self._take(heapq.heappop(self._heap))

    def _take(self, item) -> None:
        host_ns, _, seq, device_ns = item
        if self._kept is not None:
            self._kept.append((seq, device_ns, host_ns))
        elif self._counter is not None:
            self._counter.add(seq, device_ns, host_ns)

    def loss(self) -> StreamLoss:
        import heapq

        while self._heap:
            self._take(heapq.heappop(self._heap))
        if self._kept is not None:
            items = self._kept
            device = sorted(b[1] - a[1] for a, b in zip(items, items[1:], strict=False))
            period = clock.seconds(device[len(device) // 2]) if device else 0.0
            if period <= 0:
                return StreamLoss()
            return stream_loss(items, period, MODULUS[self.stream], OWN_CLOCK[self.stream])
        return self._counter.loss if self._counter is not None else StreamLoss()


def loss_counters(devices: DevicesRecord, topics) -> dict[str, RecordedLoss]:
    """A RecordedLoss per sensor topic among `topics`, with its period from the "devices"
    record."""
    periods = recorded_periods(devices)
    return {
        topic: RecordedLoss(stream, periods.get(topic))
        for topic, stream in TOPICS.items()
        if topic in topics
    }


def recording_loss(rec) -> dict[str, StreamLoss]:
    """Each recorded sensor topic's loss (a capture.recording.reader.Recording), as the live alarms
    count it: the device's sequence in the message's sequence, its time in publish_time,
    the host's receive time in log_time. One pass over the file, messages not decoded."""
    from capture.recording.messages import damage_is_an_error, iter_raw

    counters = loss_counters(rec.meta.devices, rec.topics)
    if counters:
        with damage_is_an_error(rec.path):
            for _, channel, m in iter_raw(rec.path, rec.complete, set(counters)):
                counters[channel.topic].add(m.sequence, m.publish_time, m.log_time)
    return {topic: c.loss() for topic, c in counters.items()}
