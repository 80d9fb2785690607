"""GraspClient checks its arrays' shapes before it sends or registers anything: every
entry raises ValueError naming the arrays and their shapes (docs/client.md), instead of
a zip or broadcast error or a mis-shaped batch the node refuses whole."""

from __future__ import annotations

import re

import numpy as np
import pytest

from grasp_fc_ros.client import shapes

pytestmark = pytest.mark.timeout(120)

P = np.ones((3, 4, 3))      # 3 grasps of 4 contacts
WIDER = np.ones((3, 5, 3))  # normals of 5 contacts
STACKED = P.reshape(-1, 3)  # (12, 3)


@pytest.fixture(scope="module")
def lonely(ros):
    """A client of a node that does not exist: whatever it sent would go unanswered."""
    from grasp_fc_ros.client import GraspClient

    client = GraspClient("/nobody_for_shapes/force_closure")
    yield client
    client.close()


# (entry, call, what the message must name)
MISSHAPEN = [
    ("call", lambda c: c.call(P, WIDER, timeout=0.2),
     "positions has shape (3, 4, 3) but normals (3, 5, 3)"),
    ("call", lambda c: c.call(P[0], P[0], timeout=0.2),
     "positions has shape (4, 3), but a batch is (N, n, 3)"),
    ("call", lambda c: c.call(P, P, mu=np.ones(3), timeout=0.2),
     "mu has shape (3,), but positions (3, 4, 3) have (3, 4) contacts"),
    ("call", lambda c: c.call(P, P, ids=[1, 2], timeout=0.2),
     "ids has shape (2,), but there are 3 grasps"),
    ("compute_contact_forces",
     lambda c: c.compute_contact_forces(P[0], WIDER[0], np.zeros(6), timeout=0.2),
     "positions has shape (4, 3) but normals (5, 3)"),
    ("compute_contact_forces",
     lambda c: c.compute_contact_forces(P[0], P[0], np.zeros(5), timeout=0.2),
     "wrench has shape (5,), but a wrench is (6,)"),
    ("compute_contact_forces",
     lambda c: c.compute_contact_forces(P[0], P[0], np.zeros(6), max_normal_forces=[1, 2],
                                        timeout=0.2),
     "max_normal_forces has shape (2,), but positions (4, 3) have (4,) contacts"),
    ("submit", lambda c: c.submit(P[0], WIDER[0]),
     "positions has shape (4, 3) but normals (5, 3)"),
    ("submit", lambda c: c.submit(P, P), "positions has shape (3, 4, 3), but one grasp is"),
    ("submit", lambda c: c.submit(P[0], P[0], mu=[0.5, 0.5]),
     "mu has shape (2,), but positions (4, 3) have (4,) contacts"),
    ("submit_batch", lambda c: c.submit_batch(P, WIDER),
     "positions has shape (3, 4, 3) but normals (3, 5, 3)"),
    ("check_batch", lambda c: c.check_batch(P, WIDER, timeout=0.2),
     "positions has shape (3, 4, 3) but normals (3, 5, 3)"),
    ("check_batch", lambda c: c.check_batch(P, P, ids=[1, 2], timeout=0.2),
     "ids has shape (2,), but there are 3 grasps"),
    ("check_batch", lambda c: c.check_batch(STACKED, STACKED, counts=[4, 4], timeout=0.2),
     "counts sum to 8 contacts, but positions has 12 (shape (12, 3))"),
    ("check_batch", lambda c: c.check_batch(STACKED, STACKED, timeout=0.2),
     "positions has shape (12, 3), but a batch is (N, n, 3): N grasps of n contacts (or "
     "stacked (K, 3) with counts)"),
    ("check_batch", lambda c: c.check_batch(P, P, mu=np.ones(3), timeout=0.2),
     "mu has shape (3,), but positions (3, 4, 3) have (3, 4) contacts: give one value, one "
     "per contact (3, 4), one per grasp (3, 1), or None"),
    ("check_batch", lambda c: c.check_batch(P, P, torsional_friction=np.ones(5), timeout=0.2),
     "torsional_friction has shape (5,)"),
    ("label_grasps", lambda c: c.label_grasps(P, WIDER, progress=False, timeout=0.5),
     "positions has shape (3, 4, 3) but normals (3, 5, 3)"),
    ("label_grasps", lambda c: c.label_grasps(STACKED, STACKED, counts=[4, 4, 5],
                                              progress=False, timeout=0.5),
     "counts sum to 13 contacts, but positions has 12"),
]


@pytest.mark.parametrize("entry,send,message", MISSHAPEN,
                         ids=[f"{entry}-{i}" for i, (entry, _, _) in enumerate(MISSHAPEN)])
def test_every_entry_names_the_misshapen_arrays_and_sends_nothing(lonely, entry, send,
                                                                 message):
    with pytest.raises(ValueError, match=re.escape(message)):
        send(lonely)
    assert lonely.in_flight == 0  # nothing registered (so nothing sent or re-sent)


@pytest.mark.parametrize("mu", [None, 0.5, np.full(4, 0.5), np.full((3, 1), 0.5),
                                np.full((3, 4), 0.5), np.full(12, 0.5), np.empty(0)])
def test_every_documented_friction_form_of_a_batch_is_accepted(mu):
    shapes.per_contact(mu, "mu", P, flat=True)


def test_stacked_grasps_of_mixed_sizes_are_accepted():
    positions, normals, n_grasps = shapes.grasp_batch(STACKED[:7], STACKED[:7], [3, 4])
    assert n_grasps == 2 and positions.shape == (7, 3)
    shapes.per_contact(np.full(7, 0.5), "mu", positions, flat=True)
    with pytest.raises(ValueError, match="counts must not be negative"):
        shapes.grasp_batch(STACKED[:7], STACKED[:7], [8, -1])
    with pytest.raises(ValueError, match=r"counts must be \(N,\) integers"):
        shapes.grasp_batch(STACKED[:7], STACKED[:7], [3.5, 3.5])


def test_the_service_takes_only_friction_that_broadcasts():
    """The service request is built contact by contact from (N, n): a flat (K,) mu
    does not go there."""
    shapes.per_contact(np.full((3, 1), 0.5), "mu", P)
    with pytest.raises(ValueError, match=r"mu has shape \(12,\)"):
        shapes.per_contact(np.full(12, 0.5), "mu", P)


def test_one_grasps_limits_broadcast_and_wrong_ones_are_named():
    shapes.per_contact(10.0, "max_normal_forces", P[0])
    shapes.per_contact([1.0, 2.0, 3.0, 4.0], "max_normal_forces", P[0])
    with pytest.raises(ValueError, match=r"max_normal_forces has shape \(4, 1\)"):
        shapes.per_contact(np.ones((4, 1)), "max_normal_forces", P[0])
    with pytest.raises(ValueError, match="positions must be an array of numbers"):
        shapes.one_grasp([["a", 0, 0]], [[1, 0, 0]])
