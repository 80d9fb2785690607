"""grasp_fc_ros.interface.conversions without DDS: messages <-> packed numpy arrays."""

from __future__ import annotations

import math

import numpy as np
import pytest
from grasp_fc_msgs.msg import ContactArrayBatch
from hypothesis import given, settings
from hypothesis import strategies as st

from grasp_fc_ros.core import Status
from grasp_fc_ros.interface.conversions import (
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
from grasp_fc_ros.packed import Verdicts


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
    np.testing.assert_array_equal(back.status, [Status.FORCE_CLOSURE, Status.INVALID_INPUT])
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


# --- certificates and minimum friction in the verdict messages ---------------------------

def mixed_batch(seed=5):
    """A batch of 3-, 4- and 6-finger box grasps with one invalid grasp: its message and
    the stacked arrays (positions, normals (K, 3), mu (K,), counts (N,))."""
    from grasp_fc_ros.objects import make_object, sample_grasps

    rng = np.random.default_rng(seed)
    box = make_object("box")
    counts = rng.choice([3, 4, 6], size=40)
    pieces = [sample_grasps(box, 1, int(n), rng) for n in counts]
    positions = np.concatenate([p[0] for p, _ in pieces])
    normals = np.concatenate([q[0] for _, q in pieces])
    mu = rng.uniform(0.3, 1.0, size=len(positions))
    normals[counts[:5].sum() + 1] = 0.0  # grasp 5, contact 1: invalid
    msg = grasps_to_batch_msg(np.arange(40) + 500, positions, normals, mu, counts=counts)
    return msg, positions, normals, mu, counts


def decide(msg, **settings):
    from grasp_fc_ros.engine.evaluation import evaluate
    from grasp_fc_ros.packed import Settings

    verdicts, _ = evaluate(batch_to_packed(msg), Settings(**settings))
    return verdicts


def test_batch_certificates_are_packed_per_contact_and_verify():
    from grasp_fc_ros.core import verify_certificates

    msg, positions, normals, mu, counts = mixed_batch()
    reply = verdicts_to_array_msg(decide(msg, certificates=True), msg)
    total = int(counts.sum())
    assert (len(reply.contact_forces), len(reply.separating_wrenches)) == (3 * total, 6 * 40)
    assert len(reply.min_friction) == 0  # compute_min_friction off
    got = verdict_array_to_numpy(reply)
    assert got.min_friction is None
    assert got.status[5] == Status.INVALID_INPUT
    ends = np.cumsum(counts)
    for g, (lo, hi) in enumerate(zip(ends - counts, ends, strict=True)):
        if g == 5:  # invalid: nothing to verify
            assert np.isnan(got.contact_forces[lo:hi]).all()
            assert np.isnan(got.separating_wrench[g]).all()
            continue
        forces_ok, wrench_ok = verify_certificates(
            positions[lo:hi], normals[lo:hi], mu[lo:hi],
            got.contact_forces[lo:hi], got.separating_wrench[g])
        status = got.status[g]
        assert forces_ok == (status == Status.FORCE_CLOSURE), f"grasp {g}"
        if status != Status.FORCE_CLOSURE:
            assert np.isnan(got.contact_forces[lo:hi]).all(), f"grasp {g}"
        if status == Status.FORCE_CLOSURE:
            assert np.isnan(got.separating_wrench[g]).all(), f"grasp {g}"
        else:  # rejected: a separating wrench unless marginal (none in this sample)
            assert wrench_ok, f"grasp {g}"
    # Every kind of certificate must occur, or the loop above proves little.
    assert {Status.FORCE_CLOSURE, Status.NOT_FORCE_CLOSURE} <= set(got.status.tolist())


def test_certificates_off_leave_the_fields_empty():
    msg = mixed_batch()[0]
    reply = verdicts_to_array_msg(decide(msg), msg)
    assert (len(reply.contact_forces), len(reply.separating_wrenches),
            len(reply.min_friction)) == (0, 0, 0)
    got = verdict_array_to_numpy(reply)
    assert got.contact_forces is None and got.separating_wrench is None
    assert got.min_friction is None


def test_single_verdicts_carry_forces_only_for_force_closure_and_round_trip():
    from grasp_fc_ros.interface.conversions import verdict_msgs_to_numpy

    msg, positions, normals, mu, counts = mixed_batch()
    verdicts = decide(msg, certificates=True)
    ends = np.cumsum(counts)
    queries = [grasp_to_contact_array(500 + g, positions[lo:hi], normals[lo:hi], mu[lo:hi])
               for g, (lo, hi) in enumerate(zip(ends - counts, ends, strict=True))]
    replies = verdicts_to_msgs(verdicts, queries)
    for reply, count in zip(replies, counts, strict=True):
        fc = reply.status == Status.FORCE_CLOSURE
        assert len(reply.contact_forces) == (count if fc else 0)
        assert math.isnan(reply.min_friction)
    back = verdict_msgs_to_numpy(replies, counts)
    np.testing.assert_array_equal(back.contact_forces, verdicts.contact_forces)
    np.testing.assert_array_equal(back.separating_wrench, verdicts.separating_wrench)
    assert np.isnan(back.min_friction).all()
    fc = next(g for g, r in enumerate(replies) if r.contact_forces)
    with pytest.raises(ValueError, match=f"verdict 0 \\(id {500 + fc}\\) has"):
        verdict_msgs_to_numpy(replies[fc:fc + 1], [counts[fc] + 1])
    with pytest.raises(ValueError, match="need the queries"):
        verdicts_to_msgs(verdicts)


def test_single_verdicts_without_certificates_say_none_with_nan():
    replies = verdicts_to_msgs(make_verdicts())
    for reply in replies:
        assert reply.contact_forces == []
        w = reply.separating_wrench
        assert all(math.isnan(v) for v in (w.force.x, w.force.y, w.force.z,
                                           w.torque.x, w.torque.y, w.torque.z))
        assert math.isnan(reply.min_friction)


def test_min_friction_follows_the_query_proportions_and_is_nan_for_invalid():
    from grasp_fc_ros.core import check_force_closure

    msg, positions, normals, mu, counts = mixed_batch()
    got = verdict_array_to_numpy(verdicts_to_array_msg(
        decide(msg, compute_min_friction=True), msg))
    assert got.contact_forces is None and len(got.min_friction) == 40
    assert math.isnan(got.min_friction[5])
    ends = np.cumsum(counts)
    finite = 0
    for g, (lo, hi) in enumerate(zip(ends - counts, ends, strict=True)):
        mu_star = got.min_friction[g]
        if g == 5 or not np.isfinite(mu_star) or mu_star == 0:
            continue
        finite += 1
        ratios = mu[lo:hi] / mu[lo:hi].max()
        above = check_force_closure(positions[lo:hi], normals[lo:hi],
                                    mu_star * (1 + 1e-3) * ratios)
        below = check_force_closure(positions[lo:hi], normals[lo:hi],
                                    mu_star * (1 - 1e-3) * ratios)
        assert above.force_closure and not below.force_closure, f"grasp {g}: mu* {mu_star}"
    assert finite >= 20


def soft_pairs(seed=8, n_grasps=30):
    """Two-finger grasps on a sphere, nearly antipodal, soft or hard at random: only the
    soft pairs can be force closure, and only with their torques."""
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=(n_grasps, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    other = -axis + 0.1 * rng.normal(size=(n_grasps, 3))
    other /= np.linalg.norm(other, axis=1, keepdims=True)
    positions = 0.04 * np.stack([axis, other], axis=1)
    normals = -positions
    gamma = np.where(rng.random(n_grasps) < 0.6, 0.004, 0.0)[:, None].repeat(2, axis=1)
    return positions, normals, gamma


def test_soft_certificates_carry_torques_in_both_verdict_kinds():
    from grasp_fc_ros.core import verify_certificates
    from grasp_fc_ros.engine.evaluation import evaluate
    from grasp_fc_ros.interface.conversions import verdict_msgs_to_numpy
    from grasp_fc_ros.packed import Settings

    positions, normals, gamma = soft_pairs()
    msg = grasps_to_batch_msg(np.arange(30), positions, normals, 0.5,
                              torsional_friction=gamma)
    reply = verdicts_to_array_msg(decide(msg, certificates=True), msg)
    got = verdict_array_to_numpy(reply)
    assert got.contact_torques.shape == (60,)
    forces_ok, wrench_ok = verify_certificates(
        positions, normals, 0.5, got.contact_forces.reshape(30, 2, 3),
        got.separating_wrench, gamma, got.contact_torques.reshape(30, 2))
    fc = got.status == Status.FORCE_CLOSURE
    np.testing.assert_array_equal(forces_ok, fc)
    assert fc.any() and not fc[gamma[:, 0] == 0].any()  # hard pairs never
    # Rejected: a wrench that verifies, or none (NaN) for the hard pairs, whose rank < 6
    # leaves only a zero-work wrench that rounding blurs (documented as marginal).
    no_wrench = np.isnan(got.separating_wrench).all(axis=1)
    assert (wrench_ok | no_wrench)[~fc].all()
    assert wrench_ok[~fc & (gamma[:, 0] > 0)].all()
    # The same grasps as single queries: torques only in the FORCE_CLOSURE verdicts.
    queries = [grasp_to_contact_array(i, p, n, 0.5, torsional_friction=g)
               for i, (p, n, g) in enumerate(zip(positions, normals, gamma, strict=True))]
    verdicts, _ = evaluate(contact_arrays_to_packed(queries), Settings(certificates=True))
    singles = verdicts_to_msgs(verdicts, queries)
    assert [len(v.contact_torques) for v in singles] == [2 * int(f) for f in fc]
    back = verdict_msgs_to_numpy(singles, [2] * 30)
    np.testing.assert_array_equal(back.contact_torques, got.contact_torques)
    # An all-hard batch sends no torques at all.
    hard = grasps_to_batch_msg(np.arange(30), positions, normals, 0.5)
    assert len(verdicts_to_array_msg(decide(hard, certificates=True), hard).contact_torques) == 0
