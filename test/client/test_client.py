"""grasp_fc_ros.client: the client's own rules (time-outs, the in-flight window,
duplicate ids) without any node. The README's client examples run against a node in
test/tooling/test_readme_examples.py."""

from __future__ import annotations

import numpy as np
import pytest

from grasp_fc_ros.client import GraspClient

pytestmark = pytest.mark.timeout(120)

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
    with pytest.raises(TimeoutError, match="service /nobody_here/check_force_closure within "
                                           "0.3 s: its node may be down"):
        lonely.call(positions, positions, timeout=0.3)
    with pytest.raises(TimeoutError, match="/nobody_here/compute_contact_forces not found "
                                           "within 0.3 s: its node may be down"):
        lonely.compute_contact_forces(positions[0], positions[0], np.zeros(6), timeout=0.3)
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
