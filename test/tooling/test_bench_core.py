"""The core benchmark script runs and prints its figures (tiny sizes; no timing asserted)."""

import pytest

from bench_scripts import run_benchmark


def test_core_benchmark_prints_per_stage_figures():
    out = run_benchmark(
        "bench_core", "--grasps", "1500", "--sweep-grasps", "200", "--repeats", "1",
        "--fingers", "6", "3", "--one-grasp-calls", "150")
    lines = out.splitlines()
    start = lines.index(next(line for line in lines if line.startswith("one grasp per")))
    table = [line.split() for line in lines[:start] if line.strip()[:2] in ("6 ", "3 ")]
    assert [row[0] for row in table] == ["6", "3"]
    assert all(float(value) > 0 for row in table for value in row[1:7])
    assert any(line.startswith("six fingers: filter") for line in lines)
    # One grasp per call against the batch, per n: grasps/s of both, their ratio, and no
    # lone verdict or status differing from the batch's.
    one = [line.split() for line in lines[start + 3:]]
    assert [row[0] for row in one] == ["3", "4", "6", "8"]
    for _, one_per_s, batch_per_s, ratio, calls, batch, verdicts, statuses in one:
        assert float(one_per_s) > 0 and float(batch_per_s) > 0
        assert float(ratio) == pytest.approx(float(one_per_s) / float(batch_per_s), rel=0.01)
        assert (int(calls), int(batch)) == (150, 200) and verdicts == statuses == "0"


def test_core_benchmark_times_the_peer_on_request():
    out = run_benchmark(
        "bench_core", "--grasps", "300", "--repeats", "1", "--fingers", "6", "--peer", "3",
        "--one-grasp-fingers")
    line = next(line for line in out.splitlines() if "Qhull peer" in line)
    assert "x faster" in line and float(line.split("peer ")[1].split(" ms")[0]) > 0
