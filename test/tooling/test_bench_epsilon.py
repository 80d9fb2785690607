"""The epsilon benchmark's quick form runs, prints its four cells and counts no grasp
where the 8-edge pyramid's Q1 exceeds the certified upper bound and no inconsistency
with the verdicts (tiny sizes; no timing asserted)."""

from bench_scripts import run_benchmark


def test_epsilon_benchmark_quick_form():
    out = run_benchmark("bench_epsilon", "--quick")
    lines = out.splitlines()
    table = [row.split() for row in lines if row[:2].strip() in ("4", "6")]
    assert [(row[0], row[1]) for row in table] == [("4", "0.500"), ("4", "0.176"),
                                                   ("6", "0.500"), ("6", "0.176")]
    for row in table:
        grasps, ours, peer = int(row[2]), float(row[4]), float(row[5])
        violations, inconsistent, unconverged = int(row[7]), int(row[8]), int(row[9])
        assert grasps == 24 and ours > 0 and peer > 0
        assert violations == 0 and inconsistent == 0 and unconverged == 0
    summary = next(line for line in lines if line.startswith("least ratio"))
    assert summary.endswith("violations 0, inconsistencies 0")
