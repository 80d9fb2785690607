"""The torque filter never rejects a force-closure grasp (random and adversarial)."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from grasp_cases import MU_PAPER, adversarial_grasps, ellipsoid_grasps, random_rotation
from grasp_fc_ros.core import check_force_closure, exact_force_closure, torque_filter


@pytest.mark.parametrize("n_contacts", [3, 4, 6, 8])
@pytest.mark.parametrize("mu", [MU_PAPER, 0.5, 1.2])
def test_filter_is_sound_on_random_grasps(n_contacts, mu):
    rng = np.random.default_rng(n_contacts)
    positions, normals = ellipsoid_grasps(rng, 600, n_contacts)
    exact = exact_force_closure(positions, normals, mu)
    for origins in ("seed", "all"):
        passed = torque_filter(positions, normals, mu, origins=origins)
        assert not np.any(exact & ~passed), f"origins={origins} rejected a force-closure grasp"
    if n_contacts >= 4:
        assert exact.any() and (~torque_filter(positions, normals, mu)).any()


def test_all_origins_reject_at_least_what_seed_origins_reject():
    rng = np.random.default_rng(1)
    positions, normals = ellipsoid_grasps(rng, 3000, 6)
    seed = torque_filter(positions, normals, MU_PAPER, origins="seed")
    every = torque_filter(positions, normals, MU_PAPER, origins="all")
    assert not np.any(every & ~seed)
    assert (seed & ~every).sum() > 0


@pytest.mark.parametrize("seed", range(25))
@pytest.mark.parametrize("mu", [MU_PAPER, 0.8])
def test_filter_is_sound_on_adversarial_grasps(seed, mu):
    rng = np.random.default_rng(seed)
    cases = adversarial_grasps(rng, mu=mu)
    positions = np.array([p for p, _ in cases])
    normals = np.array([n for _, n in cases])
    exact = exact_force_closure(positions, normals, mu)
    for origins in ("seed", "all"):
        assert not np.any(exact & ~torque_filter(positions, normals, mu, origins=origins))


def test_per_contact_friction_is_respected():
    rng = np.random.default_rng(5)
    positions, normals = ellipsoid_grasps(rng, 800, 5)
    mu = rng.uniform(0.05, 1.0, size=(800, 5))
    exact = exact_force_closure(positions, normals, mu)
    assert not np.any(exact & ~torque_filter(positions, normals, mu, origins="all"))
    # Lowering one contact's friction can only remove force closure.
    lower = mu.copy()
    lower[:, 0] *= 0.2
    assert not np.any(exact_force_closure(positions, normals, lower) & ~exact)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_contacts=st.integers(3, 9),
       mu=st.floats(0.05, 1.5), log_scale=st.floats(-6, 6),
       shift=st.floats(-1e3, 1e3))
def test_filter_stays_sound_and_exact_verdicts_invariant_under_rigid_motion_and_scale(
        seed, n_contacts, mu, log_scale, shift):
    rng = np.random.default_rng(seed)
    positions, normals = ellipsoid_grasps(rng, 40, n_contacts, axes=rng.uniform(0.5, 3, 3))
    rotation = random_rotation(rng)
    moved = (positions @ rotation.T) * 10.0 ** log_scale + shift
    turned = normals @ rotation.T
    order = rng.permutation(n_contacts)

    original = check_force_closure(positions, normals, mu, use_filter=False)
    transformed = check_force_closure(moved[:, order], turned[:, order], mu, use_filter=False)
    assert np.array_equal(original.force_closure, transformed.force_closure)
    assert np.allclose(original.margin, transformed.margin, atol=1e-6)
    for origins in ("seed", "all"):
        passed = torque_filter(moved[:, order], turned[:, order], mu, origins=origins)
        assert not np.any(transformed.force_closure & ~passed)
