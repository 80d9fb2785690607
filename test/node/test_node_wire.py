"""The node's serialized single-query path (grasp_fc_ros.interface.wire) answers as the
message path.

Queries that path does not take (soft contacts) go through the message path in their
place in the arrival order; without a matching layout the node takes the message path
for everything. Batches taken serialized keep their header and ids and get the core's
verdicts; bytes that are no batch are logged and dropped.
"""

from __future__ import annotations

import numpy as np
import pytest
from rclpy.serialization import serialize_message

from grasp_fc_ros.core import Status, check_force_closure
from grasp_fc_ros.interface import wire
from grasp_fc_ros.interface.conversions import (
    grasp_to_contact_array,
    grasps_to_batch_msg,
    verdict_array_to_numpy,
)
from grasp_fc_ros.objects import make_object, sample_grasps
from ros_fixtures import REPLY_TIMEOUT_S

DEFAULT_MU = 0.5
# The queries' client id: their answers come on its reply topic (client.listen).
CLIENT_ID = 9000


@pytest.fixture(scope="module")
def grasps():
    return sample_grasps(make_object("box"), 12, 6, np.random.default_rng(41))


def send_and_collect(client, msgs):
    for msg in msgs:
        client.contacts_pub.publish(msg)
    return client.wait_for("verdicts", len(msgs), timeout=REPLY_TIMEOUT_S)


def queries(grasps, soft=()):
    positions, normals = grasps
    msgs = []
    for i in range(len(positions)):
        msg = grasp_to_contact_array(100 + i, positions[i], normals[i], client_id=CLIENT_ID)
        msg.header.frame_id = f"frame_{i}" * (i % 3)
        msg.header.stamp.sec, msg.header.stamp.nanosec = 1000 + i, 7 * i
        if i in soft:
            msg.contacts[0].torsional_friction = 0.01
        msgs.append(msg)
    return msgs


def assert_answers(verdicts, msgs, grasps):
    positions, normals = grasps
    assert [v.id for v in verdicts] == [m.id for m in msgs]  # each once, in order
    expected = check_force_closure(positions, normals, DEFAULT_MU)
    for v, m, status in zip(verdicts, msgs, expected.status.tolist(), strict=True):
        assert (v.client_id, v.header.frame_id, v.header.stamp.sec, v.header.stamp.nanosec) == (
            m.client_id, m.header.frame_id, m.header.stamp.sec, m.header.stamp.nanosec)
        assert v.status == status and v.force_closure == (status == Status.FORCE_CLOSURE)


@pytest.mark.parametrize("soft", [(), (0,), (3, 4, 9), (11,)])
def test_serialized_path_answers_every_query_once_in_order(own_node, grasps, soft):
    node, _, client = own_node(f"/wire_test_{len(soft)}_{sum(soft)}", workers=0)
    client.listen(CLIENT_ID)
    assert node.uses_wire
    msgs = queries(grasps, soft)
    # Soft contacts are decided as hard ones until the node supports them: the point here
    # is only that they take the other path without losing their place. One drain of the
    # whole list, as the singles thread would pass it, so that the runs really split.
    node.single_queries.answer([serialize_message(m) for m in msgs])
    assert_answers(client.wait_for("verdicts", len(msgs)), msgs, grasps)


def test_without_the_layout_the_message_path_answers(own_node, grasps, monkeypatch):
    monkeypatch.setattr(wire, "layout_matches", lambda: False)
    node, _, client = own_node("/wire_test_off", workers=0)
    client.listen(CLIENT_ID)
    assert not node.uses_wire
    msgs = queries(grasps)
    assert_answers(send_and_collect(client, msgs), msgs, grasps)
    # Batch answers too go out as rclpy messages then.
    positions, normals = grasps
    reply = client.request_batch(grasps_to_batch_msg(np.arange(len(positions)) + 7,
                                                     positions, normals))
    got = verdict_array_to_numpy(reply)
    np.testing.assert_array_equal(got.ids, np.arange(len(positions)) + 7)
    np.testing.assert_array_equal(got.status,
                                  check_force_closure(positions, normals, DEFAULT_MU).status)


def test_invalid_query_on_the_serialized_path_names_its_id(own_node, grasps):
    _, _, client = own_node("/wire_test_invalid", workers=0)
    client.listen(CLIENT_ID)
    msgs = queries(grasps)[:3]
    msgs[1].contacts[2].normal.x = msgs[1].contacts[2].normal.y = 0.0
    msgs[1].contacts[2].normal.z = 0.0
    verdicts = send_and_collect(client, msgs)
    assert [v.id for v in verdicts] == [100, 101, 102]
    assert verdicts[1].status == Status.INVALID_INPUT
    assert verdicts[1].message == ("query id 101, contact 2: normal has zero "
                                   "length, got (0, 0, 0)")
    assert verdicts[0].message == verdicts[2].message == ""


# --- batches on the serialized path ---------------------------------------------------


def mixed_batch(grasps):
    """batch_arrays arguments of the fixture's grasps with per-contact friction (some
    too low, some 0: the node's default) and an invalid grasp (4)."""
    positions, normals = grasps
    positions, normals = positions.copy(), normals.copy()
    normals[4, 1] = 0.0  # grasp 4: a zero normal
    mu = np.tile(np.linspace(0.05, 0.9, positions.shape[1]), (len(positions), 1))
    mu[::3] = 0.0
    return dict(ids=np.arange(len(positions), dtype=np.uint64) + 2**63 + 5,
                positions=positions, normals=normals, mu=mu, counts=None,
                torsional_friction=None)


def test_a_batch_taken_serialized_keeps_its_header_ids_and_verdicts(own_node, grasps):
    from grasp_fc_ros.interface.conversions import grasps_to_batch_msg

    node, _, client = own_node("/wire_test_batch", workers=0)
    client.listen(2**64 - 1)
    assert node.uses_wire  # the node reads batches with wire.decode_contact_array_batch
    args = mixed_batch(grasps)
    msg = grasps_to_batch_msg(args["ids"], args["positions"], args["normals"], args["mu"],
                              client_id=2**64 - 1, request_id=2**64 - 2)
    msg.header.frame_id = "wrist_ü"
    msg.header.stamp.sec, msg.header.stamp.nanosec = -5, 999
    client.batch_pub.publish(msg)
    reply = client.batch_reply(2**64 - 2)
    assert (reply.client_id, reply.header.frame_id, reply.header.stamp.sec,
            reply.header.stamp.nanosec) == (2**64 - 1, "wrist_ü", -5, 999)
    got = verdict_array_to_numpy(reply)
    np.testing.assert_array_equal(got.ids, args["ids"])
    assert {Status.FORCE_CLOSURE, Status.INVALID_INPUT} <= set(got.status.tolist())
    assert len(set(got.status.tolist())) >= 3
    valid = np.arange(len(args["ids"])) != 4
    expected = check_force_closure(args["positions"][valid], args["normals"][valid],
                                   np.where(args["mu"] <= 0, DEFAULT_MU, args["mu"])[valid])
    np.testing.assert_array_equal(got.status[valid], expected.status)
    assert got.status[4] == Status.INVALID_INPUT


def test_a_big_endian_batch_is_read_by_rclpy_and_answered(own_node, grasps):
    from grasp_fc_ros.interface.conversions import batch_arrays
    from interface.test_wire import big_endian_batch

    _, _, client = own_node("/wire_test_big_endian", workers=0)
    client.listen(3)
    positions, normals = grasps
    ids = np.arange(len(positions), dtype=np.uint64) + 40
    client.batch_pub.publish(big_endian_batch(batch_arrays(ids, positions, normals),
                                              3, 77, "palm", (1, 2)))
    reply = client.batch_reply(77)
    assert (reply.client_id, reply.header.frame_id) == (3, "palm")
    got = verdict_array_to_numpy(reply)
    np.testing.assert_array_equal(got.ids, ids)
    np.testing.assert_array_equal(got.status,
                                  check_force_closure(positions, normals, DEFAULT_MU).status)


def test_unreadable_bytes_on_contacts_batch_do_not_stop_the_node(own_node, grasps):
    node, _, client = own_node("/wire_test_garbage", workers=0)
    rng = np.random.default_rng(5)
    garbage = [b"\x00\x01\x00\x00" + rng.bytes(3), b"\x00\x01\x00\x00", b"\xff" * 5]
    for raw in garbage:
        client.batch_pub.publish(raw)
    positions, normals = grasps
    reply = client.request_batch(grasps_to_batch_msg(np.arange(len(positions)) + 11,
                                                     positions, normals))
    np.testing.assert_array_equal(verdict_array_to_numpy(reply).ids,
                                  np.arange(len(positions)) + 11)
    assert len(client.wait_for("batches", 1)) == 1  # no reply to the garbage
    # Each counted as an internal error (taken in order, before the valid batch).
    assert node.statistics.callback_errors == len(garbage)
