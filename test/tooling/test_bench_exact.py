"""The exact-stage benchmark runs, prints every cell and counts no disagreement
(tiny sizes; no timing asserted)."""

from bench_scripts import run_benchmark


def test_exact_benchmark_prints_every_cell_without_disagreements():
    out = run_benchmark(
        "bench_exact", "--grasps", "150", "--repeats", "1", "--calls", "20", timeout=600)
    rows = [line.split() for line in out.splitlines()
            if line.split()[:1] in (["4"], ["6"], ["8"])]
    assert [(row[0], row[1]) for row in rows] == [
        (n, mu) for n in ("4", "6", "8") for mu in ("0.176", "0.500")]
    assert all(row[-1] == "0" for row in rows)              # disagreements
    assert all(float(row[3]) > 0 and float(row[4]) > 0 for row in rows)
    assert sum("check_force_closure" in line for line in out.splitlines()) == 5
