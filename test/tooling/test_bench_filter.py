"""The filter benchmark runs and prints its crossover table (tiny sizes; no timing asserted)."""

from bench_scripts import run_benchmark


def test_filter_benchmark_prints_costs_hit_rates_and_the_crossover():
    out = run_benchmark(
        "bench_filter", "--contacts", "4", "20", "--scale", "0.02", "--repeats", "1")
    lines = out.splitlines()
    table = [row for row in map(str.split, lines) if len(row) == 7 and row[0].isdigit()]
    assert [row[0] for row in table] == ["4"] * 3 + ["20"] * 3
    for row in table:
        filter_ms, exact_ms, hit_rate = map(float, row[2:5])
        assert filter_ms > 0 and exact_ms > 0 and 0 <= hit_rate <= 1
        assert row[6] in ("yes", "no")
    # At four contacts and mu = 0.01 nearly every grasp is rejected.
    assert float(table[0][4]) > 0.5
    assert any(line.startswith("pays for every mu at n =") for line in lines)
