"""The worker-pool benchmark script runs and prints its figures (tiny sizes; no timing
asserted)."""

import re

from bench_scripts import run_benchmark


def test_pool_benchmark_prints_the_pool_against_the_core_and_the_ceiling():
    out = run_benchmark("bench_pool", "--batches", "2", "--batch-size", "300", "--rounds", "2",
                        "--workers", "2")
    rounds = [line for line in out.splitlines() if line.startswith("core ")]
    assert len(rounds) == 2
    for line in rounds:
        found = re.fullmatch(r"core +(\d+) grasps/s; core in 2 processes +(\d+) \(\d+\.\d+x\); "
                             r"pool +(\d+) \(\d+\.\d+x\); CPU per grasp: owner \d+\.\d+ us, "
                             r"workers \d+\.\d+ us", line)
        assert found and all(int(rate) > 0 for rate in found.groups()), line
    assert re.search(r"pool: median \d+\.\d+x the core in one process", out)
