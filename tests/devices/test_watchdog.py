"""The watch every device driver shares: silence with the host's stalls excused, and
repeated faults reported at most once an interval with their count."""

from devices.watchdog import EventThrottle, SilenceWatch

S = 1_000_000_000


def test_a_repeated_fault_is_reported_at_once_then_counted_until_the_interval_has_passed():
    reports = []
    throttle = EventThrottle(lambda kind, n, t: reports.append((kind, n, t)), interval_ns=S)
    throttle.add("checksum_error", 1, 10 * S)
    throttle.add("checksum_error", 2, 10 * S + S // 2)
    throttle.add("checksum_error", 3, 10 * S + S // 2 + 1)
    throttle.flush(10 * S + S // 2 + 2)  # within the interval: held
    assert reports == [("checksum_error", 1, 10 * S)]
    throttle.flush(11 * S)
    assert reports[-1] == ("checksum_error", 5, 11 * S)
    throttle.flush(13 * S)  # nothing new: nothing said
    assert len(reports) == 2


def test_kinds_are_throttled_apart():
    reports = []
    throttle = EventThrottle(lambda kind, n, t: reports.append((kind, n)), interval_ns=S)
    throttle.add("drop", 4, 5 * S)
    throttle.add("resync", 1, 5 * S)
    assert reports == [("drop", 4), ("resync", 1)]


def test_silence_counts_from_the_end_of_a_host_stall_not_from_the_last_datum():
    watch = SilenceWatch(host_stall_ns=S // 4)
    assert not watch.check(100 * S)
    assert not watch.check(100 * S + S // 10)  # checks on time
    assert watch.since(99 * S) == 99 * S
    assert watch.check(103 * S)  # three seconds without a check: the host stalled
    assert watch.since(99 * S) == 103 * S  # the data sent meanwhile is still on its way
    assert watch.since(104 * S) == 104 * S
