"""What every device driver watches the same way: silence, and repeated faults.

`SilenceWatch` measures how long a device has been silent without counting the host's
own stalls: when the loop that checks runs late (the process stopped, swapped, starved),
the data the device sent meanwhile is still on its way, so silence counts from the end of
that stall. `EventThrottle` reports a fault that repeats (a checksum error, a dropped
frame) at most once an interval, with the count since the last report. The IMU driver and
the camera base class both use them.
"""

from __future__ import annotations

from collections.abc import Callable

EVENT_INTERVAL_NS = 1_000_000_000  # repeated faults of one kind: one event a second


class SilenceWatch:
    """Silence since the last datum, the host's own stalls excused."""

    def __init__(self, host_stall_ns: int) -> None:
        self.host_stall_ns = host_stall_ns  # a check this late: the host stalled
        self.last_check_ns = 0
        self.resumed_ns = 0  # the end of the last host stall

    def check(self, t: int) -> bool:
        """Note a check at t; True when the pause since the previous check was a host stall."""
        stalled = bool(self.last_check_ns) and t - self.last_check_ns > self.host_stall_ns
        if stalled:
            self.resumed_ns = t
        self.last_check_ns = max(self.last_check_ns, t)
        return stalled

    def since(self, last_ns: int) -> int:
        """When silence starts counting: the last datum, or the end of a later host stall."""
        return max(last_ns, self.resumed_ns)


class EventThrottle:
    """Counts of repeated faults, reported per kind at most once every `interval_ns`.

    The first of a kind is reported at once; the ones after it within the interval are
    counted and reported together when the interval has passed (at the next `add` or
    `flush`). `report(kind, count, t)` makes the event.
    """

    def __init__(
        self, report: Callable[[str, int, int], None], interval_ns: int = EVENT_INTERVAL_NS
    ) -> None:
        self._report = report
        self.interval_ns = interval_ns
        self._pending: dict[str, list[int]] = {}  # kind -> [last report time, count since]

    def add(self, kind: str, n: int, t: int) -> None:
        pending = self._pending.setdefault(kind, [0, 0])
        pending[1] += n
        if t - pending[0] >= self.interval_ns:
            self._flush(kind, t)

    def flush(self, t: int) -> None:
        """Report the counts whose interval has passed."""
        for kind, (last, count) in self._pending.items():
            if count and t - last >= self.interval_ns:
                self._flush(kind, t)

    def _flush(self, kind: str, t: int) -> None:
        pending = self._pending[kind]
        count, pending[1], pending[0] = pending[1], 0, t
        self._report(kind, count, t)
