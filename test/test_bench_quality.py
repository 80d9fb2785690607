"""The quality benchmark script runs and prints its figures (tiny sizes; no timing asserted)."""

import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_quality.py"


def test_quality_benchmark_prints_its_figures():
    done = subprocess.run(
        [sys.executable, str(SCRIPT), "--grasps", "40", "--repeats", "1", "--fingers", "6"],
        capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    row = next(line.split() for line in lines if line.strip().startswith("6 "))
    assert row[1] == "40" and all(float(v) > 0 for v in row[2:6])
    assert any(line.startswith("six fingers: mu*") for line in lines)
    assert any("unresolved 0" in line for line in lines)
