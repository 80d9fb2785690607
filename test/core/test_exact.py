"""The exact SOCP test: known grasps, the pyramid reference, batches and retries."""

import numpy as np
import pytest

from grasp_cases import MU_PAPER, ellipsoid_grasps
from grasp_fc_ros.core import Status, check_force_closure, exact_force_closure
from grasp_fc_ros.core.exact import exact_test
from grasp_fc_ros.core.exact.exact_test import solve_exact
from grasp_fc_ros.core.model.grasp_input import prepare_grasps
from grasp_fc_ros.core.tolerances import MARGIN_TOL
from reference_pyramids import pyramid_margin

TETRAHEDRON = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float)


def test_tetrahedral_grasp_of_a_sphere_is_force_closure_with_the_expected_margin():
    result = check_force_closure(TETRAHEDRON, -TETRAHEDRON, mu=0.3)
    assert result.force_closure and result.status == Status.FORCE_CLOSURE
    # Equal normal forces 1/4 with no tangential part: margin mu / 4.
    assert result.margin == pytest.approx(0.3 / 4, rel=1e-6)


def test_three_finger_equatorial_grasp_is_force_closure():
    angle = 2 * np.pi * np.arange(3) / 3
    positions = np.stack([np.cos(angle), np.sin(angle), np.zeros(3)], axis=1)
    assert exact_force_closure(positions, -positions, mu=0.1)


def test_two_antipodal_contacts_are_not_force_closure():
    """Rotation about the line through the contacts cannot be resisted."""
    positions = np.array([[1.0, 0, 0], [-1.0, 0, 0]])
    result = check_force_closure(positions, -positions, mu=2.0, use_filter=False)
    assert not result.force_closure and result.status == Status.NOT_FORCE_CLOSURE
    assert result.margin == 0.0


def test_collinear_contacts_are_not_force_closure_whatever_the_friction():
    positions = np.outer(np.linspace(-1, 1, 5), [1.0, 2.0, 0.5])
    normals = np.random.default_rng(0).normal(size=(5, 3))
    assert not exact_force_closure(positions, normals, mu=10.0)


def test_contacts_pushing_from_one_side_are_not_force_closure():
    rng = np.random.default_rng(3)
    positions = np.column_stack([rng.uniform(-1, 1, (6, 2)), np.zeros(6)])
    normals = np.tile([0.0, 0.0, -1.0], (6, 1))
    assert not exact_force_closure(positions, normals, mu=1.0)


def test_friction_makes_the_difference_on_a_box_squeeze():
    """Two fingers on each of two opposite faces of a box: force closure needs friction
    to resist sliding along the faces, and more friction means more margin."""
    positions = np.array([[1, 0.5, 0.5], [1, -0.5, -0.5], [-1, 0.5, -0.5], [-1, -0.5, 0.5]])
    normals = np.array([[-1, 0, 0], [-1, 0, 0], [1, 0, 0], [1, 0, 0]], float)
    small = check_force_closure(positions, normals, mu=0.05)
    large = check_force_closure(positions, normals, mu=0.5)
    assert small.force_closure and large.force_closure
    assert large.margin > small.margin


def test_verdicts_agree_with_inscribed_and_circumscribed_pyramids():
    rng = np.random.default_rng(11)
    positions, normals = ellipsoid_grasps(rng, 250, 4)
    exact = check_force_closure(positions, normals, MU_PAPER * 3, use_filter=False)
    decided = 0
    for g in range(len(positions)):
        inner = pyramid_margin(positions[g], normals[g], MU_PAPER * 3, inscribed=True)
        outer = pyramid_margin(positions[g], normals[g], MU_PAPER * 3, inscribed=False)
        if inner > 1e-5:          # the inscribed pyramid grasp is clearly force closure
            assert exact.force_closure[g], g
            decided += 1
        if outer == 0.0:          # not even the circumscribed pyramid grasp is
            assert not exact.force_closure[g], g
            decided += 1
    assert decided > 200


def test_force_closure_verdicts_come_with_a_margin_above_tolerance():
    rng = np.random.default_rng(2)
    positions, normals = ellipsoid_grasps(rng, 500, 6)
    result = check_force_closure(positions, normals, MU_PAPER, use_filter=False)
    assert np.all(result.margin[result.force_closure] >= MARGIN_TOL)
    assert np.all(result.margin[~result.force_closure] < MARGIN_TOL + 1e-7)


def test_verdict_does_not_depend_on_the_batch():
    rng = np.random.default_rng(4)
    positions, normals = ellipsoid_grasps(rng, 300, 6)
    together = check_force_closure(positions, normals, MU_PAPER, use_filter=False)
    order = rng.permutation(300)
    shuffled = check_force_closure(positions[order], normals[order], MU_PAPER,
                                   use_filter=False)
    assert np.array_equal(shuffled.force_closure, together.force_closure[order])
    for g in range(0, 300, 37):
        alone = check_force_closure(positions[g], normals[g], MU_PAPER, use_filter=False)
        assert alone.force_closure == together.force_closure[g]
        assert alone.margin == pytest.approx(together.margin[g], abs=1e-6)


def test_filter_changes_nothing_but_the_work():
    rng = np.random.default_rng(6)
    positions, normals = ellipsoid_grasps(rng, 1500, 6)
    filtered = check_force_closure(positions, normals, MU_PAPER, use_filter=True)
    unfiltered = check_force_closure(positions, normals, MU_PAPER, use_filter=False)
    assert np.array_equal(filtered.force_closure, unfiltered.force_closure)
    assert filtered.filtered_out.sum() > 300
    assert np.all(np.isnan(filtered.margin[filtered.filtered_out]))
    assert np.all(filtered.status[filtered.filtered_out] == Status.FILTERED_OUT)


def test_a_batch_solve_that_stops_early_is_retried_grasp_by_grasp(monkeypatch):
    """Force every batch solve to end at its iteration limit: the retries alone must
    give the same verdicts as normal solves."""
    rng = np.random.default_rng(8)
    positions, normals = ellipsoid_grasps(rng, 40, 6)
    grasps = prepare_grasps(positions, normals, MU_PAPER)
    normal = solve_exact(grasps, fast=False)
    original_settings = exact_test._settings

    def starved(tight):
        settings = original_settings(tight)
        if not tight:
            settings.max_iter = 2
        return settings

    monkeypatch.setattr(exact_test, "_settings", starved)
    retried = solve_exact(grasps, fast=False)
    assert np.array_equal(retried.force_closure, normal.force_closure)
    assert not np.any(retried.solver_failure)
    # The margin is an optimum, not a stopped iterate's value.
    assert np.allclose(retried.margin, normal.margin, atol=1e-6)
    assert normal.force_closure.any()


def test_an_undecidable_grasp_is_reported_as_a_solver_failure(monkeypatch):
    """If even the lone retry cannot decide, say so instead of guessing."""
    positions, normals = ellipsoid_grasps(np.random.default_rng(9), 3, 6)
    original_settings = exact_test._settings

    def starved(tight):
        settings = original_settings(tight)
        settings.max_iter = 1
        return settings

    monkeypatch.setattr(exact_test, "_settings", starved)
    result = solve_exact(prepare_grasps(positions, normals, MU_PAPER), fast=False)
    assert np.all(result.solver_failure)
    assert not result.force_closure.any()


def _shared_normal_batch(rng, mus=(0.1, 0.5, 2.0), per_mu=67):
    """Three contacts on one face of a box, each doubled 1e-9 apart: never force closure
    (every equilibrium force has zero total normal force)."""
    positions, mu = [], []
    for value in mus:
        for _ in range(per_mu):
            base = np.column_stack([rng.uniform(-1, 1, (3, 2)), np.ones(3)])
            positions.append(np.concatenate([base, base + 1e-9 * rng.normal(size=(3, 3))]))
            mu.append(np.full(6, value))
    positions = np.array(positions)
    return positions, np.broadcast_to([0.0, 0.0, -1.0], positions.shape), np.array(mu)


def test_contacts_sharing_one_normal_are_never_force_closure_in_a_batch():
    """Regression: batched solves passed rounding noise (~1e-27) as a witness."""
    positions, normals, mu = _shared_normal_batch(np.random.default_rng(0))
    result = check_force_closure(positions, normals, mu, use_filter=False)
    assert not result.force_closure.any()
    assert np.all(result.status == Status.NOT_FORCE_CLOSURE)


def test_no_false_force_closure_on_flat_faces_with_the_filter_off():
    """Regression (red team): three-finger grasps on a box, the filter off. Every force
    closure verdict must survive the circumscribed-pyramid LP (a relaxation)."""
    from grasp_fc_ros.objects import make_object, sample_grasps
    rng = np.random.default_rng(1)
    positions, normals = sample_grasps(make_object("box"), 2000, 3, rng)
    result = check_force_closure(positions, normals, 0.5, use_filter=False)
    assert result.force_closure.sum() > 20
    for g in np.flatnonzero(result.force_closure):
        assert pyramid_margin(positions[g], normals[g], 0.5, inscribed=False) > 0.0, g
