"""The core benchmark script runs and prints its figures (tiny sizes; no timing asserted)."""

from bench_scripts import run_benchmark


def test_core_benchmark_prints_per_stage_figures():
    out = run_benchmark(
        "bench_core", "--grasps", "1500", "--sweep-grasps", "200", "--repeats", "1",
        "--fingers", "6", "3")
    lines = out.splitlines()
    table = [line.split() for line in lines if line.strip()[:2] in ("6 ", "3 ")]
    assert [row[0] for row in table] == ["6", "3"]
    assert all(float(value) > 0 for row in table for value in row[1:7])
    assert any(line.startswith("six fingers: filter") for line in lines)


def test_core_benchmark_times_the_peer_on_request():
    out = run_benchmark(
        "bench_core", "--grasps", "300", "--repeats", "1", "--fingers", "6", "--peer", "3")
    line = next(line for line in out.splitlines() if "Qhull peer" in line)
    assert "x faster" in line and float(line.split("peer ")[1].split(" ms")[0]) > 0
