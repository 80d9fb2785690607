"""The worker-fault benchmark's quick form runs and loses no grasp: a worker SIGKILLed
mid-batch through the node and on the pool alone (no timing asserted)."""

import re

import ros_fixtures  # noqa: F401 - sets this run's own ROS_DOMAIN_ID in os.environ
from bench_scripts import run_benchmark


def test_fault_benchmark_kills_a_worker_and_loses_no_grasp():
    out = run_benchmark("bench_faults", "--quick")
    results = [line for line in out.splitlines() if line.startswith(("node,", "engine,"))]
    assert len(results) == 2, out
    for line in results:
        found = re.search(r"worker \d+ SIGKILLed mid-request; .*; (\d+) failures, "
                          r"(\d+) verdicts differ from the core's", line)
        assert found and found.groups() == ("0", "0"), line
    assert "no grasp lost to a worker's death: meets target" in out
