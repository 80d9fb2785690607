"""The node's serialized single-query path (grasp_fc_ros.wire) answers as the message path.

Queries that path does not take (soft contacts) go through the message path in their
place in the arrival order; without a matching layout the node takes the message path
for everything.
"""

from __future__ import annotations

import numpy as np
import pytest
from rclpy.serialization import serialize_message

from ros_fixtures import REPLY_TIMEOUT_S

from grasp_fc_ros import node as node_module
from grasp_fc_ros.conversions import (grasp_to_contact_array, grasps_to_batch_msg,
                                      verdict_array_to_numpy)
from grasp_fc_ros.core import Status, check_force_closure
from grasp_fc_ros.objects import make_object, sample_grasps

DEFAULT_MU = 0.5


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
        msg = grasp_to_contact_array(100 + i, positions[i], normals[i], client_id=9000 + i)
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
    for v, m, status in zip(verdicts, msgs, expected.status.tolist()):
        assert (v.client_id, v.header.frame_id, v.header.stamp.sec, v.header.stamp.nanosec) == (
            m.client_id, m.header.frame_id, m.header.stamp.sec, m.header.stamp.nanosec)
        assert v.status == status and v.force_closure == (status == Status.FORCE_CLOSURE)


@pytest.mark.parametrize("soft", [(), (0,), (3, 4, 9), (11,)])
def test_serialized_path_answers_every_query_once_in_order(own_node, grasps, soft):
    node, _, client = own_node(f"/wire_test_{len(soft)}_{sum(soft)}", workers=0)
    assert node._use_wire
    msgs = queries(grasps, soft)
    # Soft contacts are decided as hard ones until the node supports them: the point here
    # is only that they take the other path without losing their place. One drain of the
    # whole list, as the singles thread would pass it, so that the runs really split.
    node._answer_single_queries([serialize_message(m) for m in msgs])
    assert_answers(client.wait_for("verdicts", len(msgs)), msgs, grasps)


def test_without_the_layout_the_message_path_answers(own_node, grasps, monkeypatch):
    monkeypatch.setattr(node_module.wire, "layout_matches", lambda: False)
    node, _, client = own_node("/wire_test_off", workers=0)
    assert not node._use_wire
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
    msgs = queries(grasps)[:3]
    msgs[1].contacts[2].normal.x = msgs[1].contacts[2].normal.y = 0.0
    msgs[1].contacts[2].normal.z = 0.0
    verdicts = send_and_collect(client, msgs)
    assert [v.id for v in verdicts] == [100, 101, 102]
    assert verdicts[1].status == Status.INVALID_INPUT
    assert verdicts[1].message == "query id 101, contact 2: normal has zero length"
    assert verdicts[0].message == verdicts[2].message == ""
