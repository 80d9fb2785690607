"""The stall benchmark's quick form runs: service calls timed while a large batch of
12-contact grasps arrives from another process and from the same one, and the batch is
answered in full both times (no timing asserted)."""

import re

import ros_fixtures  # noqa: F401 - sets this run's own ROS_DOMAIN_ID in os.environ
from bench_scripts import run_benchmark


def test_stall_benchmark_times_calls_beside_a_batch_answered_in_full():
    out = run_benchmark("bench_stall", "--quick", timeout=300)
    for source in ("another process", "this process"):
        line = re.search(rf"batch from {source}: p50 [\d.]+ ms, p99 [\d.]+ ms, max [\d.]+ ms "
                         r"over (\d+) calls", out)
        assert line and int(line.group(1)) > 0, out
    answered = re.findall(r"the batch answered in [\d.]+ s, (\d+) of (\d+) grasps", out)
    assert len(answered) == 2 and all(a == b for a, b in answered), out
