"""grasp_fc_ros.client: the README example against a node process, and the client's
own rules (time-outs, the in-flight window, duplicate ids) without any node."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from ros_fixtures import NodeProcess, node_command

from grasp_fc_ros.client import GraspClient

pytestmark = pytest.mark.timeout(120)

README = Path(__file__).resolve().parents[2] / "README.md"


def readme_example() -> str:
    section = README.read_text().split("### From Python: `grasp_fc_ros.client`", 1)[1]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_readme_example_runs_against_a_node_process():
    # A domain of its own (101..200): the example talks to the default node name, which
    # other tests of this run also start.
    env = dict(os.environ, ROS_DOMAIN_ID=str(101 + os.getpid() % 100))
    node = NodeProcess(node_command(), env)
    try:
        done = subprocess.run([sys.executable, "-c", readme_example()], capture_output=True,
                              text=True, timeout=90, env=env)
    finally:
        node.stop(signal.SIGTERM)
    assert done.returncode == 0, done.stderr
    # "[0 2 0 ...] 0 [0 0]": the batch's statuses, one single verdict, two from the service.
    first, single, served = re.match(r"^\[([\d\s]+)\] (\d) \[([\d\s]+)\]$",
                                     done.stdout.strip(), re.S).groups()
    batch = np.array(first.split(), dtype=int)
    assert len(batch) == 100 and set(batch) <= {0, 1, 2}
    assert int(single) == batch[0] and served.split() == [str(b) for b in batch[:2]]


@pytest.fixture
def lonely(ros):
    """A client of a node that does not exist."""
    client = GraspClient("/nobody_here/force_closure", max_in_flight=3)
    yield client
    client.close()


def test_waits_and_calls_time_out_without_a_node(lonely):
    positions = np.ones((1, 4, 3))
    assert lonely.wait_for_node(timeout=0.5) is False
    with pytest.raises(TimeoutError):
        lonely.check_batch(positions, positions, timeout=0.3)
    with pytest.raises(TimeoutError):
        lonely.call(positions, positions, timeout=0.3)
    with pytest.raises(TimeoutError):
        lonely.next_diagnostics(timeout=0.3)


def test_window_of_unanswered_queries_is_enforced(lonely):
    contacts = np.ones((4, 3))
    futures = [lonely.submit(contacts, contacts, query_id=i) for i in range(3)]
    assert lonely.in_flight == 3
    with pytest.raises(TimeoutError, match="3 queries unanswered"):
        lonely.submit(contacts, contacts, query_id=3, timeout=0.3)
    with pytest.raises(ValueError, match="query id 1 is already in flight"):
        lonely.submit(contacts, contacts, query_id=1)
    lonely.close()
    assert all(f.cancelled() for f in futures)


def test_queries_are_stamped_with_the_clients_ros_clock(lonely):
    """System time unless ROS time is active (use_sim_time), then the ROS clock: 0
    before the first /clock message."""
    import time

    from rclpy.parameter import Parameter

    from grasp_fc_ros.client.single_queries import stamp

    before = time.time()
    sec, nanosec = stamp(lonely.node.get_clock())
    assert before - 1.0 <= sec + nanosec * 1e-9 <= time.time() + 1.0
    assert 0 <= nanosec < 1_000_000_000
    lonely.node.set_parameters([Parameter("use_sim_time", Parameter.Type.BOOL, True)])
    assert lonely.node.get_clock().ros_time_is_active
    assert stamp(lonely.node.get_clock()) == (0, 0)
