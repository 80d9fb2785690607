"""The soft-contact benchmark runs, counts no unsound rejection, prints its cost table
(tiny sizes; no timing asserted)."""

from bench_scripts import run_benchmark


def test_soft_benchmark_counts_rejections_and_prints_costs():
    out = run_benchmark(
        "bench_soft", "--grasps", "3000", "--cost-grasps", "40", "--contacts", "4",
        "--repeats", "1")
    lines = out.splitlines()
    assert "force-closure grasps rejected: 0" in lines[0]
    assert int(lines[0].split(", ")[2].split()[0]) > 0          # some rejections
    table = [row for row in map(str.split, lines) if len(row) == 10 and row[0].isdigit()]
    assert [row[0] for row in table] == ["4"]
    assert all(float(value) >= 0 for value in table[0][1:])
