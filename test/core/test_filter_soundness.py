"""The torque filter never rejects a force-closure grasp (random and adversarial)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from grasp_cases import MU_PAPER, adversarial_grasps, ellipsoid_grasps, random_rotation
from grasp_fc_ros.core import (
    check_force_closure,
    exact_force_closure,
    torque_filter,
    validate_grasps,
)


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


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_contacts=st.integers(3, 40),
       mu=st.floats(0.005, 2.0), near_face=st.booleans())
def test_filter_is_sound_for_every_positive_span_path(seed, n_contacts, mu, near_face):
    """Pair test (few contacts), extreme-subset proof and hull test (many), with and
    without certificates, never reject a grasp the exact test calls force closure."""
    rng = np.random.default_rng(seed)
    positions, normals = ellipsoid_grasps(rng, 16, n_contacts, axes=rng.uniform(0.5, 3, 3))
    if near_face:  # many grasps that are not force closure, and near-threshold ones
        positions[..., 2] = rng.uniform(-0.05, 0.05, positions.shape[:2])
        normals = [0.0, 0.0, 1.0] + rng.uniform(-0.5, 0.5, normals.shape)
    exact = exact_force_closure(positions, normals, mu)
    for origins in ("seed", "all"):
        passed = torque_filter(positions, normals, mu, origins=origins)
        with_certificates, _ = torque_filter(positions, normals, mu, origins=origins,
                                             certificates=True)
        assert not np.any(exact & ~passed)
        assert not np.any(exact & ~with_certificates)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_contacts=st.integers(2, 9),
       log_scale=st.floats(-150, 150), log_normal_scale=st.floats(-150, 150),
       corrupt=st.sampled_from(["none", "nan", "zero normal", "mu", "huge"]))
def test_validation_and_filter_do_not_depend_on_the_scale(seed, n_contacts, log_scale,
                                                          log_normal_scale, corrupt):
    """Positions scaled by 1e-150 .. 1e150 and normals by 1e-150 .. 1e150: the same
    grasps are valid, with the same reasons, and the filter stays sound."""
    rng = np.random.default_rng(seed)
    positions, normals = ellipsoid_grasps(rng, 12, n_contacts)
    mu = np.full((12, n_contacts), 0.4)
    bad = rng.integers(12)
    if corrupt == "nan":
        positions[bad, 0, 1] = np.nan
    elif corrupt == "zero normal":
        normals[bad, -1] = 0.0
    elif corrupt == "mu":
        mu[bad, 0] = -1.0
    elif corrupt == "huge":
        positions[bad, 0, 0] = 1e302 / 10.0 ** log_scale   # beyond the bound once scaled
    scaled_positions = positions * 10.0 ** log_scale
    scaled_normals = normals * 10.0 ** log_normal_scale
    reference = validate_grasps(positions if corrupt != "huge" else scaled_positions,
                                normals, mu)
    scaled = validate_grasps(scaled_positions, scaled_normals, mu)
    assert np.array_equal(reference.valid, scaled.valid)
    # The same reasons, but for the offending values they quote (which scale with it).
    def without_values(reasons):
        return [reason.split(", got ")[0] for reason in reasons]
    assert without_values(reference.reasons) == without_values(scaled.reasons)
    assert scaled.valid.sum() == (12 if corrupt == "none" else 11)
    valid = scaled.valid
    if n_contacts >= 3:
        exact = exact_force_closure(positions[valid], normals[valid], mu[valid])
        passed = torque_filter(scaled_positions[valid], scaled_normals[valid], mu[valid])
        assert not np.any(exact & ~passed)
