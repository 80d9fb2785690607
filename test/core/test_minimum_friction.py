"""The minimum friction coefficient: hand cases, the LP pyramid bracket, consistency with
check_force_closure on both sides, invariances and input errors."""

import importlib

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from grasp_cases import ellipsoid_grasps, random_rotation
from grasp_fc_ros.core import check_force_closure
from grasp_fc_ros.core.exact import certificates
from grasp_fc_ros.core.quality.minimum_friction import (
    ABS_TOL,
    CERT_MARGIN,
    MU_CAP,
    REL_TOL,
    lower_certificate,
    minimum_friction,
    minimum_friction_bounds,
    upper_certificate,
)
from grasp_fc_ros.core.tolerances import MARGIN_TOL, MAX_FRICTION_COEFFICIENT
from reference_pyramids import pyramid_minimum_friction

TETRAHEDRON = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float)


def equator_grasp(tilt):
    """Three fingers at 120 degrees on the unit equator, normals tilted down by ``tilt``.

    Every internal force has sum_i f_t,i . z = sin(tilt) sum_i f_n,i while
    f_t . z <= |f_t| cos(tilt), so mu >= tan(tilt); the horizontal squeeze towards the
    centre has ratio exactly tan(tilt): mu* = tan(tilt).
    """
    angle = 2 * np.pi * np.arange(3) / 3
    radial = np.stack([np.cos(angle), np.sin(angle), np.zeros(3)], axis=1)
    normals = -np.cos(tilt) * radial - np.sin(tilt) * np.array([0.0, 0.0, 1.0])
    return radial, normals


def test_tilted_equator_grasp_needs_exactly_tan_tilt():
    for tilt in np.radians([5.0, 20.0, 45.0, 70.0]):
        positions, normals = equator_grasp(tilt)
        result = minimum_friction_bounds(positions, normals)
        assert result.lower <= np.tan(tilt) * (1 + 1e-9) <= result.upper * (1 + 1e-9)
        assert result.value == pytest.approx(np.tan(tilt), rel=REL_TOL)


def test_inf_means_not_force_closure_at_any_accepted_friction():
    """mu* = inf exactly where check_force_closure says no even at the largest friction
    it accepts: MU_CAP is that bound."""
    assert MU_CAP == MAX_FRICTION_COEFFICIENT
    for needed, expected in ((5e3, np.inf), (500.0, 500.0)):
        positions, normals = equator_grasp(np.arctan(needed))
        result = minimum_friction_bounds(positions, normals)
        at_cap = check_force_closure(positions, normals, MAX_FRICTION_COEFFICIENT,
                                     use_filter=False)
        if expected == np.inf:
            assert result.value == np.inf and result.lower >= MU_CAP
            assert not at_cap.force_closure
        else:
            assert result.value == pytest.approx(expected, rel=REL_TOL)
            assert at_cap.force_closure


def test_fast_stage_search_matches_the_clarabel_search(monkeypatch):
    """The search on the fast interior-point stage gives the same mu* (margin MARGIN_TOL,
    where the boundary is sharp) as the search on Clarabel alone, and the fast stage
    does nearly all of the solves."""
    module = importlib.import_module("grasp_fc_ros.core.quality.minimum_friction")
    rng = np.random.default_rng(21)
    positions, normals = ellipsoid_grasps(rng, 60, 6)
    ratios = rng.uniform(0.5, 2.0, (60, 6))
    to_clarabel = []
    step = module._step
    monkeypatch.setattr(module, "_step", lambda chunk, *args: (to_clarabel.append(chunk.size),
                                                               step(chunk, *args)))
    fast = minimum_friction_bounds(positions, normals, ratios, margin=MARGIN_TOL)
    assert sum(to_clarabel) <= 0.05 * fast.solves.sum()
    monkeypatch.setattr(module, "_step_fast", lambda chunk, *args: chunk)
    slow = minimum_friction_bounds(positions, normals, ratios, margin=MARGIN_TOL)
    assert np.isfinite(fast.value).all() and np.isfinite(slow.value).all()
    np.testing.assert_allclose(fast.value, slow.value, rtol=2 * REL_TOL, atol=2 * ABS_TOL)


def test_two_antipodal_fingers_are_never_force_closure():
    positions = np.array([[1.0, 0, 0], [-1.0, 0, 0]])
    assert minimum_friction(positions, -positions) == np.inf


def test_collinear_contacts_are_never_force_closure():
    positions = np.outer(np.linspace(-1, 1, 5), [1.0, 2.0, 0.5])
    normals = np.random.default_rng(0).normal(size=(5, 3))
    assert minimum_friction(positions, normals) == np.inf


def test_contacts_all_pushing_one_way_are_never_force_closure():
    """Every equilibrium has total normal force 0: no friction helps (rank is 6)."""
    rng = np.random.default_rng(3)
    positions = np.column_stack([rng.uniform(-1, 1, (6, 2)), np.zeros(6)])
    normals = np.tile([0.0, 0.0, -1.0], (6, 1))
    result = minimum_friction_bounds(positions, normals)
    assert result.value == np.inf and result.lower >= MU_CAP


def test_contacts_a_rotation_lifts_off_are_never_force_closure():
    """Normals along the velocity of a rotation about z: that twist moves every contact
    straight off its surface, so no contact force, whatever the friction, resists it."""
    rng = np.random.default_rng(5)
    angle = np.sort(rng.uniform(0, 2 * np.pi, 6))
    positions = np.stack([np.cos(angle), np.sin(angle), rng.uniform(-1, 1, 6)], axis=1)
    normals = np.stack([-np.sin(angle), np.cos(angle), np.zeros(6)], axis=1)
    assert minimum_friction(positions, normals) == np.inf
    assert not check_force_closure(positions, normals, mu=100.0).force_closure


def test_tetrahedral_grasp_of_a_sphere_needs_no_friction():
    """The squeeze towards the centre is a pure normal internal force, and the grasp map
    has rank 6 with any friction: force closure for every mu > 0 (though frictionless
    normals alone span only forces)."""
    assert minimum_friction(TETRAHEDRON, -TETRAHEDRON) == 0.0
    assert check_force_closure(TETRAHEDRON, -TETRAHEDRON, mu=1e-3).force_closure


def test_frictionless_force_closure_needs_no_friction():
    """Two fingers on each face of a cube, off centre in a pinwheel: the normal wrenches
    alone positively span wrench space."""
    offsets = np.array([[0.5, 0.2], [-0.5, -0.2]])
    positions, normals = [], []
    for axis in range(3):
        for side in (1.0, -1.0):
            for u, v in offsets * side:
                point = np.zeros(3)
                point[axis] = side
                point[(axis + 1) % 3], point[(axis + 2) % 3] = u, v
                positions.append(point)
                normals.append(-side * np.eye(3)[axis])
    positions, normals = np.array(positions), np.array(normals)
    assert minimum_friction(positions, normals) == 0.0


def test_margin_tol_boundary_is_check_force_closures_boundary():
    """With margin=MARGIN_TOL the verdict flips exactly there, for every grasp."""
    rng = np.random.default_rng(11)
    for n_contacts in (3, 4, 6):
        positions, normals = ellipsoid_grasps(rng, 40, n_contacts)
        mu = minimum_friction(positions, normals, margin=MARGIN_TOL)
        assert np.isfinite(mu).all() and (mu > 0).all()
        above = check_force_closure(positions, normals, mu[:, None] * (1 + 1e-5))
        below = check_force_closure(positions, normals, mu[:, None] * (1 - 1e-5))
        assert (above.margin_upper > 0).all()
        assert not below.force_closure.any()


def test_boundary_agrees_with_the_exact_test_on_both_sides():
    """margin=0: below mu* never force closure; above it the exact test's optimum is
    positive (an internal force exists), though it may stay under MARGIN_TOL."""
    rng = np.random.default_rng(12)
    positions, normals = ellipsoid_grasps(rng, 60, 5)
    ratios = rng.uniform(0.5, 2.0, (60, 5))
    result = minimum_friction_bounds(positions, normals, ratios)
    assert np.isfinite(result.value).all()
    assert (result.upper - result.lower <= REL_TOL * result.upper).all()
    below = check_force_closure(positions, normals, result.value[:, None] * (1 - 1e-5) * ratios,
                                use_filter=False)
    above = check_force_closure(positions, normals, result.value[:, None] * (1 + 1e-5) * ratios,
                                use_filter=False)
    assert not below.force_closure.any()
    assert (below.margin < 1e-8).all()
    assert (above.margin > 0).all()
    # Where the margin grows fast enough, the verdict itself flips.
    loose = check_force_closure(positions, normals, result.value[:, None] * 1.1 * ratios)
    assert loose.force_closure.all()


def test_lp_pyramids_bracket_the_minimum_friction():
    """Inscribed pyramids need at least mu*, circumscribed ones at most."""
    rng = np.random.default_rng(13)
    cases = [ellipsoid_grasps(rng, 3, n) for n in (3, 4, 6)]
    positions = [p for batch in cases for p in batch[0]]
    normals = [n for batch in cases for n in batch[1]]
    ratios = [rng.uniform(0.5, 2.0, len(p)) for p in positions]
    for p, n, r in zip(positions, normals, ratios, strict=True):
        mu = minimum_friction(p, n, r)
        _, circumscribed = pyramid_minimum_friction(p, n, r, inscribed=False)
        _, inscribed = pyramid_minimum_friction(p, n, r, inscribed=True)
        assert circumscribed <= mu * (1 + 2 * REL_TOL) + ABS_TOL
        assert mu <= inscribed * (1 + 2 * REL_TOL) + ABS_TOL


def test_pyramids_agree_where_no_friction_helps():
    positions = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0.0, 1.0, 0.0]])
    normals = np.tile([0.0, 0.0, 1.0], (3, 1))
    assert minimum_friction(positions, normals) == np.inf
    assert pyramid_minimum_friction(positions, normals, inscribed=False)[1] == np.inf


def test_batch_answers_match_lone_answers():
    rng = np.random.default_rng(14)
    positions, normals = ellipsoid_grasps(rng, 12, 6)
    batch = minimum_friction(positions, normals)
    lone = np.array([minimum_friction(p, n) for p, n in zip(positions, normals, strict=True)])
    assert batch.shape == (12,) and lone[0].shape == ()
    np.testing.assert_allclose(batch, lone, rtol=2 * REL_TOL)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_contacts=st.integers(3, 7),
       scale=st.floats(1e-3, 1e3), ratio_scale=st.floats(0.1, 10.0))
# A search step where the fast stage resolved no grasp of its chunk (it crashed once).
@example(seed=666315, n_contacts=4, scale=1.0, ratio_scale=1.0)
# A grasp with mu* ~ 0 whose margin stays below CERT_MARGIN up to mu ~ 1e-8: answers
# 5.0e-13 and 7.2e-9 (scale 65), both within the contract.
@example(seed=15947, n_contacts=7, scale=65.0, ratio_scale=0.75)
def test_invariant_under_rigid_motion_and_scaling(seed, n_contacts, scale, ratio_scale):
    """mu* is unchanged by rotation, translation and uniform scaling of the grasp, and
    multiplying every ratio by c divides it by c: to the tolerance, or else both answers
    lie where the contract allows (L proves a margin of at most CERT_MARGIN, U force
    closure), checked by the exact test in the first frame."""
    rng = np.random.default_rng(seed)
    positions, normals = ellipsoid_grasps(rng, 3, n_contacts, axes=rng.uniform(0.5, 3, 3))
    ratios = rng.uniform(0.5, 2.0, (3, n_contacts))
    rotation = random_rotation(rng)
    moved = scale * positions @ rotation.T + rng.uniform(-10, 10, 3)
    base = minimum_friction_bounds(positions, normals, ratios)
    other = minimum_friction_bounds(moved, normals @ rotation.T, ratios)
    rescaled = minimum_friction_bounds(positions, normals, ratios * ratio_scale)
    finite = np.isfinite(base.value)
    for result, factor in ((other, 1.0), (rescaled, ratio_scale)):
        assert (np.isfinite(result.value) == finite).all()
        lower, upper = result.lower * factor, result.upper * factor
        apart = finite & ~np.isclose(result.value * factor, base.value,
                                     rtol=3 * REL_TOL, atol=3 * ABS_TOL)
        if not apart.any():
            continue
        # Both intervals mean the same grasp: at the larger L the exact test finds no
        # margin above CERT_MARGIN (plus its accuracy); just above the smaller U it
        # cannot bound the margin to 0 or below (U proves t* > 0; the exact test's own
        # verdict needs t* >= MARGIN_TOL, which holds only further up).
        highest_lower = np.maximum(lower, base.lower)[apart]
        lowest_upper = np.minimum(upper, base.upper)[apart]
        at = check_force_closure(positions[apart], normals[apart],
                                 highest_lower[:, None] * ratios[apart], use_filter=False)
        assert (at.margin <= CERT_MARGIN + 5e-8).all()
        above = check_force_closure(positions[apart], normals[apart],
                                    lowest_upper[:, None] * (1 + 1e-6) * ratios[apart],
                                    use_filter=False)
        assert (above.margin_upper > 0).all()


def test_bounds_mean_what_they_certify():
    """At the lower bound the exact test finds no internal force deeper than
    CERT_MARGIN (plus its own accuracy); just above the upper bound it finds one."""
    rng = np.random.default_rng(15)
    positions, normals = ellipsoid_grasps(rng, 30, 6)
    result = minimum_friction_bounds(positions, normals)
    assert (result.solves >= 1).all() and (result.value == result.upper).all()
    at_lower = check_force_closure(positions, normals, result.lower[:, None], use_filter=False)
    assert (at_lower.margin <= CERT_MARGIN + 1e-8).all()
    above = check_force_closure(positions, normals, result.upper[:, None] * (1 + 1e-6),
                                use_filter=False)
    assert (above.margin > 0).all()


def test_a_wrench_doing_no_work_certifies_nothing():
    """w = 0 (or any w with G^T w = 0) bounds no margin: the lower bound stays 0."""
    positions, normals = ellipsoid_grasps(np.random.default_rng(1), 2, 5)
    unit, _, _ = certificates.normalise_positions(positions)
    gmap = certificates.grasp_maps(unit)
    lower = lower_certificate(np.zeros((2, 6)), gmap, normals, np.ones((2, 5)),
                              np.full(2, MU_CAP))
    assert (lower == 0).all()


COVERAGE = {"lower": 0, "upper": 0}


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_contacts=st.integers(3, 7))
def test_certificates_from_arbitrary_wrenches_and_forces_are_sound(seed, n_contacts):
    """The certificate checks do not trust the solver: for any wrench, the exact test
    finds no margin above CERT_MARGIN at the friction it certifies; for any forces, a
    positive margin just above the friction they certify."""
    rng = np.random.default_rng(seed)
    positions, _ = ellipsoid_grasps(rng, 8, n_contacts)
    ratios = rng.uniform(0.5, 2.0, (8, n_contacts))
    unit, _, _ = certificates.normalise_positions(positions)
    gmap = certificates.grasp_maps(unit)
    # A random wrench, and normals within 80 degrees of minus its work at each contact:
    # it separates up to some friction L > 0 (cot of the largest angle / ratio).
    wrench = rng.normal(size=(8, 6))
    work = np.einsum("gkv,gk->gv", gmap, wrench).reshape(8, n_contacts, 3)
    away = -work / np.linalg.norm(work, axis=2, keepdims=True)
    side = np.cross(away, rng.normal(size=away.shape))
    side /= np.linalg.norm(side, axis=2, keepdims=True)
    angle = rng.uniform(0, np.radians(80), (8, n_contacts, 1))
    normals = np.cos(angle) * away + np.sin(angle) * side
    lower = lower_certificate(wrench, gmap, normals, ratios, np.full(8, 50.0))
    expected = (1 / np.tan(angle[..., 0]) / ratios).min(axis=1)
    # L proves a margin of at most CERT_MARGIN, not exactly 0, so it may pass the exact
    # boundary by ~CERT_MARGIN / slope (documented in minimum_friction_bounds): seen
    # 1.6e-6 relative (seed 131859, 6 contacts); it is never below it.
    assert np.all(lower >= np.minimum(expected, 50.0) * (1 - 1e-9))
    np.testing.assert_allclose(lower, np.minimum(expected, 50.0), rtol=1e-5)
    COVERAGE["lower"] += int((lower > 0).sum())
    # The exact test (batch accuracy ~1e-8) finds no margin there.
    at = check_force_closure(positions, normals, lower[:, None] * ratios, use_filter=False)
    assert not at.force_closure.any()
    assert (at.margin <= CERT_MARGIN + 5e-8).all()
    # Forces near the squeeze towards the centroid, on ordinary ellipsoid grasps.
    positions, normals = ellipsoid_grasps(rng, 8, n_contacts)
    unit, _, _ = certificates.normalise_positions(positions)
    forces = -unit.reshape(8, -1) + 0.3 * rng.normal(size=(8, 3 * n_contacts))
    upper = upper_certificate(forces, certificates.grasp_maps(unit), normals, ratios)
    # Frictions the core accepts (random forces can certify only huge ones).
    finite = np.isfinite(upper) & (upper * ratios.max(axis=1) * (1 + 1e-6)
                                   <= MAX_FRICTION_COEFFICIENT)
    COVERAGE["upper"] += int(finite.sum())
    if finite.any():
        above = check_force_closure(positions[finite], normals[finite],
                                    upper[finite, None] * (1 + 1e-6) * ratios[finite],
                                    use_filter=False)
        assert (above.margin > 0).all()


def test_bad_input_names_the_grasp_and_contact():
    positions, normals = ellipsoid_grasps(np.random.default_rng(0), 2, 4)
    ratios = np.ones((2, 4))
    ratios[1, 2] = -1.0
    with pytest.raises(ValueError, match=r"grasp 1, contact 2: friction ratio must be > 0"):
        minimum_friction(positions, normals, ratios)
    bad = normals.copy()
    bad[0, 3] = 0.0
    with pytest.raises(ValueError, match=r"grasp 0, contact 3: normal has zero length"):
        minimum_friction(positions, bad)
    with pytest.raises(ValueError, match="margin"):
        minimum_friction(positions, normals, margin=-1e-3)


def test_the_certificate_property_test_certified_something():
    """Runs after the property test (file order): it must have checked some of each."""
    assert COVERAGE["lower"] > 0 and COVERAGE["upper"] > 0
