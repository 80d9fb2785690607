"""grasp_fc_ros.conversions without DDS: messages <-> packed numpy arrays."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from grasp_fc_msgs.msg import ContactArrayBatch
from grasp_fc_ros.conversions import (
    MalformedBatch,
    batch_size,
    batch_to_packed,
    contact_arrays_to_packed,
    grasp_to_contact_array,
    grasps_to_batch_msg,
    verdict_array_to_numpy,
    verdicts_to_array_msg,
    verdicts_to_msgs,
)
from grasp_fc_ros.core import Status
from grasp_fc_ros.evaluation import Verdicts


@settings(max_examples=40, deadline=None)
@given(sizes=st.lists(st.integers(0, 7), max_size=12), seed=st.integers(0, 2**32 - 1),
       with_mu=st.booleans())
def test_batch_round_trip_keeps_every_value_in_place(sizes, seed, with_mu):
    rng = np.random.default_rng(seed)
    total = sum(sizes)
    positions, normals = rng.normal(size=(total, 3)), rng.normal(size=(total, 3))
    mu = rng.uniform(0, 1, total) if with_mu else None
    ids = rng.integers(0, 2**63, size=len(sizes), dtype=np.uint64)
    msg = grasps_to_batch_msg(ids, positions, normals, mu, counts=sizes, client_id=5,
                              request_id=9)
    assert (msg.client_id, msg.request_id, batch_size(msg)) == (5, 9, len(sizes))
    packed = batch_to_packed(msg)
    np.testing.assert_array_equal(packed.ids, ids)
    np.testing.assert_array_equal(packed.counts, sizes)
    np.testing.assert_array_equal(packed.positions, positions)
    np.testing.assert_array_equal(packed.normals, normals)
    np.testing.assert_array_equal(packed.mu, mu if with_mu else np.zeros(total))


@pytest.mark.parametrize("field, change, what", [
    ("contact_counts", lambda v: v[:1], "1 contact counts for 2 ids"),
    ("contact_counts", lambda v: v + v, "4 contact counts for 2 ids"),
    ("positions", lambda v: v[:-1], "positions has 23 values"),
    ("normals", lambda v: v + v[:3], "normals 27"),
    ("friction_coefficients", lambda v: v[:7], "friction_coefficients 7"),
])
def test_mis_packed_batch_raises_naming_the_mismatch(field, change, what):
    msg = grasps_to_batch_msg([1, 2], np.ones((2, 4, 3)), np.ones((2, 4, 3)), mu=0.5)
    setattr(msg, field, change(getattr(msg, field)))
    with pytest.raises(MalformedBatch, match="malformed batch") as info:
        batch_to_packed(msg)
    assert what in str(info.value)


def test_empty_batch_converts_to_nothing():
    packed = batch_to_packed(ContactArrayBatch())
    assert len(packed) == 0 and packed.positions.shape == (0, 3)


def test_contact_arrays_stack_in_order_with_their_friction():
    grasps = [grasp_to_contact_array(7, np.ones((2, 3)), -np.ones((2, 3)), mu=[0.1, 0.2]),
              grasp_to_contact_array(8, np.zeros((3, 3)), np.eye(3), mu=0.0, client_id=4)]
    assert grasps[1].client_id == 4
    packed = contact_arrays_to_packed(grasps, name_by_id=True)
    np.testing.assert_array_equal(packed.ids, [7, 8])
    np.testing.assert_array_equal(packed.counts, [2, 3])
    np.testing.assert_array_equal(packed.normals[2:], np.eye(3))
    np.testing.assert_array_equal(packed.mu, [0.1, 0.2, 0, 0, 0])
    assert packed.label(1) == "query id 8"


def make_verdicts() -> Verdicts:
    return Verdicts(ids=np.array([3, 4], np.uint64), force_closure=np.array([True, False]),
                    status=np.array([Status.FORCE_CLOSURE, Status.INVALID_INPUT], np.uint8),
                    margin=np.array([0.25, math.nan]), messages=["", "bad"])


def test_verdict_array_copies_header_client_and_request_id_and_round_trips():
    query = grasps_to_batch_msg([3, 4], np.ones((2, 2, 3)), np.ones((2, 2, 3)),
                                client_id=11, request_id=12)
    query.header.frame_id = "palm"
    query.header.stamp.sec = 42
    msg = verdicts_to_array_msg(make_verdicts(), query)
    assert (msg.client_id, msg.request_id) == (11, 12)
    assert msg.header.frame_id == "palm" and msg.header.stamp.sec == 42
    back = verdict_array_to_numpy(msg)
    np.testing.assert_array_equal(back.ids, [3, 4])
    np.testing.assert_array_equal(back.status, [0, 3])
    np.testing.assert_array_equal(back.margin, [0.25, math.nan])
    assert back.messages == ["", "bad"] and back.force_closure.tolist() == [True, False]


def test_single_verdicts_copy_each_query_header_and_client_id():
    queries = [grasp_to_contact_array(3, np.ones((2, 3)), np.ones((2, 3)), client_id=21),
               grasp_to_contact_array(4, np.ones((2, 3)), np.ones((2, 3)), client_id=22)]
    queries[1].header.frame_id = "world"
    replies = verdicts_to_msgs(make_verdicts(), queries)
    assert [(r.id, r.client_id, r.header.frame_id) for r in replies] == [
        (3, 21, ""), (4, 22, "world")]
    assert replies[1].message == "bad" and math.isnan(replies[1].margin)
    with pytest.raises(ValueError):
        verdicts_to_msgs(make_verdicts(), queries[:1])
