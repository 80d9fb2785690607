"""Four client processes at once beside a busy process: each gets exactly its own
answers (ids 0..N-1, none lost, none of another client's), whole batches too; the
script's quick form (sizes small; its rates are not asserted)."""

import re

import ros_fixtures  # noqa: F401 - sets this run's own ROS_DOMAIN_ID in os.environ
from bench_scripts import run_benchmark


def test_four_clients_under_load_each_get_exactly_their_own_answers():
    out = run_benchmark("bench_clients", "--quick", timeout=240)
    assert len(re.findall(r"client \d: 2000 answered, 0 lost, 0 wrong, batch answered whole",
                          out)) == 4, out
    assert "lost answers: 0 (target 0); wrong answers: 0; batches answered whole: 4 of 4" in out
    assert "single queries/s" in out
