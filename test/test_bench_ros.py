"""The ROS benchmark script runs end to end and prints its figures (tiny sizes; the
targets are not asserted: timings belong to benchmarks, not tests)."""

import os
import subprocess
import sys
from pathlib import Path

import ros_fixtures  # noqa: F401 - sets this run's own ROS_DOMAIN_ID in os.environ

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_ros.py"


def test_ros_benchmark_prints_every_figure_without_losing_queries():
    done = subprocess.run(
        [sys.executable, str(SCRIPT), "--queries", "300", "--batches", "2",
         "--batch-size", "100", "--service-calls", "20"],
        capture_output=True, text=True, timeout=240, env=dict(os.environ))
    assert done.returncode == 0, done.stdout + done.stderr
    out = done.stdout
    assert "single-grasp topic:" in out and "no loss, in order" in out
    assert "batches of 100:" in out and "INCOMPLETE" not in out
    assert "service round trip (one grasp): p50" in out
    assert "no core work (invalid query): p50" in out
