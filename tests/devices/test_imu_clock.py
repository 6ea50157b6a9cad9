"""Device clock -> host clock: drift tracked, jitter rejected, wraps and restarts handled."""

import numpy as np
import pytest

from devices.imu.clock import WRAP, DeviceClock, lower_envelope

RATE = 100  # samples per second
TICKS_PER_SAMPLE = 10_000 // RATE


def simulate(
    seconds: float,
    drift_ppm: float = 50.0,
    jitter_ms: float = 2.0,
    latency_ms: float = 0.3,
    start_ticks: int = 123_456,
    seed: int = 0,
    spikes: float = 0.02,
    clock: DeviceClock | None = None,
    t0_ns: int = 10**12,
):
    """Feed a clock as a device would: samples on device ticks, late by latency + jitter.

    Returns the clock and per sample (true host time + latency, mapped time).
    """
    rng = np.random.default_rng(seed)
    clock = clock or DeviceClock()
    truths, mapped = [], []
    for k in range(int(seconds * RATE)):
        device_ns = k * TICKS_PER_SAMPLE * 100_000
        true_ns = t0_ns + round(device_ns / (1 + drift_ppm * 1e-6))
        delay = latency_ms * 1e6 + rng.uniform(0, jitter_ms * 1e6)
        if rng.random() < spikes:  # the occasional scheduling hiccup
            delay += rng.uniform(5e6, 40e6)
        raw = (start_ticks + k * TICKS_PER_SAMPLE) % WRAP
        mapped.append(clock.update(raw, true_ns + round(delay)))
        truths.append(true_ns + latency_ms * 1e6)
    return clock, np.array(truths), np.array(mapped, dtype=np.float64)


def test_drift_and_jitter_mapped_within_a_fraction_of_a_millisecond():
    clock, truth, mapped = simulate(10.0, drift_ppm=50.0, jitter_ms=2.0)
    err_ms = np.abs(mapped - truth) * 1e-6
    assert err_ms[3 * RATE :].max() < 0.15  # after 3 s
    assert clock.drift_ppm == pytest.approx(50.0, abs=10.0)
    state = clock.state()
    assert 0.5 < state.residual_ms < 3.0  # jitter (mean 1 ms) plus spikes, above the envelope
    assert state.resets == 0
    # The mapping is the same when asked again for an earlier sample.
    raw = (123_456 + 500 * TICKS_PER_SAMPLE) % WRAP
    assert abs(clock.to_host_ns(raw) - truth[500]) < 0.2e6


@pytest.mark.parametrize("drift", [-200.0, 0.0, 120.0])
def test_drift_estimate_follows_the_device(drift):
    clock, truth, mapped = simulate(20.0, drift_ppm=drift, jitter_ms=2.0, seed=3)
    assert clock.drift_ppm == pytest.approx(drift, abs=5.0)
    assert np.abs(mapped - truth)[5 * RATE :].max() < 0.15e6


def test_first_sample_maps_to_its_receive_time():
    clock = DeviceClock()
    assert clock.update(42, 5_000_000) == 5_000_000
    assert clock.ready


def test_sample_time_fine_wrap_is_seamless():
    start = WRAP - 3 * 10_000  # wraps 3 s in
    clock, truth, mapped = simulate(8.0, start_ticks=start, seed=1)
    assert np.abs(mapped - truth)[3 * RATE :].max() < 0.15e6
    assert clock.state().resets == 0


def test_a_device_clock_restart_refits_instead_of_mapping_far_off():
    clock, _, _ = simulate(4.0, start_ticks=5_000_000, seed=2)
    # The device restarts: its ticks begin again near 0, the host clock carries on.
    t0 = 10**12 + 10 * 10**9
    clock2, truth, mapped = simulate(3.0, start_ticks=0, seed=4, clock=clock, t0_ns=t0)
    assert clock2.state().resets == 1
    assert np.abs(mapped - truth)[RATE:].max() < 0.3e6


def test_a_forward_jump_is_detected():
    clock, _, _ = simulate(3.0, start_ticks=1000)
    host = 10**12 + 3 * 10**9
    # 10 minutes ahead on the device after 20 ms on the host: a jump, not a late sample.
    mapped = clock.update(1000 + 300 * TICKS_PER_SAMPLE + 6_000_000, host)
    assert clock.state().resets == 1
    assert mapped == host


def test_lower_envelope_ignores_points_above_the_line():
    xs = list(range(0, 100, 10))
    ys = [2.0 + 0.5 * x for x in xs]
    ys[3] += 50.0
    ys[7] += 5.0
    a, b = lower_envelope(xs, ys, max_slope=1.0)
    assert a == pytest.approx(2.0) and b == pytest.approx(0.5)
    a, b = lower_envelope([5], [3.0], slope_guess=0.25, max_slope=1.0)
    assert (a, b) == (pytest.approx(3.0 - 1.25), 0.25)


def test_a_host_stall_backlog_keeps_the_fit_when_excused():
    """Samples the host reads late after it stalled are late by the host, not a device
    clock that restarted: the fit holds and maps them where the device took them."""
    clock = DeviceClock()
    t0, period = 10**12, 10_000_000  # 100 Hz, 100 ticks a sample
    for k in range(300):  # on time
        clock.update(k * 100, t0 + k * period + 1_000_000)
    stall_end = t0 + 800 * period  # the host stood still from sample 300 to 800
    clock.excuse(stall_end)
    mapped = [clock.update(k * 100, stall_end + (k - 300) * 20_000) for k in range(300, 800)]
    assert clock.resets == 0
    errors_ms = [abs(m - (t0 + k * period)) * 1e-6 for k, m in zip(range(300, 800), mapped)]
    assert max(errors_ms) < 2.0
    for k in range(800, 1100):  # on time again
        m = clock.update(k * 100, t0 + k * period + 1_000_000)
    assert clock.resets == 0 and abs(m - (t0 + 1099 * period)) < 2_000_000
