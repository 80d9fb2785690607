"""The quality benchmark script runs and prints its figures (tiny sizes; no timing asserted)."""

from bench_scripts import run_benchmark


def test_quality_benchmark_prints_its_figures():
    out = run_benchmark(
        "bench_quality", "--grasps", "40", "--repeats", "1", "--fingers", "6")
    lines = out.splitlines()
    row = next(line.split() for line in lines if line.strip().startswith("6 "))
    assert row[1] == "40" and all(float(v) > 0 for v in row[2:6])
    assert any(line.startswith("six fingers: mu*") for line in lines)
    assert any("unresolved 0" in line for line in lines)
