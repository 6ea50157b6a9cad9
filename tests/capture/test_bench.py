"""The bench's own bookkeeping: what it records must be every frame, and must not grow the
memory it measures."""

import numpy as np
import pytest

from capture import bench


def test_latency_log_keeps_every_value_in_order_past_its_expected_size():
    log = bench.LatencyLog(expected_frames=10)
    for k in range(3000):  # past the minimum allocation: it has to grow
        log.append(float(k))
    assert len(log) == 3000
    assert np.array_equal(np.asarray(log), np.arange(3000.0))
    assert np.array_equal(log.since(2990), np.arange(2990.0, 3000.0))
    log.since(0)[0] = -1.0  # a copy: the reader cannot change the record
    assert np.asarray(log)[0] == 0.0


def test_latency_log_does_not_allocate_while_it_fills_its_expected_size():
    log = bench.LatencyLog(expected_frames=5000)
    values = log._values
    for _ in range(5000):
        log.append(1.0)
    assert log._values is values


def test_empty_latency_log_is_false_like_the_sessions_deque():
    assert not bench.LatencyLog(100)


def test_rss_growth_tells_a_leak_from_memory_that_levels_off():
    t = np.arange(0, 1201, 10.0)
    leak = [(s, 300 + 0.5 * s / 60) for s in t]
    level = [(s, 300 + 8 * (1 - np.exp(-s / 120))) for s in t]
    total, late = bench.rss_growth_mib_per_min(leak)
    assert abs(total - 0.5) < 1e-6 and abs(late - 0.5) < 1e-6
    total, late = bench.rss_growth_mib_per_min(level)
    assert total > 0.1 and abs(late) < 0.01


def test_rss_growth_ignores_the_first_minute_and_needs_samples():
    warm_up_then_flat = [(0.0, 280.0), (30.0, 295.0)] + [(s, 300.0) for s in range(60, 400, 10)]
    assert all(abs(g) < 1e-9 for g in bench.rss_growth_mib_per_min(warm_up_then_flat))
    assert np.isnan(bench.rss_growth_mib_per_min([(0.0, 1.0), (10.0, 2.0)])[0])


@pytest.mark.realtime
@pytest.mark.slow
def test_a_session_run_records_one_latency_per_frame(tmp_path):
    samples = []
    run = bench.session_run(
        15.0,
        100,
        3.0,
        str(tmp_path),
        sample_every_s=1.0,
        on_sample=lambda snap, memory, recent: samples.append(len(recent)),
    )
    assert run.frames > 20
    assert len(run.latency_ms) == run.frames
    assert sum(samples) <= run.frames and len(samples) >= 2
    assert np.all(np.isfinite(run.latency_ms)) and np.all(run.latency_ms > 0)
    assert len(run.rss_mib) == len(samples)


@pytest.mark.realtime
@pytest.mark.slow
def test_soak_prints_strict_json_with_its_summary(capsys):
    import json

    from tui import cli

    assert cli.main(["bench", "--soak", "0.05", "--json"]) == 0

    def no_nan(name):
        raise AssertionError(f"{name} is not JSON")

    report = json.loads(capsys.readouterr().out, parse_constant=no_nan)
    summary = report["summary"]
    assert summary["frames"] > 50 and summary["latency_p99_ms"] > 0
    assert summary["rss_growth_mib_per_min"] is None  # 3 s cannot tell a slope
    assert report["samples"][0]["rss_mib"] > 0
