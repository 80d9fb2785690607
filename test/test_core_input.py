"""Input shapes, broadcasting and errors of the core's public API."""

import numpy as np
import pytest

from grasp_fc_ros.core import (check_force_closure, exact_force_closure, torque_filter,
                               validate_grasps)

TETRAHEDRON = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float)


def batch(n_grasps=4):
    return np.tile(TETRAHEDRON, (n_grasps, 1, 1)), np.tile(-TETRAHEDRON, (n_grasps, 1, 1))


def test_one_grasp_gives_0d_results_and_a_batch_gives_one_per_grasp():
    single = check_force_closure(TETRAHEDRON, -TETRAHEDRON, 0.5)
    assert single.force_closure.shape == single.margin.shape == single.status.shape == ()
    positions, normals = batch(3)
    several = check_force_closure(positions, normals, 0.5)
    assert several.force_closure.shape == several.filtered_out.shape == (3,)
    assert torque_filter(TETRAHEDRON, -TETRAHEDRON, 0.5).shape == ()
    assert exact_force_closure(positions, normals, 0.5).shape == (3,)


def test_normal_length_does_not_matter():
    lengths = np.array([0.001, 1.0, 7.0, 1e4])[:, None]
    a = check_force_closure(TETRAHEDRON, -TETRAHEDRON, 0.3)
    b = check_force_closure(TETRAHEDRON, -TETRAHEDRON * lengths, 0.3)
    assert a.force_closure == b.force_closure and a.margin == pytest.approx(b.margin)


def test_mu_broadcasts_per_contact_and_per_grasp():
    positions, normals = batch(2)
    per_contact = check_force_closure(positions, normals, [0.3, 0.3, 0.3, 0.3])
    per_grasp = check_force_closure(positions, normals, np.array([[0.3], [0.3]]))
    assert np.allclose(per_contact.margin, per_grasp.margin)
    with pytest.raises(ValueError, match=r"\(N, 1\)"):
        check_force_closure(positions, normals, [0.3, 0.3, 0.3])


@pytest.mark.parametrize("corrupt, message", [
    (lambda p, n, m: p.__setitem__((2, 1, 0), np.nan), "grasp 2, contact 1: position is not finite"),
    (lambda p, n, m: n.__setitem__((1, 3, 2), np.inf), "grasp 1, contact 3: normal is not finite"),
    (lambda p, n, m: n.__setitem__((0, 2), 0.0), "grasp 0, contact 2: normal has zero length"),
    (lambda p, n, m: m.__setitem__((3, 0), 0.0), "grasp 3, contact 0: friction coefficient must be > 0"),
    (lambda p, n, m: m.__setitem__((3, 1), -1.0), "grasp 3, contact 1: friction coefficient must be > 0"),
    (lambda p, n, m: m.__setitem__((2, 2), np.nan), "grasp 2, contact 2: friction coefficient is not finite"),
])
def test_bad_values_name_the_grasp_and_contact(corrupt, message):
    positions, normals = batch()
    mu = np.full((4, 4), 0.5)
    corrupt(positions, normals, mu)
    for function in (check_force_closure, exact_force_closure, torque_filter):
        with pytest.raises(ValueError, match=message):
            function(positions, normals, mu)
    report = validate_grasps(positions, normals, mu)
    bad = int(message.split()[1].rstrip(","))
    assert report.reasons[bad] == message
    assert list(report.valid) == [g != bad for g in range(4)]


@pytest.mark.parametrize("positions, normals, message", [
    (np.zeros((4, 2)), np.zeros((4, 2)), "positions must have shape"),
    (np.zeros((4, 3)), np.zeros((3, 3)), "normals must have the same shape"),
    (np.zeros(3), np.zeros(3), "positions must have shape"),
])
def test_wrong_shapes_are_refused(positions, normals, message):
    with pytest.raises(ValueError, match=message):
        check_force_closure(positions, normals, 0.5)


def test_a_grasp_needs_two_contacts():
    with pytest.raises(ValueError, match="grasp 0: has 1 contacts, needs at least 2"):
        check_force_closure(TETRAHEDRON[:1], -TETRAHEDRON[:1], 0.5)


def test_unknown_origins_are_refused():
    with pytest.raises(ValueError, match="origins must be one of"):
        torque_filter(TETRAHEDRON, -TETRAHEDRON, 0.5, origins="centroid")


def test_validation_reports_every_bad_grasp_and_keeps_the_good_ones():
    positions, normals = batch(5)
    positions[1, 0, 0] = np.nan
    normals[3, 2] = 0.0
    report = validate_grasps(positions, normals, 0.5)
    assert list(report.valid) == [True, False, True, False, True]
    assert report.reasons[0] == report.reasons[2] == report.reasons[4] == ""
    good = check_force_closure(positions[report.valid], normals[report.valid], 0.5)
    assert good.force_closure.all()
