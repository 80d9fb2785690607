"""Messages the middleware reports lost before the node took them are counted in
/diagnostics (``messages_lost``).

The count is the node's: it adds up the ``total_count_change`` of rclpy's message_lost
QoS events on its query subscriptions. Whether the rmw reports a loss is not: Fast DDS
reports queries that a publisher's KEEP_LAST history overwrote late, as fewer than were
lost (a run of 1,488 once as 1), or not at all (issue 31). So the node's part is tested
here with known events, fed to the callbacks the node registered, and the route such
events take to them with an event Fast DDS always raises (an incompatible publisher);
benchmarks/bench_message_loss.py measures the end-to-end burst (a stopped node, a
KEEP_LAST publisher) and what the rmw reported of it.
"""

from __future__ import annotations

import threading
import time

import pytest
from rclpy.event_handler import QoSMessageLostInfo, QoSSubscriptionEventType
from rclpy.qos import QoSProfile, ReliabilityPolicy

from grasp_fc_ros.interface.names import CONTACTS_BATCH_TOPIC, CONTACTS_TOPIC

pytestmark = pytest.mark.timeout(120)

NAMESPACE = "/loss_test"
NODE_NAME = f"{NAMESPACE}/force_closure"
# Discovery of a new publisher, on a loaded machine.
EVENT_TIMEOUT_S = 30.0


class MessageLost(QoSMessageLostInfo):
    """A message_lost event with the given counts (rclpy's own are read-only)."""

    def __init__(self, total_count: int, total_count_change: int):
        super().__init__()
        self._counts = (total_count, total_count_change)

    total_count = property(lambda self: self._counts[0])
    total_count_change = property(lambda self: self._counts[1])


def subscription_handlers(node, topic: str, event_type) -> list:
    """The event handlers of ``event_type`` on the node's subscriptions to ``topic``
    (the batch topic's subscription is on the node's helper participant)."""
    nodes = [node, node.batch_participant.node]
    full_name = f"{NAMESPACE}/{topic}"
    return [handler for owner in nodes for subscription in owner.subscriptions
            if subscription.topic_name == full_name
            for handler in subscription.event_handlers if handler.event_type == event_type]


def lost_callback(node, topic: str):
    """The node's one message_lost callback on its subscription to ``topic``."""
    handlers = subscription_handlers(node, topic,
                                     QoSSubscriptionEventType.RCL_SUBSCRIPTION_MESSAGE_LOST)
    assert len(handlers) == 1, f"{len(handlers)} message_lost handlers on {topic}"
    return handlers[0].callback


@pytest.fixture
def system(own_node):
    node, _, client = own_node(NAMESPACE, workers=0)
    return node, client


def diagnostics_now(client) -> dict[str, int]:
    """The node's counters in a /diagnostics status built after this call."""
    values = client.diagnostics_after(time.time(), NODE_NAME)
    return {key: int(values[key]) for key in ("messages_lost", "received", "answered")}


def test_messages_lost_is_the_sum_of_the_events_counts(system):
    """Several events on both query topics, one a run counted as one, one of none:
    ``messages_lost`` grows by exactly their ``total_count_change`` summed, and no
    query is counted received or answered for them."""
    node, client = system
    events = [(CONTACTS_TOPIC, MessageLost(3, 3)), (CONTACTS_BATCH_TOPIC, MessageLost(2, 2)),
              (CONTACTS_TOPIC, MessageLost(4, 1)), (CONTACTS_TOPIC, MessageLost(4, 0)),
              (CONTACTS_BATCH_TOPIC, MessageLost(1490, 1488))]
    before = diagnostics_now(client)
    for topic, event in events:
        lost_callback(node, topic)(event)
    after = diagnostics_now(client)
    assert after["messages_lost"] - before["messages_lost"] == 3 + 2 + 1 + 0 + 1488
    assert after["received"] == before["received"]
    assert after["answered"] == before["answered"]


def test_the_subscription_loops_hand_events_to_their_callbacks(system, monkeypatch):
    """The query subscriptions are served by loops of their own, not the executor
    (grasp_fc_ros.interface.wait_sets.SubscriptionLoop), which must wait on their QoS
    events too, message_lost among them. Fast DDS always raises an incompatible-QoS
    event for a BEST_EFFORT publisher on a RELIABLE subscription: it reaches the
    callback on both topics, through the same wait set and dispatch."""
    from grasp_fc_msgs.msg import ContactArray, ContactArrayBatch

    node, client = system
    kind = QoSSubscriptionEventType.RCL_SUBSCRIPTION_REQUESTED_INCOMPATIBLE_QOS
    seen = {CONTACTS_TOPIC: threading.Event(), CONTACTS_BATCH_TOPIC: threading.Event()}
    for topic, event in seen.items():
        handlers = subscription_handlers(node, topic, kind)
        assert len(handlers) == 1, f"{len(handlers)} incompatible-QoS handlers on {topic}"
        monkeypatch.setattr(handlers[0], "callback",
                            lambda info, event=event: event.set())
    best_effort = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
    publishers = [client.node.create_publisher(ContactArray, CONTACTS_TOPIC, best_effort),
                  client.node.create_publisher(ContactArrayBatch, CONTACTS_BATCH_TOPIC,
                                               best_effort)]
    try:
        for topic, event in seen.items():
            assert event.wait(EVENT_TIMEOUT_S), f"no QoS event on {topic} reached its callback"
    finally:
        for publisher in publishers:
            client.node.destroy_publisher(publisher)
