"""The certified epsilon: the cube anchor, the pyramid bracket of an independent Qhull
reference, upper = h(direction), invariances, consistency with the verdicts on random
and adversarial grasps, rtol 1e-6, soft fingers and the L-infinity budget, input errors."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from grasp_cases import MU_PAPER, adversarial_grasps, ellipsoid_grasps, random_rotation
from grasp_fc_ros.core import check_force_closure, epsilon_quality
from grasp_fc_ros.core.quality.epsilon import MIN_RTOL, ZERO_UPPER_TOL
from reference_epsilon import pyramid_epsilon, support_value

CUBE = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]],
                float)

#: Qhull's facet offsets are accurate to ~1e-14 here; the pyramid bracket is compared
#: with this relative slack.
HULL_SLACK = 1e-9
#: upper is h(direction) raised by the rounding allowance (64 ulps of a wrench scale of
#: at most ~3): recomputing h must land this close below it.
RECOMPUTE_TOL = 1e-12


def assert_bounds_contract(result, rtol, positions, normals, mu, torsional=None,
                           budget="l1"):
    """lower <= upper, the rtol contract where converged, the verdicts' consistency and
    upper = h(direction) recomputed from the definition."""
    lower, upper = np.atleast_1d(result.lower), np.atleast_1d(result.upper)
    fc = np.atleast_1d(result.force_closure)
    direction = np.atleast_2d(result.direction)
    converged = np.atleast_1d(result.converged)
    assert np.all(lower >= 0) and np.all(lower <= upper)
    assert np.all(lower[~fc] == 0)
    assert np.all(upper[fc] > 0)
    assert np.all(upper[fc & converged] - lower[fc & converged]
                  <= rtol * upper[fc & converged])
    np.testing.assert_allclose(np.linalg.norm(direction, axis=1), 1.0, atol=1e-12)
    positions = np.asarray(positions, float)
    positions = positions.reshape(-1, positions.shape[-2], 3)
    normals = np.asarray(normals, float).reshape(positions.shape)
    mu = np.broadcast_to(np.asarray(mu, float), positions.shape[:2])
    centres = np.atleast_2d(result.center)
    scales = np.atleast_1d(result.torque_scale)
    for g in range(positions.shape[0]):
        h = support_value(positions[g], normals[g], mu[g], direction[g], centres[g],
                          scales[g], torsional, budget)
        assert h <= upper[g] and upper[g] - h <= RECOMPUTE_TOL * max(1.0, upper[g])


# -- the anchor ---------------------------------------------------------------------


@pytest.mark.parametrize("rtol", [1e-3, 1e-6])
def test_cube_faces_have_epsilon_one_over_root_six(rtol):
    """Six contacts at the faces of a cube, mu = 0.5, c = 0, L = 1: 1/sqrt(6)."""
    result = epsilon_quality(CUBE, -CUBE, 0.5, torque_scale=1.0, rtol=rtol)
    exact = 1.0 / np.sqrt(6.0)
    assert result.lower <= exact <= result.upper
    assert result.upper - result.lower <= rtol * result.upper
    assert result.converged and result.force_closure
    assert_bounds_contract(result, rtol, CUBE, -CUBE, 0.5)


def test_cube_with_default_scale_about_its_centre():
    """The default L is max |p_i - c| = 1 here; moving c moves L and epsilon."""
    default = epsilon_quality(CUBE, -CUBE, 0.5)
    assert default.torque_scale == 1.0
    assert default.lower <= 1.0 / np.sqrt(6.0) <= default.upper


# -- the independent reference ----------------------------------------------------------


@pytest.mark.parametrize("n_contacts,mu", [(4, 0.5), (5, MU_PAPER), (6, 0.5), (6, MU_PAPER)])
def test_bounds_bracket_inscribed_and_circumscribed_pyramids(n_contacts, mu):
    """Q1 of the inscribed 16-gon pyramid <= upper and lower <= Q1 of the circumscribed
    one: both pyramids are exact polytopes inside / around W."""
    rng = np.random.default_rng(100 + n_contacts)
    # Few random grasps are force closure at the paper's friction: draw more.
    positions, normals = ellipsoid_grasps(rng, 40 if mu == 0.5 else 200, n_contacts)
    centre = rng.normal(scale=0.2, size=3)
    result = epsilon_quality(positions, normals, mu, center=centre)
    assert_bounds_contract(result, 1e-3, positions, normals, mu)
    checked = 0
    for g in np.flatnonzero(result.force_closure)[:8]:
        inner = pyramid_epsilon(positions[g], normals[g], mu, centre, sides=16)
        outer = pyramid_epsilon(positions[g], normals[g], mu, centre, sides=16,
                                inscribed=False)
        assert inner <= result.upper[g] * (1 + HULL_SLACK)
        assert result.lower[g] <= outer * (1 + HULL_SLACK)
        checked += 1
    assert checked >= 3


def test_not_force_closure_by_the_pyramids_is_zero_upper_here_too():
    """A grasp whose circumscribed pyramid is not force closure has epsilon 0: the
    verdict says so, and upper is within ZERO_UPPER_TOL of 0."""
    rng = np.random.default_rng(7)
    positions, normals = ellipsoid_grasps(rng, 60, 4)
    result = epsilon_quality(positions, normals, MU_PAPER)
    for g in range(60):
        outer = pyramid_epsilon(positions[g], normals[g], MU_PAPER, sides=12, inscribed=False)
        if outer == 0.0:
            assert not result.force_closure[g] and result.lower[g] == 0
            assert result.upper[g] <= ZERO_UPPER_TOL * 3.0


def test_per_contact_friction_matches_the_reference():
    rng = np.random.default_rng(3)
    positions, normals = ellipsoid_grasps(rng, 12, 5)
    mu = rng.uniform(0.2, 0.9, (12, 5))
    result = epsilon_quality(positions, normals, mu)
    assert_bounds_contract(result, 1e-3, positions, normals, mu)
    for g in np.flatnonzero(result.force_closure)[:4]:
        inner = pyramid_epsilon(positions[g], normals[g], mu[g], sides=16)
        outer = pyramid_epsilon(positions[g], normals[g], mu[g], sides=16, inscribed=False)
        assert inner <= result.upper[g] * (1 + HULL_SLACK)
        assert result.lower[g] <= outer * (1 + HULL_SLACK)


def test_rtol_one_in_a_million():
    rng = np.random.default_rng(11)
    positions, normals = ellipsoid_grasps(rng, 30, 6)
    result = epsilon_quality(positions, normals, 0.5, rtol=1e-6)
    fc = result.force_closure
    assert fc.sum() >= 5 and result.converged[fc].all()
    assert_bounds_contract(result, 1e-6, positions, normals, 0.5)
    coarse = epsilon_quality(positions, normals, 0.5)
    assert np.all(coarse.lower <= result.upper) and np.all(result.lower <= coarse.upper)
    for g in np.flatnonzero(fc)[:3]:
        inner = pyramid_epsilon(positions[g], normals[g], 0.5, sides=24)
        assert inner <= result.upper[g] * (1 + HULL_SLACK)


# -- invariance -------------------------------------------------------------------------


def overlap(a, b):
    """The two results' intervals intersect, grasp by grasp."""
    return np.all(np.maximum(a.lower, b.lower) <= np.minimum(a.upper, b.upper) * (1 + 1e-12))


def test_translation_rotation_and_uniform_scaling_with_the_centre():
    rng = np.random.default_rng(5)
    positions, normals = ellipsoid_grasps(rng, 30, 5)
    centre = np.array([0.1, -0.2, 0.3])
    base = epsilon_quality(positions, normals, 0.5, center=centre)
    shift = np.array([3.0, -7.0, 11.0])
    rotation = random_rotation(rng)
    moved = epsilon_quality(positions + shift, normals, 0.5, center=centre + shift)
    turned = epsilon_quality(positions @ rotation.T, normals @ rotation.T, 0.5,
                             center=rotation @ centre)
    for factor in (1e-3, 250.0):
        scaled = epsilon_quality(positions * factor, normals, 0.5, center=centre * factor)
        assert overlap(base, scaled)
        np.testing.assert_allclose(scaled.torque_scale, base.torque_scale * factor)
    assert overlap(base, moved) and overlap(base, turned)
    for other in (moved, turned):
        np.testing.assert_array_equal(other.force_closure, base.force_closure)


def test_explicit_torque_scale_scales_the_torques():
    """With L given, scaling the grasp changes epsilon (torques grow), unlike the default."""
    positions, normals = CUBE * 2.0, -CUBE
    fixed = epsilon_quality(positions, normals, 0.5, torque_scale=1.0)
    default = epsilon_quality(positions, normals, 0.5)
    assert default.lower <= 1 / np.sqrt(6) <= default.upper
    assert fixed.lower > default.upper


# -- properties on random grasps -------------------------------------------------------------


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_contacts=st.integers(3, 7),
       mu=st.sampled_from([MU_PAPER, 0.3, 0.5, 1.0]), budget=st.sampled_from(["l1", "linf"]))
def test_random_grasps_meet_the_contract(seed, n_contacts, mu, budget):
    rng = np.random.default_rng(seed)
    positions, normals = ellipsoid_grasps(rng, 8, n_contacts, axes=rng.uniform(0.5, 3.0, 3))
    centre = rng.normal(scale=0.3, size=3)
    result = epsilon_quality(positions, normals, mu, center=centre, budget=budget)
    verdict = check_force_closure(positions, normals, mu)
    np.testing.assert_array_equal(result.force_closure, verdict.force_closure)
    assert_bounds_contract(result, 1e-3, positions, normals, mu, budget=budget)
    assert result.converged[verdict.force_closure].all()


def test_linf_budget_lies_between_one_and_n_times_l1():
    """W1 is inside W_inf, which is inside n W1: eps1 <= eps_inf <= n eps1."""
    rng = np.random.default_rng(8)
    positions, normals = ellipsoid_grasps(rng, 30, 4)
    l1 = epsilon_quality(positions, normals, 0.5)
    linf = epsilon_quality(positions, normals, 0.5, budget="linf")
    assert np.all(l1.lower <= linf.upper) and np.all(linf.lower <= 4 * l1.upper)
    for g in np.flatnonzero(linf.force_closure)[:2]:
        inner = pyramid_epsilon(positions[g], normals[g], 0.5, sides=5, budget="linf")
        outer = pyramid_epsilon(positions[g], normals[g], 0.5, sides=5, inscribed=False,
                                budget="linf")
        assert inner <= linf.upper[g] * (1 + HULL_SLACK)
        assert linf.lower[g] <= outer * (1 + HULL_SLACK)


def test_soft_fingers_bracket_their_ball_polytopes():
    rng = np.random.default_rng(9)
    positions, normals = ellipsoid_grasps(rng, 20, 3)
    gamma = 0.3
    soft = epsilon_quality(positions, normals, 0.5, torsional_friction=gamma)
    hard = epsilon_quality(positions, normals, 0.5)
    assert_bounds_contract(soft, 1e-3, positions, normals, 0.5, torsional=gamma)
    # Torsional friction only adds wrenches: soft epsilon >= hard epsilon.
    assert np.all(hard.lower <= soft.upper)
    assert soft.force_closure.sum() > hard.force_closure.sum()
    for g in np.flatnonzero(soft.force_closure)[:3]:
        inner = pyramid_epsilon(positions[g], normals[g], 0.5, sides=64, torsional=gamma)
        outer = pyramid_epsilon(positions[g], normals[g], 0.5, sides=64, inscribed=False,
                                torsional=gamma)
        assert inner <= soft.upper[g] * (1 + HULL_SLACK)
        assert soft.lower[g] <= outer * (1 + HULL_SLACK)


# -- adversarial grasps and the verdicts -----------------------------------------------


def equator_grasp(tilt):
    """Three fingers at 120 degrees on the unit equator, normals tilted down by ``tilt``:
    force closure exactly for mu > tan(tilt) (test_core_minimum_friction)."""
    angle = 2 * np.pi * np.arange(3) / 3
    radial = np.stack([np.cos(angle), np.sin(angle), np.zeros(3)], axis=1)
    normals = -np.cos(tilt) * radial - np.sin(tilt) * np.array([0.0, 0.0, 1.0])
    return radial, normals


@pytest.mark.parametrize("ratio", [0.999, 1.0001, 1.01, 1.2])
def test_near_the_force_closure_threshold(ratio):
    """mu = ratio * tan(tilt): epsilon grows from 0 as mu crosses the threshold."""
    tilt = np.radians(30.0)
    positions, normals = equator_grasp(tilt)
    positions = np.vstack([positions, [[0, 0, -0.5]]])
    normals = np.vstack([normals, [[0, 0, 1.0]]])
    mu = ratio * np.tan(tilt)
    result = epsilon_quality(positions, normals, mu)
    assert_bounds_contract(result, 1e-3, positions, normals, mu)
    verdict = check_force_closure(positions, normals, mu)
    assert result.force_closure == verdict.force_closure
    assert (result.lower > 0) == bool(verdict.force_closure)


def test_adversarial_grasps_agree_with_the_verdicts():
    rng = np.random.default_rng(2)
    cases = adversarial_grasps(rng, 6, 0.5) + adversarial_grasps(rng, 4, 1.0)
    for positions, normals in cases:
        for mu in (0.5, 1.0):
            result = epsilon_quality(positions, normals, mu)
            verdict = check_force_closure(positions, normals, mu)
            assert result.force_closure == verdict.force_closure
            assert_bounds_contract(result, 1e-3, positions, normals, mu)


def test_shared_normals_and_duplicated_contacts():
    rng = np.random.default_rng(4)
    positions = rng.normal(size=(5, 3))
    shared = np.tile([[0.0, 0.0, 1.0]], (5, 1))
    result = epsilon_quality(positions, shared, 0.8)
    assert not result.force_closure and result.lower == 0
    assert result.converged and result.upper <= ZERO_UPPER_TOL * 3.0
    base = epsilon_quality(CUBE, -CUBE, 0.5)
    doubled = epsilon_quality(np.vstack([CUBE, CUBE]), -np.vstack([CUBE, CUBE]), 0.5)
    # Duplicated contacts add no wrenches (L1 budget): the same epsilon.
    assert overlap(base, doubled)


def test_collinear_contacts_get_a_zero_upper_bound():
    line = np.outer(np.linspace(-1, 1, 4), [1.0, 2.0, 0.5])
    normals = np.array([[0, 0, 1.0], [0, 1, 0], [0, 0, -1], [0, -1, 0]])
    result = epsilon_quality(line, normals, 1.0)
    assert not result.force_closure and result.lower == 0
    assert result.upper <= ZERO_UPPER_TOL * 4.0
    assert_bounds_contract(result, 1e-3, line, normals, 1.0)


@pytest.mark.parametrize("size", [1e-9, 1e9])
def test_extreme_scales(size):
    result = epsilon_quality(CUBE * size, -CUBE, 0.5, center=(0, 0, 0))
    assert result.lower <= 1 / np.sqrt(6) <= result.upper
    assert result.torque_scale == pytest.approx(size)


# -- shapes and errors ---------------------------------------------------------------------


def test_single_grasp_gives_scalars_and_batch_gives_arrays():
    one = epsilon_quality(CUBE, -CUBE, 0.5)
    assert one.lower.shape == () and one.direction.shape == (6,)
    many = epsilon_quality(np.stack([CUBE] * 3), -np.stack([CUBE] * 3), 0.5)
    assert many.lower.shape == (3,) and many.direction.shape == (3, 6)
    assert many.center.shape == (3, 3)


@pytest.mark.parametrize("kwargs,message", [
    ({"rtol": 0.0}, "rtol must be in"),
    ({"rtol": 1.0}, "rtol must be in"),
    ({"rtol": MIN_RTOL / 2}, "rtol must be in"),
    ({"budget": "l2"}, "budget must be one of"),
    ({"center": (0.0, 0.0)}, "center must have shape"),
    ({"center": (0.0, np.nan, 0.0)}, "center of grasp 0 is not finite"),
    ({"center": ("a", "b", "c")}, "center must be real numbers"),
    ({"torque_scale": 0.0}, "torque_scale of grasp 0 must be a finite length > 0"),
    ({"torque_scale": -1.0}, "torque_scale of grasp 0 must be a finite length > 0"),
    ({"torque_scale": np.inf}, "torque_scale of grasp 0 must be a finite length > 0"),
    ({"torque_scale": [1.0, 2.0]}, "torque_scale must be a number or have shape"),
])
def test_bad_arguments_are_named(kwargs, message):
    with pytest.raises(ValueError, match=message):
        epsilon_quality(CUBE, -CUBE, 0.5, **kwargs)


def test_bad_contacts_name_grasp_and_contact():
    positions = np.stack([CUBE, CUBE])
    normals = -positions.copy()
    normals[1, 4] = 0.0
    with pytest.raises(ValueError, match="grasp 1, contact 4: normal has zero length"):
        epsilon_quality(positions, normals, 0.5)
    with pytest.raises(ValueError, match="grasp 0, contact 0: friction coefficient must be > 0"):
        epsilon_quality(CUBE, -CUBE, [0.0, 1, 1, 1, 1, 1])
    with pytest.raises(ValueError, match="positions must have shape"):
        epsilon_quality(CUBE[:, :2], -CUBE[:, :2], 0.5)


@pytest.mark.parametrize("name,n_contacts,mu,index", [
    ("ellipsoid", 4, 1.0, 50), ("cylinder", 6, 1.0, 22), ("mug", 8, 0.5, 1)])
def test_grasps_that_once_folded_the_surface_converge(name, n_contacts, mu, index):
    """Random grasps on which a coarser visibility tolerance folded the surface (new facets
    of negative orientation) and stalled the search."""
    from grasp_fc_ros.objects import OBJECT_NAMES, make_object, sample_grasps

    rng = np.random.default_rng([OBJECT_NAMES.index(name), n_contacts])
    positions, normals = sample_grasps(make_object(name), 60, n_contacts, rng)
    for rtol in (1e-3, 1e-6):
        result = epsilon_quality(positions[index], normals[index], mu, rtol=rtol)
        assert result.force_closure and result.converged
        assert_bounds_contract(result, rtol, positions[index], normals[index], mu)


# The README's square grasp (four fingers at +-x, +-y): the search stops on a facet it
# cannot refine at a relative gap of ~2e-4 (STUCK), at every rtol below that. Should the
# search one day converge on it, keep this test with a grasp that still misses rtol.
SQUARE = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]])
CUBE = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])


def test_bounds_that_miss_rtol_warn_naming_how_many_and_the_widest_gap():
    from grasp_fc_ros.core import EpsilonNotConverged

    grasps = np.stack([SQUARE, SQUARE @ random_rotation(np.random.default_rng(3)).T])
    with pytest.warns(EpsilonNotConverged) as caught:
        result = epsilon_quality(grasps, -grasps, mu=0.5, rtol=1e-6)
    assert not result.converged.any() and result.force_closure.all()
    [warning] = caught
    text = str(warning.message)
    assert "2 of 2 grasps did not converge to rtol 1e-06" in text
    worst = int(np.argmax((result.upper - result.lower) / result.upper))
    assert (f"grasp {worst}, {result.lower[worst]:.6g} <= epsilon <= "
            f"{result.upper[worst]:.6g}") in text
    assert warning.filename == __file__  # it points at the caller's line
    # Still certified bounds: they overlap those of the (converged) coarser search.
    coarse = epsilon_quality(grasps, -grasps, mu=0.5, rtol=1e-3)
    assert coarse.converged.all() and overlap(result, coarse)


def test_converged_bounds_do_not_warn():
    import warnings

    from grasp_fc_ros.core import EpsilonNotConverged

    with warnings.catch_warnings():
        warnings.simplefilter("error", EpsilonNotConverged)
        result = epsilon_quality(np.stack([CUBE, CUBE]), -np.stack([CUBE, CUBE]), mu=0.5,
                                 rtol=1e-6)
        assert result.converged.all()
        assert epsilon_quality(SQUARE, -SQUARE, mu=0.5, rtol=1e-3).converged
