"""The ROS benchmark script runs end to end and prints its figures (tiny sizes; the
targets are not asserted: timings belong to benchmarks, not tests)."""

import ros_fixtures  # noqa: F401 - sets this run's own ROS_DOMAIN_ID in os.environ
from bench_scripts import run_benchmark


def test_ros_benchmark_prints_every_figure_without_losing_queries():
    out = run_benchmark(
        "bench_ros", "--queries", "300", "--batches", "2", "--batch-size", "100",
        "--service-calls", "20", "--big-batch", "20000", timeout=240)
    assert "single-grasp topic:" in out and "no loss, in order" in out
    assert "batches of 100:" in out and "INCOMPLETE" not in out
    assert "service round trip (one grasp): p50" in out
    assert "no core work (invalid query): p50" in out
