"""The fast exact stage and the certificates: agreement with the Clarabel reference on
random and adversarial grasps, certified margin intervals, verified certificates."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from grasp_cases import MU_PAPER, ellipsoid_grasps, random_rotation
from grasp_fc_ros.core import Status, check_force_closure, verify_certificates, warm_up
from grasp_fc_ros.core.exact.certificates import normalise_positions
from grasp_fc_ros.core.exact.exact_test import solve_exact
from grasp_fc_ros.core.exact.interior_point import (
    FORCE_CLOSURE,
    NOT_FORCE_CLOSURE,
    UNDECIDED,
    solve_fast,
)
from grasp_fc_ros.core.model.grasp_input import prepare_grasps
from grasp_fc_ros.core.tolerances import (
    MARGIN_ACCURACY,
    MARGIN_TOL,
    MAX_ABS_COORDINATE,
    MAX_FRICTION_COEFFICIENT,
)
from grasp_fc_ros.objects import make_object, sample_grasps

TETRAHEDRON = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float)


def _both(positions, normals, mu, margin="optimum"):
    grasps = prepare_grasps(positions, normals, mu)
    return solve_exact(grasps, margin), solve_exact(grasps, fast=False)


def _fast_codes(positions, normals, mu):
    grasps = prepare_grasps(positions, normals, mu)
    unit = normalise_positions(grasps.positions)[0]
    return solve_fast(unit, grasps.normals, grasps.mu)


@pytest.mark.parametrize("n_contacts", [4, 6, 8])
@pytest.mark.parametrize("mu", [MU_PAPER, 0.5])
def test_fast_stage_agrees_with_clarabel_on_box_grasps(n_contacts, mu):
    positions, normals = sample_grasps(make_object("box"), 400, n_contacts,
                                       np.random.default_rng(n_contacts))
    fast, reference = _both(positions, normals, mu)
    assert not reference.solver_failure.any()
    assert np.array_equal(fast.force_closure, reference.force_closure)
    # The fast stage itself decided nearly all of them (the rest went to Clarabel).
    assert np.mean(_fast_codes(positions, normals, mu)[0] == UNDECIDED) < 0.05
    # Certified intervals, at most MARGIN_ACCURACY wide, around Clarabel's optimum.
    closure = fast.force_closure
    assert np.all(fast.margin_upper[closure] - fast.margin[closure] <= MARGIN_ACCURACY)
    assert np.allclose(fast.margin, reference.margin, atol=2e-8)


@pytest.mark.parametrize("scale, offset", [(1.0, 0.0), (1e-6, 3e-6), (1e12, -7e12)])
def test_the_kernel_normalises_grasps_as_numpy_does(scale, offset):
    # solve_exact lets the kernel normalise each grasp; its results must be bit for bit
    # those of the numpy normalisation, at any length unit and position.
    positions, normals = ellipsoid_grasps(np.random.default_rng(5), 300, 6)
    positions = positions * scale + offset
    grasps = prepare_grasps(positions, normals, 0.5)
    unit = normalise_positions(grasps.positions)[0]
    for optimum in (False, True):
        in_kernel = solve_fast(grasps.positions, grasps.normals, grasps.mu, optimum,
                               normalise=True)
        in_numpy = solve_fast(unit, grasps.normals, grasps.mu, optimum)
        for ours, theirs in zip(in_kernel, in_numpy, strict=True):
            assert np.array_equal(ours, theirs, equal_nan=True)


def test_margin_bound_mode_gives_the_same_verdicts_with_a_certified_interval():
    positions, normals = ellipsoid_grasps(np.random.default_rng(21), 300, 6)
    bound, reference = _both(positions, normals, MU_PAPER, margin="bound")
    assert np.array_equal(bound.force_closure, reference.force_closure)
    # Clarabel's optimum lies within the certified interval (up to its own accuracy).
    optimum = reference.margin
    assert np.all(bound.margin <= optimum + 1e-8)
    assert np.all(bound.margin_upper >= optimum - 1e-8)


def test_tetrahedron_margin_interval_brackets_mu_over_four():
    result = check_force_closure(TETRAHEDRON, -TETRAHEDRON, mu=0.3)
    assert result.margin <= 0.075 <= result.margin_upper
    assert result.margin_upper - result.margin <= MARGIN_ACCURACY


def _bisect_threshold_mu(positions, normals, target=MARGIN_TOL):
    """mu at which the reference margin of one grasp crosses ``target``."""
    low, high = 1e-3, 5.0
    for _ in range(40):
        middle = np.sqrt(low * high)
        margin = solve_exact(prepare_grasps(positions, normals, middle), fast=False).margin[0]
        low, high = (middle, high) if margin < target else (low, middle)
    return np.sqrt(low * high)


def test_adversarial_grasps_never_disagree_with_the_reference():
    """Near-threshold (mu bisected until t* ~ MARGIN_TOL, then perturbed), shared normals,
    duplicates, collinear contacts and extreme scales: the fast stage may hand a grasp
    to Clarabel, but the two never disagree."""
    rng = np.random.default_rng(31)
    cases = []
    positions, normals = ellipsoid_grasps(rng, 6, 5)
    for g in range(len(positions)):
        threshold = _bisect_threshold_mu(positions[g], normals[g])
        for factor in (1 - 1e-3, 1 - 1e-6, 1.0, 1 + 1e-6, 1 + 1e-3):
            noise = 1e-9 * rng.normal(size=(5, 3))
            cases.append((positions[g] + noise, normals[g], threshold * factor))
    for _ in range(10):
        base = np.column_stack([rng.uniform(-1, 1, (3, 2)), np.zeros(3)])
        cases.append((np.concatenate([base, base + 1e-9 * rng.normal(size=(3, 3))]),
                      np.tile([0.0, 0.0, 1.0], (6, 1)), 1.0))
        p, n = ellipsoid_grasps(rng, 1, 4)
        cases.append((np.concatenate([p[0], p[0][:2] + 1e-7]),
                      np.concatenate([n[0], n[0][:2]]), 0.4))
        line = np.outer(rng.uniform(-1, 1, 5), rng.normal(size=3))
        cases.append((line + 1e-10 * rng.normal(size=(5, 3)), rng.normal(size=(5, 3)), 3.0))
        scale = 10.0 ** rng.uniform(-9, 9)
        cases.append((p[0] * scale + 10.0 ** rng.uniform(-9, 9), n[0], 0.5))
    for positions, normals, mu in cases:
        fast, reference = _both(positions, normals, mu)
        if not (fast.solver_failure[0] or reference.solver_failure[0]):
            assert fast.force_closure[0] == reference.force_closure[0], (positions, normals, mu)


def test_contacts_sharing_one_normal_are_rejected_by_the_fast_stage_with_a_bound():
    """The interior-point start does not exist for them (no equilibrium force has a
    positive total normal force); the trial wrench against the mean normal decides."""
    rng = np.random.default_rng(5)
    base = np.column_stack([rng.uniform(-1, 1, (3, 2)), np.ones(3)])
    positions = np.concatenate([base, base + 1e-9 * rng.normal(size=(3, 3))])[None]
    codes, _, t_hi, _, forces, _ = _fast_codes(positions, np.tile([0.0, 0.0, -1.0], (1, 6, 1)),
                                               2.0)
    assert codes[0] == NOT_FORCE_CLOSURE and t_hi[0] < MARGIN_TOL
    assert np.all(np.isnan(forces))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), n_contacts=st.integers(3, 8),
       mu=st.floats(0.05, 2.0))
def test_certificates_verify_and_verdicts_are_invariant_under_similarity(seed, n_contacts,
                                                                          mu):
    rng = np.random.default_rng(seed)
    positions, normals = ellipsoid_grasps(rng, 8, n_contacts)
    result = check_force_closure(positions, normals, mu, certificates=True)
    forces_ok, wrench_ok = verify_certificates(positions, normals, mu,
                                               result.contact_forces,
                                               result.separating_wrench)
    closure = result.status == Status.FORCE_CLOSURE
    assert np.array_equal(forces_ok, closure)
    rejected = (result.status == Status.FILTERED_OUT) | (result.status == Status.NOT_FORCE_CLOSURE)
    assert np.array_equal(wrench_ok, rejected & ~result.marginal)
    assert np.all(np.isnan(result.contact_forces[~closure]))
    assert np.all(np.isnan(result.separating_wrench[closure]))

    rotation = random_rotation(rng)
    scale = 10.0 ** rng.uniform(-3, 3)
    shift = rng.normal(size=3) * 10.0 ** rng.uniform(-3, 3)
    moved = check_force_closure(scale * positions @ rotation.T + shift, normals @ rotation.T,
                                mu, use_filter=False)
    assert np.array_equal(moved.force_closure, result.force_closure)


def test_the_separating_wrench_of_contacts_on_one_face_pushes_them_off():
    positions = np.column_stack([np.random.default_rng(2).uniform(-1, 1, (5, 2)), np.ones(5)])
    normals = np.tile([0.0, 0.0, -1.0], (5, 1))
    result = check_force_closure(positions + 7.0, normals, 0.8, use_filter=False,
                                 certificates=True)
    assert result.status == Status.NOT_FORCE_CLOSURE and not result.marginal
    wrench = result.separating_wrench
    assert wrench.shape == (6,) and np.linalg.norm(wrench) == pytest.approx(1.0)
    assert verify_certificates(positions + 7.0, normals, 0.8,
                               separating_wrench=wrench)[1]


def test_contact_forces_of_one_grasp_are_in_the_callers_frame():
    shift = np.array([100.0, -3.0, 5.0])
    result = check_force_closure(2.0 * TETRAHEDRON + shift, -TETRAHEDRON, 0.3,
                                 certificates=True)
    forces = result.contact_forces
    assert forces.shape == (4, 3)
    assert np.sum(forces * -TETRAHEDRON / np.sqrt(3)) == pytest.approx(1.0)
    assert np.allclose(forces.sum(axis=0), 0.0, atol=1e-12)
    assert np.allclose(np.cross(2.0 * TETRAHEDRON + shift, forces).sum(axis=0), 0.0,
                       atol=1e-10)


def test_verification_rejects_wrong_certificates():
    positions, normals = ellipsoid_grasps(np.random.default_rng(3), 30, 6)
    result = check_force_closure(positions, normals, 0.5, certificates=True)
    closure = result.force_closure
    assert closure.any() and (~closure).any()
    tampered = result.contact_forces.copy()
    tampered[:, 0] *= 1.5                       # no longer in equilibrium
    assert not verify_certificates(positions, normals, 0.5, tampered)[0][closure].any()
    # A force-closure grasp has no separating wrench: borrow another grasp's.
    donor = result.separating_wrench[np.flatnonzero(~closure & ~result.marginal)[0]]
    borrowed = np.broadcast_to(donor, (30, 6))
    assert not verify_certificates(positions, normals, 0.5,
                                   separating_wrench=borrowed)[1][closure].any()


def test_warm_up_compiles_every_mode():
    warm_up()
    result = check_force_closure(TETRAHEDRON, -TETRAHEDRON, 0.3, margin="bound",
                                 certificates=True)
    assert result.force_closure


def test_an_unknown_margin_mode_is_refused():
    with pytest.raises(ValueError, match="margin"):
        check_force_closure(TETRAHEDRON, -TETRAHEDRON, 0.3, margin="exact")


def test_near_duplicate_contacts_keep_their_verdict_under_similarity_transforms():
    """Red team: two contacts 1e-6 apart changed verdict (FC -> SOLVER_FAILURE) when the
    grasp was rotated, scaled and moved."""
    rng = np.random.default_rng(17)
    positions, normals = ellipsoid_grasps(rng, 40, 4)
    positions = np.concatenate([positions, positions[:, :1] + 1e-6 * rng.normal(size=(40, 1, 3))],
                               axis=1)
    normals = np.concatenate([normals, normals[:, :1]], axis=1)
    original = check_force_closure(positions, normals, 0.4, use_filter=False)
    assert original.force_closure.any()
    for _ in range(4):
        rotation = random_rotation(rng)
        scale = 10.0 ** rng.uniform(-4, 4)
        shift = rng.normal(size=3) * 10.0 ** rng.uniform(-4, 4)
        moved = check_force_closure(scale * positions @ rotation.T + shift,
                                    normals @ rotation.T, 0.4, use_filter=False)
        assert np.array_equal(moved.status, original.status)


def test_a_grasp_just_below_the_threshold_is_marginal_without_a_wrench():
    """0 < t* < MARGIN_TOL: strictly internal forces exist, so no wrench separates, but
    the grasp is too close to the boundary to be reported as force closure. (Much
    nearer t* = 0, e.g. 2e-7 here, a wrench meets the tolerant contract
    n.a + mu |a_t| <= 1e-6 max |a| and the grasp is not marginal.)"""
    positions, normals = ellipsoid_grasps(np.random.default_rng(41), 1, 5)
    mu = _bisect_threshold_mu(positions[0], normals[0], target=0.9 * MARGIN_TOL)
    result = check_force_closure(positions[0], normals[0], mu, use_filter=False,
                                 certificates=True)
    assert result.status == Status.NOT_FORCE_CLOSURE and result.marginal
    assert 0.0 < result.margin <= result.margin_upper < MARGIN_TOL
    assert np.all(np.isnan(result.separating_wrench))
    assert np.all(np.isnan(result.contact_forces))


def test_friction_at_its_bound_is_decided_with_verified_forces():
    """Red team: mu >= 1e10 made the Clarabel path fail (all grasps from 1e16). mu is
    now bounded by MAX_FRICTION_COEFFICIENT (larger values are refused by the input
    check); at the bound every grasp is decided, and more friction never loses force
    closure, so every grasp closed at mu = 1 stays closed, with forces that pass the
    caller-frame check."""
    positions, normals = ellipsoid_grasps(np.random.default_rng(12), 60, 4)
    moderate = check_force_closure(positions, normals, 1.0, use_filter=False)
    huge = check_force_closure(positions, normals, MAX_FRICTION_COEFFICIENT, use_filter=False,
                               certificates=True)
    assert not np.any(huge.status == Status.SOLVER_FAILURE)
    assert np.all(huge.force_closure[moderate.force_closure])
    forces_ok, _ = verify_certificates(positions, normals, MAX_FRICTION_COEFFICIENT,
                                       huge.contact_forces)
    assert np.array_equal(forces_ok, huge.force_closure)


@pytest.mark.parametrize("scale", [1e-300, 1e300, MAX_ABS_COORDINATE / 4])
def test_extreme_coordinates_keep_verdict_margin_and_certificates(scale):
    """Red team: coordinates near the float range overflowed the centroid (up to
    MAX_ABS_COORDINATE they are accepted; beyond it refused by the input check)."""
    positions = scale * (TETRAHEDRON + 1.0)
    result = check_force_closure(positions, -TETRAHEDRON, 0.3, use_filter=False,
                                 certificates=True)
    assert result.status == Status.FORCE_CLOSURE
    assert result.margin == pytest.approx(0.075, rel=1e-9)
    assert verify_certificates(positions, -TETRAHEDRON, 0.3, result.contact_forces)[0]


def test_collinear_contacts_are_marginal_without_a_wrench():
    """Rank 5: the only separating wrench (a torque about the line) does zero work at
    every contact, which rounding turns into noise of either sign."""
    rng = np.random.default_rng(8)
    positions = np.outer(np.linspace(-1, 1, 5), rng.normal(size=3)) + rng.normal(size=3)
    normals = rng.normal(size=(5, 3))
    result = check_force_closure(positions, normals, 0.3, use_filter=False,
                                 certificates=True)
    assert result.status == Status.NOT_FORCE_CLOSURE and result.margin == 0.0
    assert result.marginal == np.all(np.isnan(result.separating_wrench))


def test_fast_stage_results_are_identical_alone_and_in_a_batch():
    """Scratch space is shared across a batch: nothing may leak from grasp to grasp."""
    positions, normals = sample_grasps(make_object("box"), 60, 6, np.random.default_rng(9))
    together = _fast_codes(positions, normals, 0.5)
    for g in range(0, 60, 7):
        alone = _fast_codes(positions[g:g + 1], normals[g:g + 1], 0.5)
        for batch_value, alone_value in zip(together, alone, strict=True):
            np.testing.assert_array_equal(batch_value[g], alone_value[0])


def test_verdicts_just_above_the_threshold_are_certified_by_the_fast_stage():
    """Verdicts skip the witness where the iterate's forces before projection are not
    deep enough to matter (WITNESS_SKIP_SLACK): grasps with t* just above MARGIN_TOL must
    still be certified force closure by the fast stage itself, with forces that verify
    and a lower bound no higher than the optimum; just below, never force closure."""
    rng = np.random.default_rng(41)
    positions, normals = ellipsoid_grasps(rng, 4, 6)
    for g in range(len(positions)):
        for target, closure in ((3 * MARGIN_TOL, True), (MARGIN_TOL / 3, False)):
            mu = _bisect_threshold_mu(positions[g], normals[g], target)
            grasps = prepare_grasps(positions[g], normals[g], mu)
            optimum = solve_exact(grasps, fast=False).margin[0]
            unit = normalise_positions(grasps.positions)[0]
            codes, t_lo, t_hi, _, _, _ = solve_fast(unit, grasps.normals, grasps.mu)
            if closure:
                assert codes[0] == FORCE_CLOSURE and MARGIN_TOL <= t_lo[0] <= optimum + 1e-8
            else:
                assert codes[0] != FORCE_CLOSURE and t_hi[0] >= optimum - 1e-8
            result = check_force_closure(positions[g], normals[g], mu, margin="bound",
                                         use_filter=False, certificates=True)
            assert (result.status == Status.FORCE_CLOSURE) == closure
            assert result.margin <= optimum + 1e-8
            if closure:
                assert verify_certificates(positions[g], normals[g], mu,
                                           result.contact_forces)[0]


def _compiled_signatures() -> int:
    from grasp_fc_ros.core import one_grasp
    from grasp_fc_ros.core.exact import interior_point
    from grasp_fc_ros.core.filter import positive_span
    from grasp_fc_ros.core.forces import force_interior_point
    kernels = (interior_point._solve_all, one_grasp._prepare_one,
               force_interior_point._solve_all, positive_span._pair_test_kernel)
    return sum(len(kernel.signatures) for kernel in kernels)


def test_read_only_input_compiles_nothing_after_warm_up():
    # The node decodes queries with np.frombuffer: read-only arrays, a numba type of
    # their own. After warm_up no entry point may compile a kernel for them.
    from grasp_fc_ros.core import minimum_friction, optimal_contact_forces
    warm_up()
    rng = np.random.default_rng(5)
    grasps = [sample_grasps(make_object("box"), 6, n, rng) for n in (6, 4)]
    for positions, normals in grasps:
        positions.setflags(write=False)
        normals.setflags(write=False)
    mu = np.full((6, 6), 0.5)
    mu.setflags(write=False)
    (positions, normals), (four_p, four_n) = grasps
    before = _compiled_signatures()
    check_force_closure(positions[0], normals[0], 0.5)  # the one-grasp path
    for margin in ("bound", "optimum"):
        check_force_closure(positions, normals, mu, margin=margin)
    check_force_closure(positions, normals, mu, certificates=True)
    check_force_closure(four_p, four_n, mu[:, :4], use_filter=True)  # the pair test
    minimum_friction(positions, normals, mu)
    optimal_contact_forces(positions[0], normals[0], mu[0], np.array([0, 0, -1.0, 0, 0, 0]))
    assert _compiled_signatures() == before


def test_the_newton_systems_ldl_factor_solves_and_refuses_an_indefinite_matrix():
    from grasp_fc_ros.core._kernels.linear_algebra import ldl, ldl_substitute

    rng = np.random.default_rng(5)
    factor, x = np.empty((6, 6)), np.empty(6)
    for _ in range(50):
        half = rng.standard_normal((6, 6))
        matrix = half @ half.T + 1e-3 * np.eye(6)
        rhs = rng.standard_normal(6)
        lower = np.tril(matrix) + np.triu(np.full((6, 6), np.nan), 1)    # reads the lower only
        assert ldl(lower, factor)
        ldl_substitute(factor, rhs, x)
        np.testing.assert_allclose(matrix @ x, rhs, atol=1e-9 * np.linalg.cond(matrix))
    indefinite = np.diag([1.0, 2.0, -1.0, 1.0, 1.0, 1.0])
    assert not ldl(indefinite, factor)
