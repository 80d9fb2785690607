"""The exact-stage benchmark runs, prints every cell and counts no disagreement
(tiny sizes; no timing asserted)."""

import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_exact.py"


def test_exact_benchmark_prints_every_cell_without_disagreements():
    done = subprocess.run(
        [sys.executable, str(SCRIPT), "--grasps", "150", "--repeats", "1", "--calls", "20"],
        capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    rows = [line.split() for line in done.stdout.splitlines()
            if line.split()[:1] in (["4"], ["6"], ["8"])]
    assert [(row[0], row[1]) for row in rows] == [
        (n, mu) for n in ("4", "6", "8") for mu in ("0.176", "0.500")]
    assert all(row[-1] == "0" for row in rows)              # disagreements
    assert all(float(row[3]) > 0 and float(row[4]) > 0 for row in rows)
    assert sum("check_force_closure" in line for line in done.stdout.splitlines()) == 5
