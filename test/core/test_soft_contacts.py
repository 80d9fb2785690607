"""Soft-finger contacts: torsional friction in the exact test, filter and certificates."""

import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from grasp_cases import ellipsoid_grasps, random_rotation
from grasp_fc_ros.core import (
    Status,
    check_force_closure,
    exact_force_closure,
    minimum_friction,
    optimal_contact_forces,
    torque_filter,
    validate_grasps,
    verify_certificates,
)
from grasp_fc_ros.core.model.contact_model import HARD, SOFT, model_of
from grasp_fc_ros.core.model.grasp_input import prepare_grasps
from reference_pyramids import (
    soft_pyramid_is_force_closure,
    soft_pyramid_min_max_force,
    soft_pyramid_minimum_friction,
)


def antipodal_pairs(rng, n_grasps):
    """Two contacts on opposite sides of a sphere of random radius, normals inward."""
    direction = rng.normal(size=(n_grasps, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    radius = rng.uniform(0.1, 10.0, size=(n_grasps, 1, 1))
    positions = np.stack([direction, -direction], axis=1) * radius
    return positions, -positions / radius, radius[:, 0, 0]


def soft_grasps(rng, n_grasps, n_contacts, soft_share=0.5):
    """Ellipsoid grasps, gamma up to 0.3 of the object's size on a random share of the
    contacts (0 elsewhere)."""
    positions, normals = ellipsoid_grasps(rng, n_grasps, n_contacts,
                                          axes=rng.uniform(0.5, 3, 3))
    gamma = rng.uniform(0.0, 0.3, size=(n_grasps, n_contacts))
    gamma *= rng.random((n_grasps, n_contacts)) < soft_share
    return positions, normals, gamma


def test_two_soft_antipodal_fingers_are_force_closure_two_hard_never():
    rng = np.random.default_rng(0)
    positions, normals, radius = antipodal_pairs(rng, 50)
    hard = check_force_closure(positions, normals, 0.5)
    soft = check_force_closure(positions, normals, 0.5,
                               torsional_friction=0.05 * radius[:, None])
    assert not hard.force_closure.any()
    assert soft.force_closure.all()
    assert (soft.status == Status.FORCE_CLOSURE).all()
    # One soft finger is enough: its torsion (either sign) resists the torque about the
    # line through both contacts, the one wrench two hard contacts leave free.
    one = check_force_closure(positions, normals, 0.5,
                              torsional_friction=np.array([0.05, 0.0]) * radius[:, None])
    assert one.force_closure.all()
    # Beyond the friction cones (normals tilted by more than atan(mu)) no torsion helps.
    tilted = normals.copy()
    tilted[:, 0] = normals[:, 0] + 1.2 * np.cross(normals[:, 0], rng.normal(size=(50, 3)))
    wide = check_force_closure(positions, tilted, 0.1, torsional_friction=0.05 * radius[:, None])
    assert not wide.force_closure.all()


def test_zero_torsional_friction_is_the_hard_path():
    rng = np.random.default_rng(1)
    positions, normals = ellipsoid_grasps(rng, 200, 4)
    hard = check_force_closure(positions, normals, 0.4, certificates=True)
    zero = check_force_closure(positions, normals, 0.4, certificates=True,
                               torsional_friction=np.zeros((200, 4)))
    for name in ("status", "margin", "margin_upper", "contact_forces", "separating_wrench"):
        assert np.array_equal(getattr(hard, name), getattr(zero, name), equal_nan=True)
    assert zero.contact_torques is None
    assert prepare_grasps(positions, normals, 0.4, 0.0).torsional is None
    assert model_of(None) is HARD and SOFT.components == 4


def test_torsional_friction_only_adds_force_closure():
    """The soft cone contains the hard one and grows with gamma."""
    rng = np.random.default_rng(2)
    positions, normals, gamma = soft_grasps(rng, 300, 3, soft_share=1.0)
    hard = exact_force_closure(positions, normals, 0.3)
    soft = exact_force_closure(positions, normals, 0.3, torsional_friction=gamma)
    more = exact_force_closure(positions, normals, 0.3, torsional_friction=2 * gamma)
    assert not np.any(hard & ~soft) and not np.any(soft & ~more)
    assert (soft & ~hard).sum() > 0
    # gamma far beyond the grasp's size: the torsion columns stay scaled, so the grasp
    # map's rank test and the solver do not break down (a column of size gamma would).
    huge = check_force_closure(positions, normals, 0.3, torsional_friction=1e9 * gamma,
                               use_filter=False)
    assert not np.any(more & ~huge.force_closure)
    assert not (huge.status == Status.SOLVER_FAILURE).any()
    assert huge.force_closure.sum() > more.sum()


@pytest.mark.parametrize("bad, what", [
    (-0.1, "torsional friction must be >= 0 (0: a hard contact), got -0.1"),
    (np.nan, "torsional friction is not finite, got nan"),
    (np.inf, "torsional friction is not finite, got inf"),
])
def test_bad_torsional_friction_is_named(bad, what):
    rng = np.random.default_rng(3)
    positions, normals = ellipsoid_grasps(rng, 3, 4)
    gamma = np.zeros((3, 4))
    gamma[1, 2] = bad
    with pytest.raises(ValueError, match=re.escape(f"grasp 1, contact 2: {what}")):
        check_force_closure(positions, normals, 0.5, torsional_friction=gamma)
    validation = validate_grasps(positions, normals, 0.5, gamma)
    assert validation.valid.tolist() == [True, False, True]
    assert validation.reasons[1] == f"grasp 1, contact 2: {what}"
    with pytest.raises(ValueError, match="torsional_friction of shape"):
        exact_force_closure(positions, normals, 0.5, torsional_friction=np.ones(3))


def test_soft_certificates_are_verified_and_carry_torques():
    rng = np.random.default_rng(4)
    positions, normals, gamma = soft_grasps(rng, 150, 3, soft_share=0.7)
    result = check_force_closure(positions, normals, 0.3, torsional_friction=gamma,
                                 certificates=True)
    fc = result.force_closure
    assert fc.any() and (~fc).any()
    assert result.contact_torques.shape == (150, 3)
    forces_ok, wrench_ok = verify_certificates(
        positions, normals, 0.3, result.contact_forces, result.separating_wrench,
        torsional_friction=gamma, contact_torques=result.contact_torques)
    assert np.array_equal(forces_ok, fc)
    assert np.array_equal(wrench_ok, ~fc & ~result.marginal)
    assert (result.contact_torques[fc][gamma[fc] == 0] == 0).all()
    # The same forces without their torsional moments are not an equilibrium of a grasp
    # that needs torsion, and the wrenches do positive work on soft contacts' moments.
    uses_torsion = fc & (np.abs(result.contact_torques).max(axis=1, initial=0) > 1e-3)
    assert uses_torsion.any()
    hard_forces_ok, _ = verify_certificates(positions, normals, 0.3, result.contact_forces,
                                            torsional_friction=gamma)
    assert not hard_forces_ok[uses_torsion].any()
    _, hard_wrench_ok = verify_certificates(positions, normals, 0.3,
                                            separating_wrench=result.separating_wrench)
    assert hard_wrench_ok[wrench_ok].all()   # a soft separating wrench also separates hard


def test_soft_verdicts_are_bracketed_by_polyhedral_soft_cones():
    rng = np.random.default_rng(5)
    positions, normals, gamma = soft_grasps(rng, 60, 3, soft_share=0.7)
    mu = 0.4
    exact = exact_force_closure(positions, normals, mu, torsional_friction=gamma)
    inner = np.array([soft_pyramid_is_force_closure(p, n, mu, g, inscribed=True)
                      for p, n, g in zip(positions, normals, gamma, strict=True)])
    outer = np.array([soft_pyramid_is_force_closure(p, n, mu, g, inscribed=False)
                      for p, n, g in zip(positions, normals, gamma, strict=True)])
    assert not np.any(inner & ~exact), "inscribed soft cones FC but exact says not"
    assert not np.any(exact & ~outer), "exact FC but circumscribed soft cones not"
    assert inner.any() and (~outer).any()


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_contacts=st.integers(2, 5),
       log_scale=st.floats(-4, 4), shift=st.floats(-1e2, 1e2))
def test_soft_verdicts_invariant_under_rotation_translation_and_scale(
        seed, n_contacts, log_scale, shift):
    rng = np.random.default_rng(seed)
    positions, normals, gamma = soft_grasps(rng, 20, n_contacts, soft_share=0.8)
    rotation = random_rotation(rng)
    scale = 10.0 ** log_scale
    moved = (positions @ rotation.T) * scale + shift
    original = check_force_closure(positions, normals, 0.5, torsional_friction=gamma,
                                   use_filter=False)
    transformed = check_force_closure(moved, normals @ rotation.T, 0.5,
                                      torsional_friction=gamma * scale, use_filter=False)
    assert np.array_equal(original.force_closure, transformed.force_closure)
    assert np.allclose(original.margin, transformed.margin, atol=1e-6)
    for origins in ("seed", "all"):
        passed = torque_filter(moved, normals @ rotation.T, 0.5, origins=origins,
                               torsional_friction=gamma * scale)
        assert not np.any(transformed.force_closure & ~passed)


@pytest.mark.parametrize("n_contacts", [2, 3, 4])
def test_filter_is_sound_on_random_soft_grasps(n_contacts):
    """Bounded here (3 x 1,500 grasps); benchmarks/bench_filter.py --soft runs 100,000."""
    rng = np.random.default_rng(10 + n_contacts)
    positions, normals, gamma = soft_grasps(rng, 1500, n_contacts, soft_share=0.4)
    if n_contacts == 2:
        positions[::2, 1] = -positions[::2, 0]          # many antipodal pairs
        normals[::2, 1] = -normals[::2, 0]
    exact = exact_force_closure(positions, normals, 0.3, torsional_friction=gamma)
    for origins in ("seed", "all"):
        passed = torque_filter(positions, normals, 0.3, origins=origins,
                               torsional_friction=gamma)
        with_certificates, wrench = torque_filter(positions, normals, 0.3, origins=origins,
                                                  certificates=True,
                                                  torsional_friction=gamma)
        assert not np.any(exact & ~passed)
        assert not np.any(exact & ~with_certificates)
        _, wrench_ok = verify_certificates(positions, normals, 0.3,
                                           separating_wrench=wrench,
                                           torsional_friction=gamma)
        assert not np.any(wrench_ok & with_certificates)
        if n_contacts > 2:  # two contacts: the torque about their line does no work at
            # all, which rounding blurs beyond the relative check (as for hard contacts)
            assert np.array_equal(wrench_ok, ~with_certificates)
    assert exact.any() and (~passed).any()


def test_soft_contact_at_the_origin_contributes_its_line():
    """Two soft antipodal fingers plus a hard third: about either soft finger, the other
    contacts' fans alone do not span, the soft lines do; the filter must pass."""
    positions = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0]])
    normals = np.array([[-1.0, 0, 0], [1, 0, 0], [0, -1, 0]])
    gamma = [0.1, 0.1, 0.0]
    assert exact_force_closure(positions, normals, 0.5, torsional_friction=gamma)
    for origins in ("seed", "all"):
        assert torque_filter(positions, normals, 0.5, origins=origins,
                             torsional_friction=gamma)


def test_soft_antipodal_pair_holds_a_twist_with_the_analytic_force():
    """Torque T about the line of two soft fingers: each gives at most gamma f_n, so
    s* = T / (2 gamma); hard fingers cannot hold it at all."""
    positions = np.array([[1.0, 0, 0], [-1, 0, 0]])
    twist = np.array([0, 0, 0, 0.3, 0, 0])
    assert np.isinf(optimal_contact_forces(positions, -positions, 0.5, twist)[0])
    s_star, forces, torques = optimal_contact_forces(positions, -positions, 0.5, twist,
                                                     torsional_friction=0.1)
    assert s_star == pytest.approx(1.5, rel=1e-6)
    assert torques == pytest.approx([0.15, -0.15], rel=1e-6)
    net = forces.sum(axis=0), (np.cross(positions, forces)
                               + torques[:, None] * -positions).sum(axis=0)
    assert np.allclose(np.concatenate(net) + twist, 0, atol=1e-9)
    hard = optimal_contact_forces(positions, -positions, 0.5, twist, torsional_friction=0.0)
    assert np.isinf(hard[0]) and np.isnan(hard[2]).all()


def test_soft_optimal_forces_are_bracketed_by_polyhedral_soft_cones():
    rng = np.random.default_rng(7)
    positions, normals, gamma = soft_grasps(rng, 25, 3, soft_share=0.7)
    wrench = rng.normal(size=(25, 6))
    s_star, forces, torques = optimal_contact_forces(positions, normals, 0.5, wrench,
                                                     torsional_friction=gamma)
    inner = [soft_pyramid_min_max_force(p, n, 0.5, g, w, inscribed=True)
             for p, n, g, w in zip(positions, normals, gamma, wrench, strict=True)]
    outer = [soft_pyramid_min_max_force(p, n, 0.5, g, w, inscribed=False)
             for p, n, g, w in zip(positions, normals, gamma, wrench, strict=True)]
    finite = np.isfinite(s_star)
    assert finite.any() and (~finite).any()
    larger = optimal_contact_forces(positions, normals, 0.5, wrench,
                                    torsional_friction=gamma * 30)[0]
    assert not np.isnan(larger).any() and np.all(larger <= s_star * (1 + 1e-6) + 1e-9)
    assert np.all(np.asarray(outer) <= s_star * (1 + 1e-6) + 1e-9)
    assert np.all(s_star <= np.asarray(inner) * (1 + 1e-6) + 1e-9)
    # Finite answers are real equilibria inside the soft cones.
    f, tau, n = forces[finite], torques[finite], normals[finite]
    f_n = (f * n).sum(axis=-1)
    f_t = np.linalg.norm(f - f_n[..., None] * n, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        twist = np.where(gamma[finite] > 0, 0.5 * tau / gamma[finite], 0.0)
    assert np.all(np.hypot(f_t, twist) <= 0.5 * f_n * (1 + 1e-6) + 1e-9)
    assert np.all(tau[gamma[finite] == 0] == 0)
    torque = (np.cross(positions[finite], f) + tau[..., None] * n).sum(axis=1)
    assert np.allclose(f.sum(axis=1) + wrench[finite, :3], 0, atol=1e-8)
    assert np.allclose(torque + wrench[finite, 3:], 0, atol=1e-8)


def test_minimum_friction_of_soft_grasps():
    positions = np.array([[1.0, 0, 0], [-1, 0, 0]])
    assert minimum_friction(positions, -positions) == np.inf
    assert minimum_friction(positions, -positions, torsional_friction=0.1) == 0.0
    rng = np.random.default_rng(8)
    positions, normals, gamma = soft_grasps(rng, 60, 3, soft_share=0.7)
    soft = minimum_friction(positions, normals, torsional_friction=gamma)
    hard = minimum_friction(positions, normals)
    assert not np.isnan(soft).any()
    assert np.all(soft <= hard * (1 + 1e-6))
    assert (soft < hard * 0.99).sum() > 0
    finite = np.isfinite(soft) & (soft > 0)
    for factor, expected in ((1.01, True), (0.99, False)):
        verdict = check_force_closure(positions[finite], normals[finite],
                                      soft[finite, None] * factor,
                                      torsional_friction=gamma[finite]).force_closure
        assert (verdict == expected).all()
    # Larger gamma, here beyond the grasp's size (the torsion's cone row gets small), only
    # lowers mu*.
    larger = minimum_friction(positions, normals, torsional_friction=gamma * 30)
    assert not np.isnan(larger).any() and np.all(larger <= soft * (1 + 1e-6))
    # Uniform scaling with gamma scaled along leaves mu* unchanged.
    scaled = minimum_friction(positions * 7.0, normals, torsional_friction=gamma * 7.0)
    assert np.allclose(scaled, soft, rtol=1e-5)


def test_soft_minimum_friction_is_bracketed_by_polyhedral_soft_cones():
    rng = np.random.default_rng(9)
    positions, normals, gamma = soft_grasps(rng, 6, 3, soft_share=1.0)
    soft = minimum_friction(positions, normals, torsional_friction=gamma)
    for p, n, g, value in zip(positions, normals, gamma, soft, strict=True):
        outer_low, _ = soft_pyramid_minimum_friction(p, n, g, inscribed=False)
        _, inner_high = soft_pyramid_minimum_friction(p, n, g, inscribed=True)
        assert outer_low <= value * (1 + 1e-6) + 1e-9
        assert value <= inner_high * (1 + 1e-6) + 1e-9


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_contacts=st.integers(2, 6),
       mu=st.floats(0.05, 1.5), soft_count=st.integers(1, 6), tilt=st.floats(0.0, 1e-6))
def test_filter_stays_sound_where_soft_normals_share_a_plane(seed, n_contacts, mu,
                                                             soft_count, tilt):
    """Soft normals all (nearly, by ``tilt``) perpendicular to one direction: the only
    case where the soft lines leave the filter a separating direction to find."""
    rng = np.random.default_rng(seed)
    positions, normals, _ = soft_grasps(rng, 200, n_contacts)
    soft = np.arange(n_contacts) < min(soft_count, n_contacts)
    flat = normals[:, soft].copy()
    flat[..., 2] = tilt * rng.normal(size=flat.shape[:2])
    normals[:, soft] = flat / np.linalg.norm(flat, axis=2, keepdims=True)
    rotation = random_rotation(rng)
    positions, normals = positions @ rotation.T, normals @ rotation.T
    gamma = np.where(soft, rng.uniform(0.01, 0.5, (200, n_contacts)), 0.0)
    exact = exact_force_closure(positions, normals, mu, torsional_friction=gamma)
    for origins in ("seed", "all"):
        passed = torque_filter(positions, normals, mu, origins=origins,
                               torsional_friction=gamma)
        assert not np.any(exact & ~passed)


def test_filter_passes_grasps_whose_soft_normals_span_at_once(monkeypatch):
    """The shortcut changes no verdict: the same grasps through the torque sets."""
    from grasp_fc_ros.core.filter import torque_space_filter
    rng = np.random.default_rng(11)
    positions, normals, gamma = soft_grasps(rng, 600, 4, soft_share=0.6)
    spanned = torque_space_filter.soft_normals_span(prepare_grasps(positions, normals, 0.3,
                                                                   gamma))
    assert spanned.any() and (~spanned).any()
    quick = [torque_filter(positions, normals, 0.3, origins=o, torsional_friction=gamma,
                           certificates=True) for o in ("seed", "all")]
    with pytest.raises(ValueError, match="origins must be one of"):   # all spanned
        torque_filter(positions, normals, 0.3, origins="none", torsional_friction=1.0)
    monkeypatch.setattr(torque_space_filter, "soft_normals_span",
                        lambda grasps: np.zeros(len(grasps.mu), dtype=bool))
    for (passed, wrench), origins in zip(quick, ("seed", "all"), strict=True):
        slow, slow_wrench = torque_filter(positions, normals, 0.3, origins=origins,
                                          torsional_friction=gamma, certificates=True)
        assert np.array_equal(passed, slow) and passed[spanned].all()
        assert np.array_equal(wrench, slow_wrench, equal_nan=True)
