"""`walkcap bench --cluster`: the printed report."""

from tests.capture.test_bench_cluster import example_report
from tui.commands import bench_corpus


def test_the_cluster_report_prints_both_speedups_and_the_cores_used():
    text = bench_corpus._format(example_report())
    assert "1.20x over one process" in text and "2.00x over one core (2.50x without)" in text
    assert "on 1.30 cores" in text
