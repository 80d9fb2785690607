"""Input shapes, broadcasting and errors of the core's public API."""

import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from grasp_fc_ros.core import (
    Status,
    check_force_closure,
    exact_force_closure,
    torque_filter,
    validate_grasps,
)

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
    (lambda p, n, m: p.__setitem__((2, 1, 0), np.nan),
     "grasp 2, contact 1: position is not finite, got (nan, -1, -1)"),
    (lambda p, n, m: n.__setitem__((1, 3, 2), np.inf),
     "grasp 1, contact 3: normal is not finite, got (1, 1, inf)"),
    (lambda p, n, m: n.__setitem__((0, 2), 0.0),
     "grasp 0, contact 2: normal has zero length, got (0, 0, 0)"),
    (lambda p, n, m: m.__setitem__((3, 0), 0.0),
     "grasp 3, contact 0: friction coefficient must be > 0, got 0"),
    (lambda p, n, m: m.__setitem__((3, 1), -1.0),
     "grasp 3, contact 1: friction coefficient must be > 0, got -1"),
    (lambda p, n, m: m.__setitem__((2, 2), np.nan),
     "grasp 2, contact 2: friction coefficient is not finite, got nan"),
])
def test_bad_values_name_the_grasp_and_contact(corrupt, message):
    positions, normals = batch()
    mu = np.full((4, 4), 0.5)
    corrupt(positions, normals, mu)
    for function in (check_force_closure, exact_force_closure, torque_filter):
        with pytest.raises(ValueError, match=re.escape(message)):
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


# Inputs at the edges of floating point: each gets a correct verdict or a clear refusal.

def ellipsoid_batch(n_grasps=200, n_contacts=5, seed=0):
    rng = np.random.default_rng(seed)
    direction = rng.normal(size=(n_grasps, n_contacts, 3))
    direction /= np.linalg.norm(direction, axis=2, keepdims=True)
    positions = direction * [1.0, 2.0, 3.0]
    normals = -positions / np.array([1.0, 2.0, 3.0]) ** 2
    return positions, normals


@pytest.mark.parametrize("length", [1e-300, 1e-13, 1e155, 1e300])
def test_normals_of_any_representable_length_give_the_same_verdicts(length):
    positions, normals = ellipsoid_batch()
    unit = normals / np.linalg.norm(normals, axis=2, keepdims=True)
    reference = check_force_closure(positions, unit, 0.5)
    scaled = check_force_closure(positions, unit * length, 0.5)
    assert reference.force_closure.any() and not reference.force_closure.all()
    assert np.array_equal(reference.status, scaled.status)
    assert np.allclose(reference.margin, scaled.margin, equal_nan=True, atol=1e-9)


def test_only_zero_and_subnormal_normals_are_too_short():
    normals = -TETRAHEDRON.copy()
    normals[1] = [5e-324, 0.0, 1e-310]
    with pytest.raises(ValueError, match="grasp 0, contact 1: normal is too short"):
        check_force_closure(TETRAHEDRON, normals, 0.5)
    normals[1] = [2.3e-308, 0.0, 1e-310]  # one normal float component: a direction
    assert check_force_closure(TETRAHEDRON, normals, 0.5).status in (0, 1, 2)


@pytest.mark.parametrize("scale", [1e-300, 1e-150, 1e150, 1e300])
def test_verdicts_do_not_change_at_extreme_length_scales(scale):
    positions, normals = ellipsoid_batch(seed=1)
    reference = check_force_closure(positions, normals, 0.5, origins="all")
    scaled = check_force_closure(positions * scale, normals, 0.5, origins="all")
    assert np.array_equal(reference.force_closure, scaled.force_closure)
    # The filter may catch other grasps at another scale (seed origins are unit-bound),
    # but never a force-closure one.
    for origins in ("seed", "all"):
        assert not np.any(reference.force_closure
                          & ~torque_filter(positions * scale, normals, 0.5, origins=origins))


def test_coordinates_near_the_float_limit_are_refused_naming_the_contact():
    positions, normals = batch(3)
    positions[2, 1] = [9e307, -9e307, 0.0]
    with pytest.raises(ValueError, match="grasp 2, contact 1: position has a coordinate "
                                         "beyond .* larger length unit"):
        check_force_closure(positions, normals, 0.5)
    report = validate_grasps(positions, normals, 0.5)
    assert list(report.valid) == [True, True, False]


def test_the_largest_accepted_coordinates_give_correct_verdicts():
    limit = 2.0 ** 1000
    positions = TETRAHEDRON * limit
    # A grasp spanning the whole accepted range, and one far from the origin.
    shifted = TETRAHEDRON * 1e290 + limit * 0.5
    for p in (positions, shifted):
        result = check_force_closure(p, -TETRAHEDRON, 0.5)
        assert result.status == Status.FORCE_CLOSURE, result
        assert torque_filter(p, -TETRAHEDRON, 0.5, origins="all")


def test_friction_beyond_its_bound_is_refused_and_at_the_bound_is_decided():
    from grasp_fc_ros.core.tolerances import MAX_FRICTION_COEFFICIENT
    positions, normals = ellipsoid_batch(n_grasps=60, n_contacts=3, seed=2)
    at_bound = check_force_closure(positions, normals, MAX_FRICTION_COEFFICIENT)
    assert not np.any(at_bound.status == Status.SOLVER_FAILURE), (
        "solver failures at the friction bound")
    mu = np.full((60, 3), 0.5)
    mu[7, 2] = MAX_FRICTION_COEFFICIENT * 1.5
    with pytest.raises(ValueError, match="grasp 7, contact 2: friction coefficient exceeds"):
        check_force_closure(positions, normals, mu)
    assert validate_grasps(positions, normals, mu).valid.sum() == 59


@pytest.mark.parametrize("argument", ["positions", "normals", "mu"])
def test_complex_and_non_numeric_input_is_refused_naming_the_argument(argument):
    values = {"positions": TETRAHEDRON, "normals": -TETRAHEDRON, "mu": 0.5}
    values[argument] = np.asarray(values[argument]) + 1e-3j
    with pytest.raises(ValueError, match=f"{argument} must be real numbers, got complex"):
        check_force_closure(values["positions"], values["normals"], values["mu"])
    with pytest.raises(ValueError, match=f"{argument} must be real numbers, got complex"):
        validate_grasps(values["positions"], values["normals"], values["mu"])
    values[argument] = np.full(np.shape(values[argument]), "x")
    with pytest.raises(ValueError, match=f"{argument} must be real numbers"):
        check_force_closure(values["positions"], values["normals"], values["mu"])


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_quick_all_valid_check_agrees_with_the_per_grasp_validation(seed):
    """prepare_grasps skips the per-grasp validation when a few whole-array checks pass:
    those must pass exactly when the per-grasp validation finds nothing."""
    from grasp_fc_ros.core.model.grasp_input import _all_valid, _largest_component, _validate
    from grasp_fc_ros.core.tolerances import (
        MAX_ABS_COORDINATE,
        MAX_FRICTION_COEFFICIENT,
        MIN_NORMAL_COMPONENT,
    )
    rng = np.random.default_rng(seed)
    positions = rng.normal(size=(4, 5, 3))
    normals = rng.normal(size=(4, 5, 3))
    mu = rng.uniform(0.1, 1.0, (4, 5))
    bad_values = {
        "positions": [np.nan, np.inf, -np.inf, 2 * MAX_ABS_COORDINATE, MAX_ABS_COORDINATE],
        "normals": [np.nan, np.inf, 0.0, MIN_NORMAL_COMPONENT / 2, MIN_NORMAL_COMPONENT],
        "mu": [np.nan, np.inf, 0.0, -1.0, 2 * MAX_FRICTION_COEFFICIENT,
               MAX_FRICTION_COEFFICIENT],
    }
    for _ in range(rng.integers(0, 3)):
        which = rng.choice(list(bad_values))
        value = rng.choice(bad_values[which])
        g, c = rng.integers(4), rng.integers(5)
        if which == "mu":
            mu[g, c] = value
        elif which == "normals":
            normals[g, c] = value if value in (np.nan, np.inf) or value == 0.0 else (
                value * np.array([1.0, -1.0, 0.5]))
        else:
            positions[g, c, rng.integers(3)] = value
    quick = _all_valid(positions, normals, mu, _largest_component(normals))
    assert quick == _validate(positions, normals, mu).valid.all()


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 4), st.integers(2, 5), st.data())
def test_validate_grasps_shortcut_reports_as_the_full_check(n_grasps, n_contacts, data):
    """validate_grasps skips its per-check bookkeeping for good input: same answer."""
    from grasp_fc_ros.core.model.grasp_input import _validate

    values = st.sampled_from([0.0, 1.0, -2.5, 1e-320, 1e300, 1e302, np.inf, np.nan])
    p = np.array(data.draw(st.lists(values, min_size=n_grasps * n_contacts * 3,
                                    max_size=n_grasps * n_contacts * 3))).reshape(
        n_grasps, n_contacts, 3)
    nrm = np.array(data.draw(st.lists(values, min_size=p.size, max_size=p.size))).reshape(p.shape)
    m = np.array(data.draw(st.lists(st.sampled_from([0.5, 0.0, -1.0, 2000.0, np.nan]),
                                    min_size=n_grasps * n_contacts,
                                    max_size=n_grasps * n_contacts))).reshape(p.shape[:2])
    fast, full = validate_grasps(p, nrm, m), _validate(p, nrm, m)
    np.testing.assert_array_equal(fast.valid, full.valid)
    assert fast.reasons == full.reasons


def test_unit_vectors_of_a_large_batch_equal_those_of_its_small_pieces():
    """unit_vectors works component by component from COMPONENTWISE_MIN_VECTORS vectors
    on and in its broadcast form below: bit for bit the same directions."""
    from grasp_fc_ros.core.model.grasp_input import COMPONENTWISE_MIN_VECTORS, unit_vectors
    rng = np.random.default_rng(11)
    vectors = rng.normal(size=(3 * COMPONENTWISE_MIN_VECTORS, 3)) * 10.0 ** rng.integers(
        -300, 300, size=(3 * COMPONENTWISE_MIN_VECTORS, 1))
    vectors[::7, 1] = 0.0
    pieces = np.concatenate([unit_vectors(piece) for piece in np.split(vectors, 12)])
    assert np.array_equal(unit_vectors(vectors), pieces)
    np.testing.assert_allclose(np.linalg.norm(pieces, axis=1), 1.0, rtol=1e-15)
