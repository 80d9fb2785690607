"""Every answer reaches its asker, and only its asker; no query waits forever.

The node answers a query carrying a client id on that client's reply topics, one
without on the shared ones; a repeated query is answered again; GraspClient keeps a
query whose publish failed or that had no answer within its bound, and sends it again;
refusals come in bulk, with their reason (issue 22). Several client processes at once:
test/tooling/test_bench_clients.py.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from grasp_fc_msgs.msg import ContactArray, ForceClosureVerdict
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node

from grasp_fc_ros.client import GraspClient
from grasp_fc_ros.client.connection import MATCH_GRACE_S, WATCH_PERIOD_S
from grasp_fc_ros.core import Status, check_force_closure
from grasp_fc_ros.interface.conversions import (
    grasp_to_contact_array,
    grasps_to_batch_msg,
    verdict_array_to_numpy,
)
from grasp_fc_ros.interface.names import reply_topic
from grasp_fc_ros.objects import make_object, sample_grasps
from ros_fixtures import RELIABLE, REPLY_TIMEOUT_S, SpinThread

pytestmark = pytest.mark.timeout(120)

DEFAULT_MU = 0.5
CLIENT_ID = 77
# Long enough for an answer that is coming to arrive (a quiet topic stays quiet).
QUIET_S = 0.5


@pytest.fixture(scope="module")
def grasps():
    return sample_grasps(make_object("box"), 8, 6, np.random.default_rng(22))


def collect(node: Node, msg_type: type, topic: str) -> tuple[list, threading.Condition]:
    """Messages arriving on ``topic``, and a condition notified at each."""
    got: list = []
    ready = threading.Condition()

    def on_message(msg):
        with ready:
            got.append(msg)
            ready.notify_all()

    node.create_subscription(msg_type, topic, on_message, RELIABLE)
    return got, ready


def wait_len(got: list, ready: threading.Condition, n: int) -> list:
    with ready:
        assert ready.wait_for(lambda: len(got) >= n, REPLY_TIMEOUT_S), f"{len(got)} of {n}"
        return list(got)


def test_answers_go_to_the_askers_reply_topic_and_id_0_to_the_shared_one(own_node, grasps):
    _, _, client = own_node("/delivery_topics")
    mine, ready = collect(client.node, ForceClosureVerdict, reply_topic("verdicts", CLIENT_ID))
    other, _ = collect(client.node, ForceClosureVerdict, reply_topic("verdicts", CLIENT_ID + 1))
    positions, normals = grasps
    client.contacts_pub.publish(grasp_to_contact_array(5, positions[0], normals[0],
                                                       client_id=CLIENT_ID))
    client.contacts_pub.publish(grasp_to_contact_array(6, positions[1], normals[1]))
    [answer] = wait_len(mine, ready, 1)
    [shared] = client.wait_for("verdicts", 1)
    time.sleep(QUIET_S)
    assert (answer.client_id, answer.id) == (CLIENT_ID, 5)
    assert (shared.client_id, shared.id) == (0, 6)
    assert len(mine) == 1 and len(client.verdicts) == 1 and not other


def test_a_repeated_query_and_batch_are_answered_again(own_node, grasps):
    _, _, client = own_node("/delivery_repeat")
    client.listen(CLIENT_ID)
    positions, normals = grasps
    query = grasp_to_contact_array(5, positions[0], normals[0], client_id=CLIENT_ID)
    batch = grasps_to_batch_msg(np.arange(3), positions[:3], normals[:3],
                                client_id=CLIENT_ID, request_id=9)
    for _ in range(2):
        client.contacts_pub.publish(query)
        client.batch_pub.publish(batch)
    verdicts = client.wait_for("verdicts", 2)
    answers = client.wait_for("batches", 2)
    expected = check_force_closure(positions[:3], normals[:3], DEFAULT_MU).status
    assert [(v.client_id, v.id, v.status) for v in verdicts] == [
        (CLIENT_ID, 5, expected[0])] * 2
    for answer in answers:
        assert (answer.client_id, answer.request_id) == (CLIENT_ID, 9)
        np.testing.assert_array_equal(verdict_array_to_numpy(answer).status, expected)


def test_a_batch_with_counts_and_no_ids_is_invalid_with_the_reason(own_node, grasps):
    _, _, client = own_node("/delivery_no_ids")
    positions, normals = grasps
    msg = grasps_to_batch_msg(np.arange(3), positions[:3], normals[:3])
    msg.ids = []
    got = verdict_array_to_numpy(client.request_batch(msg))
    np.testing.assert_array_equal(got.ids, [0])
    assert got.status.tolist() == [Status.INVALID_INPUT]
    assert got.messages == ["malformed batch: 3 contact counts for 0 ids"]


def test_an_oversized_batch_is_refused_whole_in_one_answer(own_node):
    _, _, client = own_node("/delivery_oversize", max_batch=100_000)
    n = 200_001  # beyond the default max_batch; no contacts: refused before conversion
    msg = grasps_to_batch_msg(np.arange(n), np.empty((n, 0, 3)), np.empty((n, 0, 3)))
    answer = client.request_batch(msg)
    np.testing.assert_array_equal(answer.ids, np.arange(n))
    assert (np.asarray(answer.status) == Status.INVALID_INPUT).all()
    assert set(answer.messages) == {"200001 grasps exceed max_batch=100000"}



def test_a_batch_of_more_contacts_than_max_message_contacts_is_refused_saying_why(
        own_node, grasps):
    # A raw publisher's message (GraspClient splits its batches below the limit).
    node, _, client = own_node("/delivery_contact_cap", max_message_contacts=100)
    positions, normals = (np.concatenate([a] * 3) for a in grasps)  # 6 contacts each
    over = grasps_to_batch_msg(np.arange(17), positions[:17], normals[:17])  # 102 contacts
    answer = verdict_array_to_numpy(client.request_batch(over))
    np.testing.assert_array_equal(answer.ids, np.arange(17))
    assert (answer.status == Status.INVALID_INPUT).all()
    assert set(answer.messages) == {
        "102 contacts in one message exceed max_message_contacts=100: split it into "
        "messages of whole grasps (GraspClient does)"}
    within = grasps_to_batch_msg(np.arange(16), positions[:16], normals[:16])  # 96 contacts
    answer = verdict_array_to_numpy(client.request_batch(within))
    assert answer.status.tolist() == core_statuses(positions[:16], normals[:16])

    from rclpy.parameter import Parameter

    node.set_parameters([Parameter("max_message_contacts", value=0)])  # 0: no limit
    answer = verdict_array_to_numpy(client.request_batch(over))
    assert answer.status.tolist() == core_statuses(positions[:17], normals[:17])

# --- GraspClient: nothing is lost while no node is up, and nothing waits forever ------


def core_statuses(positions, normals):
    return check_force_closure(positions, normals, DEFAULT_MU).status.tolist()


def test_the_client_keeps_queries_sent_before_the_node_starts(own_node, grasps):
    positions, normals = grasps
    with GraspClient("/delivery_late/force_closure") as grasp_client:
        single = grasp_client.submit(positions[0], normals[0])
        batch = grasp_client.submit_batch(positions, normals)
        time.sleep(QUIET_S)
        assert not single.done() and not batch.done()
        own_node("/delivery_late")
        assert single.result(REPLY_TIMEOUT_S).status == core_statuses(positions, normals)[0]
        assert batch.result(REPLY_TIMEOUT_S).status.tolist() == core_statuses(positions, normals)


def test_a_failed_publish_is_kept_and_sent_again(own_node, grasps, monkeypatch):
    own_node("/delivery_publish_fails")
    positions, normals = grasps
    with GraspClient("/delivery_publish_fails/force_closure") as grasp_client:
        assert grasp_client.wait_for_node(REPLY_TIMEOUT_S)
        for publisher in (grasp_client._singles.publisher, grasp_client._batches.publisher):
            fail_once(monkeypatch, publisher)
        single = grasp_client.submit(positions[0], normals[0])
        batch = grasp_client.submit_batch(positions, normals)
        assert single.result(REPLY_TIMEOUT_S).status == core_statuses(positions, normals)[0]
        assert batch.result(REPLY_TIMEOUT_S).status.tolist() == core_statuses(positions, normals)
        assert grasp_client.resubmitted == 1 + len(positions)


def fail_once(monkeypatch, publisher):
    """Make ``publisher``'s next publish fail as rclpy's does with no reader left."""
    publish = publisher.publish
    failed = []

    def publish_or_fail(msg):
        if not failed:
            failed.append(msg)
            raise _rclpy.RCLError("Failed to publish: cannot publish data")
        publish(msg)

    monkeypatch.setattr(publisher, "publish", publish_or_fail)


class ForgetfulResponder:
    """A stand-in node that ignores the first copy of every query and answers the
    second, on the asker's reply topic (as if the first answer had been lost)."""

    def __init__(self, namespace: str):
        self.node = Node("force_closure", namespace=namespace)
        self.seen: set[tuple[int, int]] = set()
        self.replies: dict[int, object] = {}
        self.node.create_subscription(ContactArray, "contacts", self._on_query, RELIABLE)
        self.spinner = SpinThread(self.node)

    def _on_query(self, query: ContactArray) -> None:
        key = (query.client_id, query.id)
        if query.client_id not in self.replies:
            self.replies[query.client_id] = self.node.create_publisher(
                ForceClosureVerdict, reply_topic("verdicts", query.client_id), RELIABLE)
        if key not in self.seen:
            self.seen.add(key)
            return
        self.replies[query.client_id].publish(ForceClosureVerdict(
            client_id=query.client_id, id=query.id, status=ForceClosureVerdict.FORCE_CLOSURE))


def test_a_query_without_an_answer_is_sent_again_after_its_bound(ros, grasps):
    positions, normals = grasps
    responder = ForgetfulResponder("/delivery_forgetful")
    try:
        with GraspClient("/delivery_forgetful/force_closure", resend_after=0.5) as grasp_client:
            deadline = time.monotonic() + REPLY_TIMEOUT_S
            while not grasp_client._singles.publisher.get_subscription_count():
                assert time.monotonic() < deadline, "the responder was never matched"
                time.sleep(0.01)
            # Past the watch's first look at the responder (which re-sends everything).
            time.sleep(2 * WATCH_PERIOD_S + MATCH_GRACE_S)
            before = grasp_client.resubmitted
            answer = grasp_client.submit(positions[0], normals[0], query_id=3).result(
                REPLY_TIMEOUT_S)
            assert (answer.client_id, answer.id) == (grasp_client.client_id, 3)
            assert grasp_client.resubmitted - before >= 1
    finally:
        responder.spinner.stop()


def test_a_gone_clients_reply_publishers_are_destroyed(own_node, grasps, monkeypatch):
    from grasp_fc_ros.node import replies as replies_module

    node, _, _ = own_node("/delivery_sweep")
    positions, normals = grasps
    with GraspClient("/delivery_sweep/force_closure") as grasp_client:
        assert grasp_client.wait_for_node(REPLY_TIMEOUT_S)
        grasp_client.submit(positions[0], normals[0]).result(REPLY_TIMEOUT_S)
        grasp_client.check_batch(positions, normals, timeout=REPLY_TIMEOUT_S)
        assert node.replies.reply_topics == 2
        monkeypatch.setattr(replies_module, "REPLY_IDLE_S", 0.0)
        node.replies.sweep()
        assert node.replies.reply_topics == 2  # still read
    deadline = time.monotonic() + REPLY_TIMEOUT_S
    while node.replies.reply_topics:  # once the client's subscriptions are gone
        assert time.monotonic() < deadline, "reply publishers of a gone client kept"
        node.replies.sweep()
        time.sleep(0.05)
