"""The action benchmark runs end to end and prints its figures (small sizes; the
targets are not asserted: timings belong to benchmarks, not tests)."""

import os
import subprocess
import sys
from pathlib import Path

import ros_fixtures  # noqa: F401 - sets this run's own ROS_DOMAIN_ID in os.environ

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_action.py"


def test_action_benchmark_prints_every_figure_and_loses_nothing():
    done = subprocess.run(
        [sys.executable, str(SCRIPT), "--goal-grasps", "100000", "--cancels", "2",
         "--cancel-after", "0.05", "--rounds", "1"],
        capture_output=True, text=True, timeout=240, env=dict(os.environ))
    assert done.returncode == 0, done.stdout + done.stderr
    out = done.stdout
    assert "feedback:" in out and "largest gap" in out and "INCOMPLETE" not in out
    assert "cancel latency over 2 cancels: median" in out
    assert "0 lost, all equal the core" in out
    assert "throughput (medians of 1 alternating rounds): action" in out and "ratio" in out
