"""GraspClient sends a large batch in parts of at most MAX_MESSAGE_CONTACTS contacts and
joins their answers; a service call made meanwhile is answered (no timing asserted:
bench_stall.py measures the latency). A large service call goes as several requests
the same way."""

from __future__ import annotations

import time

import numpy as np
import pytest
from grasp_fc_msgs.msg import ContactArrayBatch

from grasp_fc_ros.client import GraspClient, service_calls
from grasp_fc_ros.client import batches as batches_module
from grasp_fc_ros.client.batches import (
    PART_ANSWER_WAIT_S,
    PARTS_IN_FLIGHT,
    grasp_ranges,
    split_batch,
)
from grasp_fc_ros.core import Status, check_force_closure
from grasp_fc_ros.engine.pool import EvaluationPool
from grasp_fc_ros.interface.conversions import batch_arrays
from grasp_fc_ros.interface.names import MAX_MESSAGE_CONTACTS, QUERY_QOS
from grasp_fc_ros.objects import make_object, sample_grasps

pytestmark = pytest.mark.timeout(180)

REPLY_TIMEOUT_S = 120.0


def mixed_batch(n_grasps: int, seed: int):
    """(positions (K, 3), normals (K, 3), counts (N,), mu (K,)): grasps of 3-12 contacts."""
    rng = np.random.default_rng(seed)
    counts = rng.integers(3, 13, n_grasps)
    surface = make_object("box")
    grasps = [sample_grasps(surface, 1, int(n), rng) for n in counts]
    positions = np.concatenate([p[0] for p, _ in grasps])
    normals = np.concatenate([n[0] for _, n in grasps])
    return positions, normals, counts, rng.uniform(0.2, 0.8, len(positions))


def test_parts_hold_whole_grasps_in_order_within_the_bound():
    positions, normals, counts, mu = mixed_batch(400, 1)
    fields = batch_arrays(np.arange(400) + 7, positions, normals, mu, counts)
    parts = split_batch(fields, 500)
    assert len(parts) >= -(-int(counts.sum()) // 500) and len(parts) > 1
    for part in parts:
        contacts = int(part.contact_counts.sum())
        assert contacts <= 500
        assert len(part.positions) == len(part.normals) == 3 * contacts
        assert len(part.friction_coefficients) == contacts
        assert len(part.torsional_friction) == 0  # hard contacts: the field stays empty
    for name, whole in zip(fields._fields, fields, strict=True):
        joined = np.concatenate([getattr(part, name) for part in parts])
        np.testing.assert_array_equal(joined, whole, err_msg=name)


def test_a_grasp_larger_than_the_bound_goes_alone_and_small_batches_whole():
    positions, normals, counts, mu = mixed_batch(30, 2)
    fields = batch_arrays(np.arange(30), positions, normals, mu, counts)
    assert split_batch(fields, int(counts.sum())) == [fields]
    parts = split_batch(fields, 2)  # every grasp has more contacts than that
    assert [len(part.ids) for part in parts] == [1] * 30
    # Arrays that do not match the counts are sent whole, for the node to refuse.
    short = fields._replace(positions=fields.positions[:-3])
    assert split_batch(short, 2) == [short]


def test_large_batch_goes_in_parts_and_comes_back_whole_beside_a_service_call(own_node):
    _, _, raw = own_node("/parts_test", max_batch=5000)
    n_grasps = 2000
    positions, normals, counts, mu = mixed_batch(n_grasps, 3)
    assert counts.sum() > 2 * MAX_MESSAGE_CONTACTS
    sizes: list[int] = []  # contacts of every message on contacts_batch
    raw.node.create_subscription(ContactArrayBatch, "/parts_test/contacts_batch",
                                 lambda msg: sizes.append(sum(msg.contact_counts)), QUERY_QOS)
    client = GraspClient("/parts_test/force_closure")
    try:
        assert client.wait_for_node(REPLY_TIMEOUT_S)
        ids = np.arange(n_grasps) + 1000
        answer = client.submit_batch(positions, normals, mu, counts=counts, ids=ids)
        single = sample_grasps(make_object("box"), 1, 6, np.random.default_rng(4))
        called = client.call(*single, timeout=REPLY_TIMEOUT_S)
        verdicts = answer.result(REPLY_TIMEOUT_S)
    finally:
        client.close()
    assert len(called) == 1
    np.testing.assert_array_equal(verdicts.ids, ids)
    ends = np.cumsum(counts)
    expected = [check_force_closure(positions[end - n:end][None], normals[end - n:end][None],
                                    mu[end - n:end][None]) for n, end in zip(counts, ends,
                                                                             strict=True)]
    np.testing.assert_array_equal(verdicts.status, [e.status[0] for e in expected])
    np.testing.assert_array_equal(verdicts.force_closure,
                                  [e.force_closure[0] for e in expected])
    deadline = time.monotonic() + REPLY_TIMEOUT_S  # the listener hears them on its thread
    while sum(sizes) < counts.sum() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert sum(sizes) == counts.sum()
    assert len(sizes) > 2 and max(sizes) <= MAX_MESSAGE_CONTACTS


def test_grasp_ranges_hold_whole_grasps_in_order_within_the_bound():
    counts = [3, 5, 2, 7, 1, 4]
    assert grasp_ranges(counts, 8) == [(0, 2), (2, 3), (3, 5), (5, 6)]
    assert grasp_ranges(counts, 22) == [(0, 6)]
    assert grasp_ranges(counts, 2) == [(0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (5, 6)]
    assert grasp_ranges([1, 1, 3, 1, 1], 2) == [(0, 2), (2, 3), (3, 5)]
    assert grasp_ranges([], 8) == []


def test_a_big_service_call_goes_as_several_requests_under_the_nodes_limit(own_node,
                                                                           monkeypatch):
    # The node refuses a request of more than 100 contacts; the client's bound, made
    # small, splits the call into requests of at most 40 (6 whole 6-contact grasps).
    _, _, raw = own_node("/service_parts_test", max_message_contacts=100)
    monkeypatch.setattr(service_calls, "MAX_REQUEST_CONTACTS", 40)
    positions, normals = sample_grasps(make_object("box"), 50, 6, np.random.default_rng(5))
    normals[17, 2] = 0.0  # invalid: its verdict must stay in its place
    mu = np.random.default_rng(6).uniform(0.2, 0.8, (50, 6))
    ids = np.arange(50) * 7 + 3
    client = GraspClient("/service_parts_test/force_closure")
    try:
        assert client.wait_for_node(REPLY_TIMEOUT_S)
        called = client.call(positions, normals, mu, ids=ids, timeout=REPLY_TIMEOUT_S)
    finally:
        client.close()
    np.testing.assert_array_equal(called.ids, ids)
    assert called.status[17] == Status.INVALID_INPUT
    valid = np.arange(50) != 17  # the core raises on the invalid grasp
    expected = check_force_closure(positions[valid], normals[valid], mu[valid])
    np.testing.assert_array_equal(called.status[valid], expected.status)
    np.testing.assert_array_equal(called.force_closure[valid], expected.force_closure)
    np.testing.assert_allclose(called.margin[valid], expected.margin, rtol=1e-4, atol=1e-6,
                               equal_nan=True)


class SlowPool(EvaluationPool):
    """A pool without workers that takes :data:`SLOW_DECISION_S` more per decision."""

    def decide(self, *args, **kwargs):
        time.sleep(SLOW_DECISION_S)
        return super().decide(*args, **kwargs)


# Each request of the call below takes this long (s): less than the call's timeout, but
# all of them together take more.
SLOW_DECISION_S = 0.3


def test_a_call_in_several_requests_has_one_timeout_for_them_all(own_node, monkeypatch):
    own_node("/service_timeout_test", pool=SlowPool(workers=0))
    monkeypatch.setattr(service_calls, "MAX_REQUEST_CONTACTS", 12)
    positions, normals = sample_grasps(make_object("box"), 16, 6, np.random.default_rng(7))
    client = GraspClient("/service_timeout_test/force_closure")
    try:
        assert client.wait_for_node(REPLY_TIMEOUT_S)
        assert len(client.call(positions[:2], normals[:2], timeout=REPLY_TIMEOUT_S)) == 2
        with pytest.raises(TimeoutError, match="service /service_timeout_test/"
                                               "check_force_closure within 1.0 s: its "
                                               "node may be down"):
            client.call(positions, normals, timeout=1.0)  # 8 requests: >= 2.4 s
    finally:
        client.close()


class PartsListener:
    """A plain listener on a namespace's batch topic (no node answers there) and a
    GraspClient of that namespace, matched: when each part of a batch was heard."""

    def __init__(self, namespace: str):
        from rclpy.node import Node

        from ros_fixtures import SpinThread

        self.heard: list[float] = []
        node = Node("parts_listener", namespace=namespace)
        node.create_subscription(ContactArrayBatch, f"{namespace}/contacts_batch",
                                 lambda _: self.heard.append(time.monotonic()), QUERY_QOS)
        self.spinner = SpinThread(node)
        self.client = GraspClient(f"{namespace}/force_closure")
        self.wait_until(lambda: self.client._batches.publisher.get_subscription_count(),  # noqa: SLF001
                        "the listener never matched")

    @staticmethod
    def wait_until(condition, what: str) -> None:
        deadline = time.monotonic() + REPLY_TIMEOUT_S
        while not condition():
            assert time.monotonic() < deadline, what
            time.sleep(0.01)

    def send(self, n_parts: int) -> float:
        """Submit a batch of ``n_parts`` parts of 1,024 grasps; when it was submitted."""
        positions, normals = sample_grasps(make_object("box"), 1024 * n_parts, 6,
                                           np.random.default_rng(5))
        sent = time.monotonic()
        self.client.submit_batch(positions, normals)
        return sent

    def wait_heard(self, n_parts: int) -> None:
        self.wait_until(lambda: len(self.heard) >= n_parts, f"heard {len(self.heard)} parts")

    def close(self) -> None:
        self.client.close()
        self.spinner.stop()  # destroys the listener


# How long no further part may come while PARTS_IN_FLIGHT are unanswered (s): several
# times the longest a part waits for its acknowledgement (PART_ACK_WAIT_S, 1 s).
QUIET_S = 3.0


def test_no_more_than_parts_in_flight_go_out_unanswered(ros, monkeypatch):
    """With nobody answering, the client sends PARTS_IN_FLIGHT parts, then waits."""
    monkeypatch.setattr(batches_module, "PART_ANSWER_WAIT_S", 3600.0)  # no wait ends here
    listener = PartsListener("/window_test")
    try:
        listener.send(PARTS_IN_FLIGHT + 2)
        listener.wait_heard(PARTS_IN_FLIGHT)
        time.sleep(QUIET_S)
        assert len(listener.heard) == PARTS_IN_FLIGHT
    finally:
        listener.close()


def test_the_wait_for_an_answer_ends_after_part_answer_wait_s(ros):
    """With nobody answering, the part after PARTS_IN_FLIGHT goes out once
    PART_ANSWER_WAIT_S has passed, not before (a vanished node delays a batch, never
    forever)."""
    listener = PartsListener("/window_wait_test")
    try:
        sent = listener.send(PARTS_IN_FLIGHT + 2)
        listener.wait_heard(PARTS_IN_FLIGHT + 1)
    finally:
        listener.close()
    assert listener.heard[PARTS_IN_FLIGHT] - sent >= PART_ANSWER_WAIT_S
