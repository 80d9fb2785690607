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


def test_exact_benchmark_against_an_old_commit_prints_every_cell_or_says_why_not():
    out = run_benchmark("bench_exact", "--against", "e89657b", "--grasps", "60",
                        "--repeats", "1", timeout=600)
    if "git history not available" in out:       # a checkout without that history
        return
    rows = [line.split() for line in out.splitlines()
            if line.split()[:1] in (["4"], ["6"], ["8"])]
    assert [(row[0], row[1]) for row in rows] == [
        (n, mu) for n in ("4", "6", "8") for mu in ("0.176", "0.500")]
    for row in rows:
        old, verdicts, ratio, margin, margin_ratio, disagree = (
            float(row[3]), float(row[4]), row[5], float(row[6]), row[7], row[8])
        assert old > 0 and verdicts > 0 and margin > 0
        assert ratio.endswith("x") and margin_ratio.endswith("x") and disagree == "0"


def test_exact_benchmark_says_so_when_the_commit_is_not_in_the_history():
    out = run_benchmark("bench_exact", "--against", "0123456789abcdef", "--grasps", "60",
                        "--repeats", "1")
    assert "--against 0123456789abcdef: git history not available" in out
    assert "nothing measured" in out
