"""Load tests of the node in-process with its worker processes: bursts, floods, a large
batch beside the service. Bounds are generous (a shared 2-core machine): they check
that nothing is lost and nothing waits for a batch, not speed."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from grasp_fc_msgs.msg import ForceClosureVerdict

from grasp_fc_ros.client import GraspClient, service_calls
from grasp_fc_ros.core import Status, check_force_closure
from grasp_fc_ros.interface import wire
from grasp_fc_ros.interface.conversions import grasp_to_contact_array, grasps_to_batch_msg
from grasp_fc_ros.interface.names import QUERY_QOS, reply_topic
from grasp_fc_ros.node.batches import BATCHES_IN_PROGRESS
from grasp_fc_ros.node.lane import SHUTDOWN_MESSAGE
from grasp_fc_ros.objects import make_object, sample_grasps
from ros_fixtures import REPLY_TIMEOUT_S

pytestmark = pytest.mark.timeout(180)

BURST = 10_000
# Every REAL_EVERY-th query of the burst is a real 6-finger grasp; the others have one
# contact (INVALID_INPUT without core work), so the burst tests flow control and
# bookkeeping in seconds rather than the core's speed.
REAL_EVERY = 20
LOAD_TIMEOUT_S = 120.0


@pytest.fixture(scope="module")
def grasps():
    return sample_grasps(make_object("box"), 3000, 6, np.random.default_rng(21))


def test_burst_of_single_queries_is_answered_exactly_once(own_node, grasps):
    _, _, raw = own_node("/burst_test")
    positions, normals = grasps
    real = np.arange(0, BURST, REAL_EVERY)
    # Every verdict on the topic, by id: read from the bytes, all received ones per
    # wake-up, so that this listener keeps up with the node in the same process (one
    # rclpy message per wake-up fell ~5,000 behind and then heard nothing more).
    heard, all_heard = [], threading.Event()

    def on_verdict(data):
        while data is not None:  # and every other verdict already received
            heard.append(wire.verdict_ids(data)[1])
            with listener.handle:
                taken = listener.handle.take_message(ForceClosureVerdict, True)
            data = taken and taken[0]
        if len(heard) >= BURST:
            all_heard.set()

    client = GraspClient("/burst_test/force_closure")
    # The client's reply topic: a second reader of its answers.
    listener = raw.node.create_subscription(
        ForceClosureVerdict, reply_topic("/burst_test/verdicts", client.client_id),
        on_verdict, QUERY_QOS, raw=True)
    try:
        assert client.wait_for_node(REPLY_TIMEOUT_S)
        futures = []
        for i in range(BURST):  # back to back: submit() waits only for the window
            k = i % len(positions)
            contacts = slice(None) if i % REAL_EVERY == 0 else slice(0, 1)
            futures.append(client.submit(positions[k][contacts], normals[k][contacts],
                                         query_id=i, timeout=LOAD_TIMEOUT_S))
        verdicts = [f.result(LOAD_TIMEOUT_S) for f in futures]
        # The listener hears every verdict on the reply topic: each id exactly once.
        assert all_heard.wait(LOAD_TIMEOUT_S), f"heard {len(heard)} of {BURST} verdicts"
        time.sleep(0.5)
    finally:
        client.close()
    assert [v.id for v in verdicts] == list(range(BURST))
    ids = list(heard)
    assert len(ids) == BURST and sorted(ids) == list(range(BURST)), "lost or doubled"
    assert ids == list(range(BURST)), "single-topic verdicts must come in arrival order"
    status = np.array([v.status for v in verdicts])
    expected = check_force_closure(positions[real % len(positions)],
                                   normals[real % len(positions)], 0.5).status
    np.testing.assert_array_equal(status[real], expected)
    assert (np.delete(status, real) == Status.INVALID_INPUT).all()
    # The last queries are counted just after their verdicts went out.
    after = raw.diagnostics_when(lambda v: int(v["answered"]) >= BURST,
                                 "/burst_test/force_closure")
    assert int(after["received"]) == int(after["answered"]) == BURST
    assert after["overloaded"] == "0"


def test_service_answers_while_a_large_batch_is_decided(own_node, grasps):
    # One worker and 99,000 grasps (max_batch is 100,000): seconds of work.
    node, _, raw = own_node("/latency_test", workers=1)
    positions, normals = (np.tile(a, (33, 1, 1)) for a in grasps)
    client = GraspClient("/latency_test/force_closure")
    try:
        assert client.wait_for_node(REPLY_TIMEOUT_S)
        batch = client.submit_batch(positions, normals)
        deadline = time.monotonic() + LOAD_TIMEOUT_S
        # Start once the node is deciding the batch (its ~36 chunks take seconds).
        while node.statistics.received == 0:
            assert time.monotonic() < deadline, "the node never received the batch"
            time.sleep(0.01)
        expected = check_force_closure(positions[0], normals[0], 0.5).status
        during = []  # per call: whether the batch was still undecided when it was answered
        while not batch.done() and len(during) < 5:
            verdict = client.call(positions[:1], normals[:1], timeout=REPLY_TIMEOUT_S)
            during.append(not batch.done())
            assert verdict.status[0] == expected
        # A call waits at most for the chunk being decided, not for the batch (how long
        # it waits is benchmarks/bench_ros.py's "service round trip during a batch").
        assert during and during[0], "the first call was answered only after the batch"
        verdicts = batch.result(LOAD_TIMEOUT_S)
        np.testing.assert_array_equal(verdicts.ids, np.arange(len(positions)))
        np.testing.assert_array_equal(verdicts.status[:200],
                                      check_force_closure(positions[:200], normals[:200],
                                                          0.5).status)
    finally:
        client.close()


def test_batches_are_answered_in_arrival_order_while_the_next_ones_are_decided(
        own_node, grasps):
    # One worker, so a large batch's chunks take a while; the batches behind it start
    # before it is answered (BATCHES_IN_PROGRESS), and a tiny one is even decided first
    # (inline), but every answer goes out in arrival order, complete.
    _, _, client = own_node("/order_test", workers=1)
    positions, normals = grasps
    sizes = [3000, 2, 1, 700, 3, 3000, 2]
    request_ids = list(range(500, 500 + len(sizes)))
    for request_id, size in zip(request_ids, sizes, strict=True):
        msg = grasps_to_batch_msg(np.arange(size), positions[:size], normals[:size])
        msg.request_id = request_id
        client.batch_pub.publish(msg)
    answers = client.wait_for("batches", len(sizes), timeout=LOAD_TIMEOUT_S)
    assert [a.request_id for a in answers] == request_ids
    expected = check_force_closure(positions, normals, 0.5).status
    for answer, size in zip(answers, sizes, strict=True):
        np.testing.assert_array_equal(answer.ids, np.arange(size))
        np.testing.assert_array_equal(answer.status, expected[:size])


def test_batches_in_progress_and_queued_are_answered_in_order_at_shutdown(own_node, grasps):
    node, spinner, client = own_node("/batch_shutdown_test", workers=1)
    positions, normals = grasps
    big = grasps_to_batch_msg(np.arange(60_000), np.tile(positions, (20, 1, 1)),
                              np.tile(normals, (20, 1, 1)))  # seconds on one worker
    mispacked = grasps_to_batch_msg([0, 1], positions[:2], normals[:2])
    mispacked.contact_counts = [6, 5]  # refused at conversion, while big is decided
    # Small batches (decided at once) fill the other places in progress behind big.
    small = [grasps_to_batch_msg([0, 1, 2], positions[:3], normals[:3])
             for _ in range(BATCHES_IN_PROGRESS - 1)]  # the last one stays queued
    msgs = [big, mispacked, *small]
    for request_id, msg in enumerate(msgs, start=1):
        msg.request_id = request_id
        client.batch_pub.publish(msg)
    deadline = time.monotonic() + LOAD_TIMEOUT_S
    while not (node.batches.in_progress == BATCHES_IN_PROGRESS and node.batches.queued == 1):
        assert time.monotonic() < deadline, "the batches never got in place"
        time.sleep(0.01)
    spinner.stop()
    answers = client.wait_for("batches", len(msgs))
    assert [a.request_id for a in answers] == list(range(1, len(msgs) + 1))
    # The mis-packed batch keeps the answer it got; the others say why they got none.
    assert set(answers[1].status) == {Status.INVALID_INPUT}
    assert answers[1].messages[0].startswith("malformed batch")
    for answer in (answers[0], *answers[2:]):
        assert set(answer.status) == {Status.SOLVER_FAILURE}
        assert set(answer.messages) == {SHUTDOWN_MESSAGE}
    time.sleep(0.5)
    assert len(client.wait_for("batches", len(msgs))) == len(msgs), "a batch got two answers"


def test_malformed_message_flood_is_answered_and_harmless(own_node, grasps):
    node, _, client = own_node("/flood_test")
    positions, normals = (a[:4] for a in grasps)
    n_flood = 300
    for k in range(n_flood):
        msg = grasps_to_batch_msg([k, k + 1], positions[:2], normals[:2])
        if k % 3 == 0:
            msg.contact_counts = msg.contact_counts[:1]
        elif k % 3 == 1:
            msg.positions = msg.positions[:-1]
        else:
            msg.friction_coefficients = [np.nan] * 12
        msg.request_id = 10_000 + k
        client.batch_pub.publish(msg)
        client.contacts_pub.publish(grasp_to_contact_array(k, positions[0][:0], normals[0][:0]))
    batches = client.wait_for("batches", n_flood, timeout=LOAD_TIMEOUT_S)
    singles = client.wait_for("verdicts", n_flood, timeout=LOAD_TIMEOUT_S)
    assert sorted(b.request_id for b in batches) == list(range(10_000, 10_000 + n_flood))
    assert all(set(b.status) == {Status.INVALID_INPUT} for b in batches)
    assert all(v.status == Status.INVALID_INPUT for v in singles)
    # Still fully working afterwards.
    got = client.request_batch(grasps_to_batch_msg([7, 8], positions[:2], normals[:2]))
    np.testing.assert_array_equal(
        got.status, check_force_closure(positions[:2], normals[:2], 0.5).status)


def test_two_clients_with_the_same_ids_get_only_their_own_verdicts(own_node, grasps):
    own_node("/two_clients")
    positions, normals = grasps
    first = GraspClient("/two_clients/force_closure")
    second = GraspClient("/two_clients/force_closure")
    try:
        assert first.wait_for_node(REPLY_TIMEOUT_S) and second.wait_for_node(REPLY_TIMEOUT_S)
        # Same ids 0..29 from both; the second sends one-contact (invalid) grasps.
        a = [first.submit(positions[i], normals[i], query_id=i) for i in range(30)]
        b = [second.submit(positions[i][:1], normals[i][:1], query_id=i) for i in range(30)]
        batch_a = first.submit_batch(positions[:5], normals[:5])
        batch_b = second.submit_batch(positions[:5, :1], normals[:5, :1])
        expected = check_force_closure(positions[:30], normals[:30], 0.5).status
        assert [f.result(LOAD_TIMEOUT_S).status for f in a] == expected.tolist()
        assert all(f.result(LOAD_TIMEOUT_S).status == Status.INVALID_INPUT for f in b)
        np.testing.assert_array_equal(batch_a.result(LOAD_TIMEOUT_S).status, expected[:5])
        assert set(batch_b.result(LOAD_TIMEOUT_S).status) == {Status.INVALID_INPUT}
    finally:
        first.close()
        second.close()


def test_a_service_request_in_progress_at_shutdown_gets_its_answer(own_node, grasps,
                                                                   monkeypatch):
    node, spinner, _ = own_node("/service_shutdown_test", workers=1)
    positions, normals = (np.tile(a, (10, 1, 1)) for a in grasps)  # seconds on one worker
    # One request (the client would send this call in parts, and a part after the
    # node's end would find no node).
    monkeypatch.setattr(service_calls, "MAX_REQUEST_CONTACTS", positions.size // 3)
    client = GraspClient("/service_shutdown_test/force_closure")
    try:
        assert client.wait_for_node(REPLY_TIMEOUT_S)
        answer: list = []
        caller = threading.Thread(target=lambda: answer.append(
            client.call(positions, normals, timeout=LOAD_TIMEOUT_S)))
        caller.start()
        deadline = time.monotonic() + LOAD_TIMEOUT_S
        while node.statistics.received < len(positions):  # being decided now
            assert time.monotonic() < deadline, "the node never received the request"
            time.sleep(0.01)
        spinner.stop()
        caller.join(LOAD_TIMEOUT_S)
        [verdicts] = answer
        assert set(verdicts.status) == {Status.SOLVER_FAILURE}
        assert set(verdicts.messages) == {SHUTDOWN_MESSAGE}
    finally:
        client.close()
