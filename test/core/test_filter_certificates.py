"""The filter's separating wrenches: every rejected grasp gets one that no contact
force does positive work on, in the caller's frame about the caller's origin."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from grasp_cases import MU_PAPER, adversarial_grasps, ellipsoid_grasps, random_rotation
from grasp_fc_ros.core import exact_force_closure, torque_filter


def most_work(positions, normals, mu, wrench):
    """The user's check: per contact n.a + mu |a_t| with a = w_force + w_torque x p,
    and max_j |a_j|. Shapes (N, n, 3), (N, n, 3), (N, n), (N, 6) -> (N, n), (N,)."""
    normals = normals / np.linalg.norm(normals, axis=2, keepdims=True)
    a = wrench[:, None, :3] + np.cross(wrench[:, None, 3:], positions)
    normal_part = (a * normals).sum(axis=2)
    tangential = np.linalg.norm(a - normal_part[..., None] * normals, axis=2)
    return normal_part + mu * tangential, np.linalg.norm(a, axis=2).max(axis=1)


def check_certificates(positions, normals, mu, origins, rounding=0.0):
    """Run the filter with certificates and assert everything about them."""
    mu = np.broadcast_to(mu, positions.shape[:2])
    plain = torque_filter(positions, normals, mu, origins=origins)
    passed, wrench = torque_filter(positions, normals, mu, origins=origins,
                                   certificates=True)
    assert wrench.shape == (len(positions), 6)
    assert np.isnan(wrench[passed]).all()
    rejected = ~passed
    assert np.isfinite(wrench[rejected]).all()
    assert np.allclose(np.linalg.norm(wrench[rejected], axis=1), 1.0)
    work, largest = most_work(positions[rejected], normals[rejected], mu[rejected],
                              wrench[rejected])
    # rounding: an allowance for a_j that are all rounding noise (collinear contacts).
    floor = rounding * np.finfo(float).eps * (1 + mu[rejected]) * (
        1 + np.abs(positions[rejected]).max(axis=(1, 2)))[:, None]
    assert (work <= 1e-6 * largest[:, None] + floor).all(), work.max()
    # With certificates a rejection never appears that the plain filter did not make.
    assert not np.any(plain & ~passed)
    return plain, passed


@pytest.mark.parametrize("n_contacts", [3, 4, 6, 8, 14])
@pytest.mark.parametrize("mu", [MU_PAPER, 0.5, 1.2])
@pytest.mark.parametrize("origins", ["seed", "all"])
def test_every_rejection_of_random_grasps_has_a_separating_wrench(n_contacts, mu, origins):
    rng = np.random.default_rng(n_contacts)
    positions, normals = ellipsoid_grasps(rng, 300, n_contacts)
    # Half of the grasps on the upper half only: many are not force closure at any mu.
    upper = np.abs(positions[:150, :, 2])
    normals[:150, :, 2] *= np.sign(positions[:150, :, 2])
    positions[:150, :, 2] = upper
    rotation = random_rotation(rng)
    positions = positions @ rotation.T + rng.normal(size=3)
    normals = normals @ rotation.T
    plain, passed = check_certificates(positions, normals, mu, origins)
    # On grasps in general position no certificate fails its check.
    assert np.array_equal(plain, passed)
    if n_contacts <= 8 or mu == MU_PAPER:
        assert (~passed).sum() >= (10 if mu == MU_PAPER else 1)


@pytest.mark.parametrize("seed", range(12))
@pytest.mark.parametrize("mu", [MU_PAPER, 0.8])
def test_adversarial_rejections_have_separating_wrenches(seed, mu):
    rng = np.random.default_rng(seed)
    cases = adversarial_grasps(rng, mu=mu)
    positions = np.array([p for p, _ in cases])
    normals = np.array([n for _, n in cases])
    exact = exact_force_closure(positions, normals, mu)
    for origins in ("seed", "all"):
        _, passed = check_certificates(positions, normals, mu, origins, rounding=64)
        assert not np.any(exact & ~passed)


@pytest.mark.parametrize("mu", [MU_PAPER, 0.5, 3.0])
def test_contacts_sharing_one_normal_each_doubled_are_rejected_with_wrenches(mu):
    """Three contacts on one face of a box, each doubled 1e-9 apart (issue 9's case)."""
    rng = np.random.default_rng(4)
    face = np.concatenate([rng.uniform(-1, 1, (100, 3, 2)), np.zeros((100, 3, 1))], axis=2)
    positions = np.concatenate([face, face + rng.uniform(-1e-9, 1e-9, face.shape)], axis=1)
    normals = np.broadcast_to([0.0, 0.0, 1.0], positions.shape).copy()
    for origins in ("seed", "all"):
        plain, passed = check_certificates(positions, normals, mu, origins, rounding=64)
        assert (~passed).sum() >= 10


def test_a_duplicate_of_the_origin_contact_does_no_work():
    positions = np.array([[0.0, 0, 0], [0, 0, 0], [1, 0, 0.2], [0.5, 1, 0.1]])
    normals = np.array([[0.0, 0, 1], [0, 0, 1], [0, 0, 1], [0, 0, 1]])
    passed, wrench = torque_filter(positions[None], normals[None], 0.3, origins="all",
                                   certificates=True)
    assert not passed[0]
    work, largest = most_work(positions[None], normals[None], np.full((1, 4), 0.3), wrench)
    assert (work <= 1e-6 * largest).all()


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_contacts=st.integers(3, 30),
       mu=st.floats(0.01, 2.0), log_scale=st.floats(-100, 100))
def test_certificates_hold_over_scales_and_contact_counts(seed, n_contacts, mu, log_scale):
    rng = np.random.default_rng(seed)
    positions, normals = ellipsoid_grasps(rng, 20, n_contacts, axes=rng.uniform(0.5, 3, 3))
    scale = 10.0 ** log_scale
    # Near the origin, so that a_i = w_force + w_torque x p_i carries no cancellation.
    positions = (positions + rng.uniform(-1, 1, 3)) * scale
    check_certificates(positions, normals, mu, "seed")
