import numpy as np

from devices.clock import seconds, to_ns


def test_seconds_is_the_ns_times_1e_9_every_site_computes():
    times = np.array([0, 1, 66_666_667, 1_700_000_000_123_456_789], dtype=np.int64)
    assert seconds(66_666_667) == 66_666_667 * 1e-9
    np.testing.assert_array_equal(seconds(times - times[0]), (times - times[0]) * 1e-9)


def test_to_ns_is_the_nearest_nanosecond():
    assert to_ns(1.001) == 1_001_000_000  # int(1.001 * 1e9) truncates to 1_000_999_999
    assert to_ns(0.25) == 250_000_000
    assert to_ns(-0.5) == -500_000_000
    assert isinstance(to_ns(np.float64(2.0)), int)
