"""The labelling benchmark script runs and prints its figures (tiny sizes; no timing asserted)."""

import re

from bench_scripts import run_benchmark


def test_label_benchmark_prints_scaling_and_memory():
    out = run_benchmark("bench_label", "--quick")

    def number(pattern):
        match = re.search(pattern, out)
        assert match, (pattern, out)
        return float(match.group(1).replace(",", ""))

    assert number(r"core in-process, 1 core\s+:\s+([\d,]+) grasps/s") > 0
    for workers in (1, 2):
        assert number(rf"{workers} worker\(s\) :\s+([\d,]+) grasps/s") > 0
    assert number(r"2 workers / 1 worker\s+:\s+([\d.]+)x") > 0
    assert "60,000 three-finger grasps" in out
    peaks = re.search(r"large run .* worker peak RSS (\d+), (\d+) MiB", out)
    assert peaks and all(0 < float(p) < 4096 for p in peaks.groups())
