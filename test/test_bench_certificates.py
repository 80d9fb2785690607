"""The certificates benchmark runs end to end and prints a line per setting (tiny sizes;
timings are not asserted)."""

import os
import subprocess
import sys
from pathlib import Path

import ros_fixtures  # noqa: F401 - sets this run's own ROS_DOMAIN_ID in os.environ

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_certificates.py"


def test_certificates_benchmark_prints_every_setting_without_losing_queries():
    done = subprocess.run([sys.executable, str(SCRIPT), "--batches", "1", "--batch-size",
                           "40", "--queries", "50"],
                          capture_output=True, text=True, timeout=300, env=dict(os.environ))
    assert done.returncode == 0, done.stdout + done.stderr
    lines = done.stdout.splitlines()
    for tag in ("off", "certificates", "certificates+min_friction"):
        line = next(x for x in lines if x.strip().startswith(tag + " "))
        assert "B/grasp" in line and "INCOMPLETE" not in line and "LOST" not in line
