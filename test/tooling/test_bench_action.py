"""The action benchmark runs end to end and prints its figures (small sizes; the
targets are not asserted: timings belong to benchmarks, not tests)."""

import ros_fixtures  # noqa: F401 - sets this run's own ROS_DOMAIN_ID in os.environ
from bench_scripts import run_benchmark


def test_action_benchmark_prints_every_figure_and_loses_nothing():
    out = run_benchmark(
        "bench_action", "--goal-grasps", "100000", "--cancels", "2", "--cancel-after",
        "0.05", "--rounds", "1", timeout=240)
    assert "feedback:" in out and "largest gap" in out and "INCOMPLETE" not in out
    assert "cancel latency over 2 cancels: median" in out
    assert "0 lost, all equal the core" in out
    assert "throughput (medians of 1 alternating rounds): action" in out and "ratio" in out
