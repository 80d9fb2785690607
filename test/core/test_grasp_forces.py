"""Optimal contact forces for a load: hand cases, the returned forces, normal-force
limits, the LP pyramid bracket, invariances, batches and input errors."""

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from grasp_cases import adversarial_grasps, ellipsoid_grasps, random_rotation
from grasp_fc_ros.core import check_force_closure, warm_up
from grasp_fc_ros.core.exact import certificates
from grasp_fc_ros.core.forces import force_interior_point, grasp_forces
from grasp_fc_ros.core.forces.grasp_forces import (
    FORCE_TOL,
    OPTIMALITY_TOL,
    GraspForces,
    lower_bound,
    optimal_contact_forces,
)
from grasp_fc_ros.objects import make_object, sample_grasps
from reference_pyramids import pyramid_min_max_force

GRAVITY = np.array([0.0, 0.0, -9.81, 0.0, 0.0, 0.0])


def equator_grasp():
    angle = 2 * np.pi * np.arange(3) / 3
    positions = np.stack([np.cos(angle), np.sin(angle), np.zeros(3)], axis=1)
    return positions, -positions


def assert_holds(positions, normals, mu, wrench, s_star, forces, limits=np.inf):
    """The forces balance the wrench, lie in their cones and limits, and reach s*."""
    scale = max(np.abs(wrench).max(), s_star)
    np.testing.assert_allclose(forces.sum(axis=0), -wrench[:3], atol=1e-9 * scale)
    torque = np.cross(positions, forces).sum(axis=0)
    np.testing.assert_allclose(torque, -wrench[3:],
                               atol=1e-9 * scale * max(1.0, np.abs(positions).max()))
    normal = (forces * normals).sum(axis=1)
    tangential = np.linalg.norm(forces - normal[:, None] * normals, axis=1)
    assert (tangential <= mu * normal + FORCE_TOL * s_star).all()
    assert (normal <= limits + FORCE_TOL * s_star).all()
    assert normal.max() == pytest.approx(s_star, rel=1e-12)


def test_gravity_on_a_three_finger_equator_grasp():
    """Horizontal normals: only friction lifts. sum_i mu f_n,i >= m g, so the least
    largest normal force is m g / (3 mu), reached by equal shares."""
    positions, normals = equator_grasp()
    s_star, forces, _ = optimal_contact_forces(positions, normals, 0.5, GRAVITY)
    assert s_star == pytest.approx(9.81 / 1.5, rel=1e-7)
    assert_holds(positions, normals, 0.5, GRAVITY, s_star, forces)
    np.testing.assert_allclose(forces[:, 2], 9.81 / 3, rtol=1e-6)


def test_gravity_at_an_offset_centre_of_mass_is_a_torque_about_the_origin():
    """The load is m g at the centre of mass c: torque c x F about the origin. The same
    grasp and load moved so that c is the origin give the same s*."""
    positions, normals = equator_grasp()
    centre = np.array([0.1, -0.2, 0.05])
    load = np.concatenate([GRAVITY[:3], np.cross(centre, GRAVITY[:3])])
    s_star, forces, _ = optimal_contact_forces(positions, normals, 0.8, load)
    assert_holds(positions, normals, 0.8, load, s_star, forces)
    moved, _, _ = optimal_contact_forces(positions - centre, normals, 0.8, GRAVITY)
    assert s_star == pytest.approx(moved, rel=1e-7)
    centred, _, _ = optimal_contact_forces(positions, normals, 0.8, GRAVITY)
    assert s_star > centred                     # an off-centre load costs more force


def test_normal_force_limits():
    positions, normals = equator_grasp()
    needed = 9.81 / 1.5
    s_star, forces, _ = optimal_contact_forces(positions, normals, 0.5, GRAVITY,
                                            max_normal_force=needed * 0.99)
    assert s_star == np.inf and np.isnan(forces).all()
    s_star, forces, _ = optimal_contact_forces(positions, normals, 0.5, GRAVITY,
                                            max_normal_force=needed * 1.01)
    assert s_star == pytest.approx(needed, rel=1e-7)
    # One contact may not push at all: two fingers cannot lift by friction alone here.
    s_star, _, _ = optimal_contact_forces(positions, normals, 0.5, GRAVITY,
                                       max_normal_force=[np.inf, np.inf, 0.0])
    assert s_star == np.inf


def test_limits_raise_s_star_where_the_best_forces_break_them():
    """A low limit on one contact moves load to the others: s* grows, and the returned
    forces respect every limit."""
    rng = np.random.default_rng(7)
    positions, normals = ellipsoid_grasps(rng, 1, 6)
    wrench = rng.normal(size=6)
    free, forces, _ = optimal_contact_forces(positions[0], normals[0], 0.7, wrench)
    busiest = np.argmax((forces * normals[0]).sum(axis=1))
    limits = np.full(6, np.inf)
    limits[busiest] = 0.5 * free
    limited, limited_forces, _ = optimal_contact_forces(positions[0], normals[0], 0.7, wrench,
                                                     max_normal_force=limits)
    assert np.isfinite(free) and limited >= free * (1 - 1e-9)
    if np.isfinite(limited):
        assert_holds(positions[0], normals[0], 0.7, wrench, limited, limited_forces, limits)


def test_zero_wrench_needs_no_force():
    positions, normals = equator_grasp()
    s_star, forces, _ = optimal_contact_forces(positions, normals, 0.5, np.zeros(6))
    assert s_star == 0.0 and (forces == 0).all()


def test_two_antipodal_fingers_cannot_resist_a_torque_about_their_axis():
    positions = np.array([[1.0, 0, 0], [-1.0, 0, 0]])
    twist = np.array([0, 0, 0, 1.0, 0, 0])
    s_star, forces, _ = optimal_contact_forces(positions, -positions, 2.0, twist)
    assert s_star == np.inf and np.isnan(forces).all()
    squeeze_load = np.array([0, 0, -1.0, 0, 0, 0])
    s_star, forces, _ = optimal_contact_forces(positions, -positions, 2.0, squeeze_load)
    assert s_star == pytest.approx(0.25, rel=1e-7)         # each lifts 1/2 = mu f_n


def test_force_closure_grasps_hold_every_wrench_and_others_not_all():
    rng = np.random.default_rng(8)
    positions, normals = ellipsoid_grasps(rng, 40, 5)
    fc = check_force_closure(positions, normals, 0.6).force_closure
    assert fc.any() and not fc.all()
    wrenches = rng.normal(size=(8, 6))
    finite = np.stack([np.isfinite(optimal_contact_forces(positions, normals, 0.6, w)[0])
                       for w in wrenches])
    assert finite[:, fc].all()
    assert not finite[:, ~fc].all(axis=0).any()    # some wrench defeats each of the others


def test_returned_forces_hold_the_wrench():
    rng = np.random.default_rng(9)
    positions, normals = ellipsoid_grasps(rng, 50, 6)
    wrenches = rng.normal(size=(50, 6))
    mu = rng.uniform(0.3, 1.0, (50, 6))
    s_star, forces, _ = optimal_contact_forces(positions, normals, mu, wrenches)
    held = np.flatnonzero(np.isfinite(s_star))
    assert held.size > 10 and not np.isnan(s_star).any()
    for g in held:
        assert_holds(positions[g], normals[g], mu[g], wrenches[g], s_star[g], forces[g])


def test_lp_pyramids_bracket_s_star():
    """Circumscribed pyramids need at most s*, inscribed ones at least; with limits too."""
    rng = np.random.default_rng(10)
    positions, normals = ellipsoid_grasps(rng, 12, 5)
    wrenches = rng.normal(size=(12, 6))
    limits = rng.uniform(0.5, 3.0, (12, 5))
    for limit in (None, limits):
        s_star, _, _ = optimal_contact_forces(positions, normals, 0.6, wrenches, limit)
        for g in range(12):
            lim = None if limit is None else limit[g]
            outer = pyramid_min_max_force(positions[g], normals[g], 0.6, wrenches[g],
                                          inscribed=False, max_normal_force=lim)
            inner = pyramid_min_max_force(positions[g], normals[g], 0.6, wrenches[g],
                                          inscribed=True, max_normal_force=lim)
            assert outer <= s_star[g] * (1 + 1e-6) + 1e-9
            assert s_star[g] <= inner * (1 + 1e-6) + 1e-9


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_contacts=st.integers(3, 7),
       scale=st.floats(1e-2, 1e2), load=st.floats(1e-3, 1e3))
# Found by hypothesis: the moved grasp's s* 2.4e-6 above the first frame's, both within
# their certified accuracy (the test demanded 1e-6).
@example(seed=6445, n_contacts=3, scale=1.0, load=1.0)
# Found by hypothesis: s* 8,700x the wrench (a nearly marginal grasp), another frame's
# 2.4e-5 above the first frame's; the bound below grows with s* / |wrench|.
@example(seed=5779, n_contacts=5, scale=1.0, load=1.0)
def test_invariant_under_rigid_motion_and_scaling(seed, n_contacts, scale, load):
    """Moving the grasp and the wrench along leaves s*; scaling lengths by k with the
    torque scaled by k leaves s*; scaling the wrench by c scales s* by c."""
    rng = np.random.default_rng(seed)
    positions, normals = ellipsoid_grasps(rng, 4, n_contacts, axes=rng.uniform(0.5, 3, 3))
    wrench = rng.normal(size=(4, 6))
    mu = rng.uniform(0.3, 1.2, (4, n_contacts))
    base, _, _ = optimal_contact_forces(positions, normals, mu, wrench)

    rotation, shift = random_rotation(rng), rng.uniform(-5, 5, 3)
    force = wrench[:, :3] @ rotation.T
    moved_wrench = np.concatenate([force, wrench[:, 3:] @ rotation.T + np.cross(shift, force)],
                                  axis=1)
    moved, _, _ = optimal_contact_forces(positions @ rotation.T + shift, normals @ rotation.T,
                                      mu, moved_wrench)
    scaled_wrench = np.concatenate([wrench[:, :3], scale * wrench[:, 3:]], axis=1)
    scaled, _, _ = optimal_contact_forces(scale * positions, normals, mu, scaled_wrench)
    heavier, _, _ = optimal_contact_forces(positions, normals, mu, load * wrench)

    finite = np.isfinite(base)
    # Each answer is within OPTIMALITY_TOL of its own frame's dual bound, by forces inside
    # the cones to FORCE_TOL * s*. That slack acts like a friction coefficient larger by
    # ~FORCE_TOL, which lowers s* by a relative ~FORCE_TOL * s* / |wrench|: negligible for
    # most grasps, not for a nearly marginal one that needs forces thousands of times the
    # wrench. Two frames agree to the sum, and to no less than two stages agree to
    # (assert_same_s_star).
    conditioning = base[finite] / np.linalg.norm(wrench[finite], axis=1)
    rtol = 3 * OPTIMALITY_TOL + FORCE_TOL * conditioning
    for other in (moved, scaled, heavier / load):
        assert (np.isfinite(other) == finite).all()
        assert (np.abs(other[finite] - base[finite]) <= rtol * base[finite]).all(), (
            other[finite], base[finite], rtol)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_contacts=st.integers(3, 6))
def test_dual_lower_bound_is_sound_for_any_wrench(seed, n_contacts):
    """The bound that certifies s* (and every inf) from below holds for arbitrary dual
    wrenches, not only the solver's: never above the s* of checked forces."""
    rng = np.random.default_rng(seed)
    positions, normals = ellipsoid_grasps(rng, 6, n_contacts)
    wrench = rng.normal(size=(6, 6))
    mu = rng.uniform(0.3, 1.2, (6, n_contacts))
    limits = np.where(rng.random((6, n_contacts)) < 0.3, rng.uniform(0.5, 5.0, (6, n_contacts)),
                      np.inf)
    s_star, _, _ = optimal_contact_forces(positions, normals, mu, wrench, limits)
    unit, centroid, size = certificates.normalise_positions(positions)
    torque = wrench[:, 3:] - np.cross(centroid, wrench[:, :3])
    scaled = np.concatenate([wrench[:, :3], torque / size[:, None]], axis=1)
    magnitude = np.linalg.norm(scaled, axis=1)
    gmap = certificates.grasp_maps(unit)
    for _ in range(5):
        dual = rng.normal(size=(6, 6))
        bound = lower_bound(dual, gmap, normals, mu, scaled / magnitude[:, None],
                            limits / magnitude[:, None]) * magnitude
        held = np.isfinite(s_star)
        assert (bound[held] <= s_star[held] * (1 + 1e-9)).all()


def solve_both_ways(monkeypatch, positions, normals, mu, wrench, limits=None):
    """s* through the fast stage (and Clarabel for what it leaves), the number of grasps
    it left, and s* on the Clarabel stage alone."""
    left = []
    stage = grasp_forces._clarabel_stage
    with monkeypatch.context() as patch:
        patch.setattr(grasp_forces, "_clarabel_stage",
                      lambda gmap, *args: (left.append(gmap.shape[0]), stage(gmap, *args))[1])
        fast, _, _ = optimal_contact_forces(positions, normals, mu, wrench, limits)
    with monkeypatch.context() as patch:
        patch.setattr(grasp_forces, "_fast_stage", lambda unit, *args: (
            np.zeros(unit.shape[0]), np.zeros(unit.shape[:2] + (3,)),
            np.zeros(unit.shape[0], dtype=bool)))
        slow, _, _ = optimal_contact_forces(positions, normals, mu, wrench, limits)
    return fast, sum(left), slow


def assert_same_s_star(fast, slow):
    """Same inf (and no NaN) on both stages, finite values within both stages' accuracy."""
    assert not np.isnan(fast).any() and not np.isnan(slow).any()
    np.testing.assert_array_equal(np.isinf(fast), np.isinf(slow))
    finite = np.isfinite(slow)
    np.testing.assert_allclose(fast[finite], slow[finite], rtol=3 * OPTIMALITY_TOL)


@pytest.mark.parametrize("n_contacts", [3, 4, 6])
@pytest.mark.parametrize("limited", [False, True])
def test_fast_stage_agrees_with_clarabel_and_decides_nearly_every_box_grasp(
        monkeypatch, n_contacts, limited):
    """The compiled stage gives Clarabel's s* (and inf on the same grasps), with and
    without limits, and leaves at most a few percent of the grasps to Clarabel."""
    rng = np.random.default_rng(30 + n_contacts)
    positions, normals = sample_grasps(make_object("box"), 150, n_contacts, rng)
    wrench = rng.normal(size=(150, 6))
    mu = rng.uniform(0.3, 1.0, (150, n_contacts))
    limits = None
    if limited:   # around the unlimited need: some grasps are held still, some no more
        need, _, _ = optimal_contact_forces(positions, normals, mu, wrench)
        limits = rng.uniform(0.5, 3.0, (150, n_contacts)) * np.minimum(need, 1e3)[:, None]
        limits[rng.random((150, n_contacts)) < 0.3] = np.inf
    fast, left, slow = solve_both_ways(monkeypatch, positions, normals, mu, wrench, limits)
    assert_same_s_star(fast, slow)
    assert np.isfinite(slow).sum() >= 20 and np.isinf(slow).sum() >= 20
    assert left <= 0.02 * 150


def test_fast_stage_agrees_with_clarabel_on_adversarial_grasps(monkeypatch):
    """Antipodal pairs, duplicate contacts, collinear and coplanar contacts, a contact
    limited to 0, loads no forces can hold: the same s* as Clarabel (what the kernel
    cannot certify goes there)."""
    rng = np.random.default_rng(40)
    cases = adversarial_grasps(rng, n_contacts=6, mu=0.5)
    positions = np.array([p for p, _ in cases])
    normals = np.array([n for _, n in cases])
    wrenches = np.concatenate([rng.normal(size=(4, 6)),
                               [[0, 0, -1.0, 0, 0, 0], [0, 0, 0, 1.0, 0, 0]]])
    for wrench in wrenches:
        for limits in (None, np.where(np.arange(6) == 2, 0.0, 5.0)):
            fast, _, slow = solve_both_ways(monkeypatch, positions, normals, 0.5, wrench,
                                            limits)
            assert_same_s_star(fast, slow)
    # Two antipodal fingers: rank 5, left to Clarabel; three doubled contacts decided.
    pair = np.array([[1.0, 0, 0], [-1.0, 0, 0]])
    for load, expected in (([0, 0, 0, 1.0, 0, 0], np.inf), ([0, 0, -1.0, 0, 0, 0], 0.25)):
        fast, _, slow = solve_both_ways(monkeypatch, pair, -pair, 2.0, np.array(load))
        assert fast == slow == pytest.approx(expected, rel=1e-6)
    angle = 2 * np.pi * np.arange(3) / 3
    ring = np.stack([np.cos(angle), np.sin(angle), np.zeros(3)], axis=1)
    doubled = np.concatenate([ring, ring + 1e-9])
    fast, left, slow = solve_both_ways(monkeypatch, doubled, -doubled, 0.5, GRAVITY)
    assert fast == pytest.approx(9.81 / 3, rel=1e-6) and slow == pytest.approx(fast, rel=1e-6)
    # A contact limited to 0 is dropped by the kernel (force 0), not left to Clarabel.
    angle = 2 * np.pi * np.arange(5) / 5
    five = np.stack([np.cos(angle), np.sin(angle), 0.3 * np.cos(2 * angle)], axis=1)
    fast, left, slow = solve_both_ways(monkeypatch, five, -five, 0.8, GRAVITY,
                                       [np.inf, 3.0, 0.0, np.inf, 20.0])
    assert left == 0 and np.isfinite(slow) and fast == pytest.approx(slow, rel=3e-6)


def test_infeasible_loads_are_proved_by_the_fast_stage(monkeypatch):
    """Pulling a grasp's contacts off the object: s* = inf from the kernel's wrench alone."""
    rng = np.random.default_rng(41)
    positions, normals = ellipsoid_grasps(rng, 40, 4)
    normals[:, :, 2] = -np.abs(normals[:, :, 2]) - 0.5         # every contact pushes down
    normals /= np.linalg.norm(normals, axis=2, keepdims=True)
    fast, left, slow = solve_both_ways(monkeypatch, positions, normals, 0.3,
                                       np.array([0, 0, -1.0, 0, 0, 0]))
    assert np.isinf(fast).all() and np.isinf(slow).all() and left == 0


def test_wrong_fast_answers_are_caught_by_the_checks(monkeypatch):
    """Forces off the optimum, or an infeasibility claim with a wrench that proves
    nothing, fail the numpy checks: those grasps get Clarabel's answer instead."""
    rng = np.random.default_rng(42)
    positions, normals = ellipsoid_grasps(rng, 60, 5)
    wrench = rng.normal(size=(60, 6))
    _, _, slow = solve_both_ways(monkeypatch, positions, normals, 0.7, wrench)
    kernel = grasp_forces.solve_fast_forces

    def sloppy(*args):
        codes, beta, iterations, forces, dual = kernel(*args)
        return codes, beta, iterations, 1.001 * forces, dual

    def boastful(*args):
        codes, beta, iterations, forces, dual = kernel(*args)
        return np.full_like(codes, 1), beta, iterations, forces, rng.normal(size=dual.shape)

    for wrong in (sloppy, boastful):
        monkeypatch.setattr(grasp_forces, "solve_fast_forces", wrong)
        fast, left, _ = solve_both_ways(monkeypatch, positions, normals, 0.7, wrench)
        assert_same_s_star(fast, slow)
        assert left >= np.isfinite(slow).sum()


def test_warm_up_compiles_the_fast_stage_for_the_calls_it_serves():
    """After the core's warm-up, s* calls (one grasp, a batch, with limits) run the
    already compiled kernel: no new specialisation, so no compile at the first query."""
    warm_up()
    compiled = set(force_interior_point._solve_all.signatures)
    assert compiled
    positions, normals = equator_grasp()
    optimal_contact_forces(positions, normals, 0.5, GRAVITY)
    optimal_contact_forces(np.stack([positions] * 3), np.stack([normals] * 3), 0.5, GRAVITY,
                           max_normal_force=10.0)
    assert set(force_interior_point._solve_all.signatures) == compiled


def test_batch_shapes():
    rng = np.random.default_rng(11)
    positions, normals = ellipsoid_grasps(rng, 5, 4)
    one_wrench = rng.normal(size=6)
    s_batch, f_batch, _ = optimal_contact_forces(positions, normals, 0.9, one_wrench)
    assert s_batch.shape == (5,) and f_batch.shape == (5, 4, 3)
    s_one, f_one, _ = optimal_contact_forces(positions[2], normals[2], 0.9, one_wrench)
    assert s_one.shape == () and f_one.shape == (4, 3)
    np.testing.assert_allclose(s_one, s_batch[2], rtol=1e-7)
    many = rng.normal(size=(7, 6))
    s_many, f_many, _ = optimal_contact_forces(positions[0], normals[0], 0.9, many)
    assert s_many.shape == (7,) and f_many.shape == (7, 4, 3)
    lone = [optimal_contact_forces(positions[0], normals[0], 0.9, w)[0] for w in many]
    np.testing.assert_allclose(s_many, lone, rtol=1e-7)


def test_bad_input_is_named():
    positions, normals = equator_grasp()
    with pytest.raises(ValueError, match=r"wrench must have shape"):
        optimal_contact_forces(positions, normals, 0.5, np.zeros(5))
    with pytest.raises(ValueError, match=r"wrench 1 is not finite"):
        optimal_contact_forces(np.stack([positions] * 2), np.stack([normals] * 2), 0.5,
                               np.array([np.zeros(6), [0, 0, np.nan, 0, 0, 0]]))
    with pytest.raises(ValueError, match=r"grasp 0, contact 1: max_normal_force must be >= 0"):
        optimal_contact_forces(positions, normals, 0.5, GRAVITY, max_normal_force=[1, -1, 1])
    with pytest.raises(ValueError, match=r"grasp 0, contact 2: friction coefficient"):
        optimal_contact_forces(positions, normals, [0.5, 0.5, 0.0], GRAVITY)
    with pytest.raises(ValueError, match=r"does not match"):
        optimal_contact_forces(np.stack([positions] * 2), np.stack([normals] * 2), 0.5,
                               np.zeros((3, 6)))


def test_one_return_shape_for_hard_and_soft_contacts():
    positions, normals = (a[0] for a in sample_grasps(make_object("box"), 1, 4,
                                                      np.random.default_rng(5)))
    hard = optimal_contact_forces(positions, normals, 0.5, GRAVITY)
    given_zero = optimal_contact_forces(positions, normals, 0.5, GRAVITY, torsional_friction=0.0)
    soft = optimal_contact_forces(positions, normals, 0.5, GRAVITY, torsional_friction=0.01)
    for solution in (hard, given_zero, soft):
        assert isinstance(solution, GraspForces) and len(solution) == 3
        assert solution.forces.shape == (4, 3) and solution.torques.shape == (4,)
    assert hard.max_normal_force == given_zero.max_normal_force
    np.testing.assert_array_equal(hard.torques, np.where(np.isnan(hard.forces[:, 0]), np.nan, 0))
