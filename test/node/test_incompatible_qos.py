"""Peers whose QoS the node cannot match are counted in /diagnostics, with the policy
named, and the status is WARN while they are there: a BEST_EFFORT publisher of queries
(on ``contacts``, and on ``contacts_batch``, which a second DDS participant subscribes),
a TRANSIENT_LOCAL subscriber of answers; compatible peers are not counted."""

from __future__ import annotations

import time

import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from grasp_fc_msgs.msg import ContactArray, ContactArrayBatch, ForceClosureVerdict
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

pytestmark = pytest.mark.timeout(120)

NAMESPACE = "/incompatible_qos_test"
NODE = f"{NAMESPACE}/force_closure"
WAIT_S = 30.0
BEST_EFFORT = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
TRANSIENT_LOCAL = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)


def status_where(client, wanted, timeout=WAIT_S) -> DiagnosticStatus:
    """The first status of the node published from now on for which ``wanted(level,
    message, key values)`` holds."""
    since = time.time()

    def find():
        for msg in client.diagnostics:
            stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
            for status in msg.status:
                values = {kv.key: kv.value for kv in status.values}
                if (stamp > since and status.name.startswith(NODE + ":")
                        and wanted(status.level, status.message, values)):
                    return status
        return None

    with client._lock:
        assert client._lock.wait_for(lambda: find() is not None, timeout), (
            f"no such diagnostics within {timeout} s; last: {client.diagnostics[-1:]}")
        return find()


def test_incompatible_publishers_and_subscribers_are_counted_while_there(own_node,
                                                                         monkeypatch):
    import grasp_fc_ros.node.incompatible_qos as incompatible_qos

    monkeypatch.setattr(incompatible_qos, "FORGET_AFTER_S", 1.0)
    _, _, client = own_node(NAMESPACE)
    # The client's own RELIABLE publishers and subscriptions match: nothing counted.
    status_where(client, lambda level, message, values: (
        level == DiagnosticStatus.OK and values["incompatible_qos_publishers"] == "0"
        and values["incompatible_qos_subscribers"] == "0"))

    node = client.node
    single = node.create_publisher(ContactArray, "contacts", BEST_EFFORT)
    status = status_where(client, lambda level, message, values: (
        values["incompatible_qos_publishers"] == "1 (RELIABILITY)"))
    assert status.level == DiagnosticStatus.WARN
    assert (f"publishers with incompatible QoS on {NAMESPACE}/contacts: 1 (RELIABILITY)"
            in status.message)

    batch = node.create_publisher(ContactArrayBatch, "contacts_batch", BEST_EFFORT)
    status = status_where(client, lambda level, message, values: (
        values["incompatible_qos_publishers"] == "2 (RELIABILITY)"))
    assert f"on {NAMESPACE}/contacts_batch: 1 (RELIABILITY)" in status.message

    reader = node.create_subscription(ForceClosureVerdict, "verdicts", lambda _: None,
                                      TRANSIENT_LOCAL)
    status = status_where(client, lambda level, message, values: (
        values["incompatible_qos_subscribers"] == "1 (DURABILITY)"))
    assert status.level == DiagnosticStatus.WARN
    assert (f"subscribers with incompatible QoS on {NAMESPACE}/verdicts: 1 (DURABILITY)"
            in status.message)

    for publisher in (single, batch):
        node.destroy_publisher(publisher)
    node.destroy_subscription(reader)
    status_where(client, lambda level, message, values: (
        level == DiagnosticStatus.OK and message == "ok"
        and values["incompatible_qos_publishers"] == "0"
        and values["incompatible_qos_subscribers"] == "0"))
