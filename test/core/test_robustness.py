"""The robustness radii: closed-form anchors, soundness against random and searched
perturbations inside each radius (judged by the exact test and by independent checks:
circumscribed pyramids with an LP, a separating wrench recomputed from its definition,
Clarabel on the torque set), tightness, invariances, per-contact friction, input."""

import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from grasp_cases import adversarial_grasps, ellipsoid_grasps, random_rotation
from grasp_fc_ros.core import Holds, check_force_closure, epsilon_quality, holds_under
from grasp_fc_ros.core.model.grasp_input import prepare_grasps
from grasp_fc_ros.core.robustness import RobustnessRadii, robustness
from grasp_fc_ros.core.robustness.break_distance import least_breaking_direction
from grasp_fc_ros.core.robustness.position_radius import INRADIUS_RTOL, torque_inradius
from grasp_fc_ros.core.robustness.shrink import BRACKET_RTOL, tilted_friction
from grasp_fc_ros.core.robustness.witness import tilt_towards, work_vectors
from reference_pyramids import pyramid_is_force_closure
from reference_robustness import (
    random_moves,
    random_tilts,
    separates,
    torque_inradius_reference,
    torque_support,
)

CUBE = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]],
                float)

#: A 16-sided circumscribed pyramid contains the cone: its grasp is force closure
#: whenever the true one is (an independent necessary condition).
OUTER_SIDES = 16


def equator_grasp(tilt):
    """Three fingers at 120 degrees on the unit equator, normals tilted down by ``tilt``:
    force closure exactly for mu > tan(tilt) (test_minimum_friction's anchor)."""
    angle = 2 * np.pi * np.arange(3) / 3
    radial = np.stack([np.cos(angle), np.sin(angle), np.zeros(3)], axis=1)
    normals = -np.cos(tilt) * radial - np.sin(tilt) * np.array([0.0, 0.0, 1.0])
    return radial, normals


def force_closure_grasps(seed, count, n_contacts, mu):
    """Random ellipsoid grasps that are force closure at ``mu`` (up to ``count``)."""
    positions, normals = ellipsoid_grasps(np.random.default_rng(seed), 4 * count, n_contacts)
    closed = check_force_closure(positions, normals, mu).force_closure
    return positions[closed][:count], normals[closed][:count]


def assert_force_closure_kept(positions, normals, mu, where):
    """The exact test says force closure, and the circumscribed pyramids agree."""
    mu = np.broadcast_to(np.asarray(mu, float), positions.shape[:2])
    verdict = check_force_closure(positions, normals, mu)
    lost = np.flatnonzero(~np.atleast_1d(verdict.force_closure))
    assert not lost.size, f"{where}: force closure lost on {lost.tolist()}"
    for g in range(len(positions)):
        assert pyramid_is_force_closure(positions[g], normals[g], mu[g], OUTER_SIDES,
                                        inscribed=False), f"{where}: grasp {g}"


# -- closed-form anchors ------------------------------------------------------------------


@pytest.mark.parametrize("mu", [0.2, 0.5, 1.0])
def test_cube_radii(mu):
    """Six contacts at a cube's faces are force closure at every friction (radius up to
    the whole cone, capped within BRACKET_RTOL); its torque inradius is
    sqrt(2/3) sin(arctan mu), reached for b along a diagonal."""
    radii = robustness(CUBE, -CUBE, mu)
    alpha = np.arctan(mu)
    assert radii.force_closure
    assert alpha * (1 - 2 * BRACKET_RTOL) <= radii.normal_angle < alpha
    assert mu * (1 - 2 * BRACKET_RTOL) <= radii.friction_drop < mu
    exact = np.sqrt(2.0 / 3.0) * np.sin(alpha)
    assert exact * (1 - INRADIUS_RTOL) <= radii.position_radius <= exact


@pytest.mark.parametrize("tilt_deg", [5.0, 20.0, 35.0])
def test_equator_grasp_radii_are_the_friction_margin(tilt_deg):
    """mu* = tan(tilt): the normals may tilt by arctan(mu) - tilt, friction drop by
    mu - tan(tilt), up to the bracket and the exact test's MARGIN_TOL."""
    tilt, mu = np.radians(tilt_deg), 0.8
    positions, normals = equator_grasp(tilt)
    radii = robustness(positions, normals, mu)
    angle, drop = np.arctan(mu) - tilt, mu - np.tan(tilt)
    assert angle * (1 - 3 * BRACKET_RTOL) <= radii.normal_angle <= angle
    assert drop * (1 - 3 * BRACKET_RTOL) <= radii.friction_drop <= drop


def test_grasps_that_are_not_force_closure_get_zero():
    positions, normals = equator_grasp(np.radians(40.0))
    radii = robustness(positions, normals, 0.5)             # needs tan 40 deg = 0.84
    assert not radii.force_closure
    assert radii.normal_angle == radii.position_radius == radii.friction_drop == 0.0
    two = robustness([[1, 0, 0], [-1, 0, 0]], [[-1, 0, 0], [1, 0, 0]], 1.0)
    assert not two.force_closure and two.position_radius == 0.0


# -- soundness and tightness ----------------------------------------------------------------


@pytest.mark.parametrize("n_contacts,mu", [(3, 0.8), (4, 0.5), (6, 0.3)])
def test_tilts_inside_the_normal_angle_keep_force_closure_and_tilts_past_it_break_it(
        n_contacts, mu):
    """Random tilts of 0.999 normal_angle, and the searched ones (towards -v_i of the
    wrench that separates the grasp shrunk just past the radius), keep force closure;
    the searched tilt by that shrink breaks it (a separating wrench, checked by its
    definition)."""
    positions, normals = force_closure_grasps(n_contacts, 12, n_contacts, mu)
    radii = robustness(positions, normals, mu)
    angle = radii.normal_angle
    assert np.all(angle > 0)
    rng = np.random.default_rng(7)
    for _ in range(3):
        tilted = random_tilts(rng, normals, 0.999 * angle[:, None])
        assert_force_closure_kept(positions, tilted, mu, "random tilts")
    past = angle * (1 + 2 * BRACKET_RTOL)
    shrunk = check_force_closure(positions, normals, tilted_friction(
        np.full(positions.shape[:2], mu), past[:, None]), certificates=True)
    wrench = shrunk.separating_wrench
    assert not shrunk.force_closure.any() and not np.isnan(wrench).any()
    work = work_vectors(positions, wrench)
    inside = tilt_towards(normals, work, np.broadcast_to(0.999 * angle[:, None],
                                                         positions.shape[:2]))
    assert_force_closure_kept(positions, inside, mu, "searched tilts")
    beyond = tilt_towards(normals, work, np.broadcast_to(past[:, None], positions.shape[:2]))
    assert not check_force_closure(positions, beyond, mu).force_closure.any()
    for g in range(len(positions)):
        assert separates(positions[g], beyond[g], mu, wrench[g])


def test_friction_drops_inside_the_radius_keep_force_closure():
    positions, normals = force_closure_grasps(11, 12, 5, 0.6)
    radii = robustness(positions, normals, 0.6)
    rng = np.random.default_rng(3)
    drops = rng.uniform(0.5, 1.0, positions.shape[:2]) * radii.friction_drop[:, None]
    drops[::2] = radii.friction_drop[::2, None]                  # all at once, the worst
    assert_force_closure_kept(positions, normals, 0.6 - 0.999 * drops, "friction drops")
    past = 0.6 - radii.friction_drop * (1 + 2 * BRACKET_RTOL)
    assert not check_force_closure(positions, normals, past[:, None]).force_closure.any()


@pytest.mark.parametrize("n_contacts,mu", [(4, 0.5), (6, 0.3)])
def test_moves_inside_the_position_radius_keep_force_closure(n_contacts, mu):
    """Random moves of 0.999 rho (half on the sphere), and the searched ones: no torque
    direction needs less than rho of moves (r*(b) >= rho, the least found over the
    sphere); its moves scaled to 0.999 rho keep force closure."""
    positions, normals = force_closure_grasps(20 + n_contacts, 10, n_contacts, mu)
    radius = robustness(positions, normals, mu).position_radius
    rng = np.random.default_rng(5)
    for _ in range(3):
        moved = positions + random_moves(rng, positions.shape, 0.999 * radius[:, None])
        assert_force_closure_kept(moved, normals, mu, "random moves")
    distance, _ = least_breaking_direction(prepare_grasps(positions, normals, mu))
    assert np.all(distance >= radius * (1 - 1e-7))


def test_position_radius_brackets_the_torque_set_inradius_of_clarabel():
    """lower <= g(b) for every sampled b (soundness) and g(b) <= upper for the search's
    direction, with g from Clarabel directly; the lattice minimum lies within the
    search's accuracy of lower."""
    positions, normals = force_closure_grasps(31, 4, 5, 0.5)
    bounds = torque_inradius(prepare_grasps(positions, normals, 0.5))
    for g in range(len(positions)):
        reference = torque_inradius_reference(positions[g], normals[g], 0.5)
        assert bounds.lower[g] <= reference * (1 + 1e-7)
        assert reference <= bounds.lower[g] * (1 + 2 * INRADIUS_RTOL)
        b = bounds.direction[g, 3:]
        assert torque_support(positions[g], normals[g], 0.5, b) <= bounds.upper[g] * (1 + 1e-7)


# -- invariances, per-contact friction, shapes ------------------------------------------------


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2 ** 31), scale=st.sampled_from([1e-3, 1.0, 250.0]))
def test_radii_are_invariant_under_rigid_motion_and_scale_with_length(seed, scale):
    rng = np.random.default_rng(seed)
    positions, normals = ellipsoid_grasps(rng, 3, 5)
    mu = rng.uniform(0.3, 1.0, (3, 5))
    base = robustness(positions, normals, mu)
    rotation = random_rotation(rng)
    shift = rng.normal(size=3) * 10
    moved = robustness(scale * positions @ rotation.T + shift, normals @ rotation.T, mu)
    np.testing.assert_array_equal(moved.force_closure, base.force_closure)
    # The bisections may land on the other side of a step: one bracket apart at most.
    np.testing.assert_allclose(moved.normal_angle, base.normal_angle,
                               rtol=2 * BRACKET_RTOL, atol=1e-12)
    np.testing.assert_allclose(moved.friction_drop, base.friction_drop,
                               rtol=2 * BRACKET_RTOL, atol=1e-12)
    np.testing.assert_allclose(moved.position_radius, scale * base.position_radius,
                               rtol=2 * INRADIUS_RTOL, atol=1e-300)


def test_per_contact_friction():
    """The weakest contact sets the friction drop when the others have friction to spare;
    the tilt is bounded by the smallest cone; the lone grasp equals the batch."""
    positions, normals = equator_grasp(np.radians(20.0))
    mu = np.array([0.8, 2.0, 2.0])
    radii = robustness(positions, normals, mu)
    assert radii.friction_drop <= 0.8 - np.tan(np.radians(20.0))
    assert radii.normal_angle <= np.arctan(0.8)
    batch = robustness(np.stack([positions, positions]), np.stack([normals, normals]),
                       np.stack([mu, [0.8] * 3]))
    assert batch.friction_drop[0] == radii.friction_drop
    assert batch.friction_drop[1] < batch.friction_drop[0] or np.isclose(
        batch.friction_drop[1], batch.friction_drop[0], rtol=2 * BRACKET_RTOL)


def test_shapes_empty_batch_and_one_grasp():
    empty = robustness(np.zeros((0, 4, 3)), np.ones((0, 4, 3)), 0.5)
    assert isinstance(empty, RobustnessRadii)
    for field in (empty.normal_angle, empty.position_radius, empty.friction_drop,
                  empty.force_closure):
        assert field.shape == (0,)
    one = robustness(CUBE, -CUBE, 0.5)
    assert np.ndim(one.position_radius) == 0 and np.ndim(one.force_closure) == 0


def test_adversarial_grasps_get_sound_radii():
    """Duplicates, collinear and coplanar contacts, antipodal pairs, lever arms on cone
    surfaces: radii are finite, >= 0, 0 where not force closure, and moves inside the
    position radius keep force closure."""
    rng = np.random.default_rng(12)
    cases = adversarial_grasps(rng, 6, 0.7)
    positions = np.array([p for p, _ in cases])
    normals = np.array([n for _, n in cases])
    radii = robustness(positions, normals, 0.7)
    for field in (radii.normal_angle, radii.position_radius, radii.friction_drop):
        assert np.all(np.isfinite(field)) and np.all(field >= 0)
        assert np.all(field[~radii.force_closure] == 0)
    closed = radii.force_closure
    moved = positions[closed] + random_moves(rng, positions[closed].shape,
                                             0.999 * radii.position_radius[closed, None])
    assert_force_closure_kept(moved, normals[closed], 0.7, "adversarial moves")


@pytest.mark.parametrize("kwargs,message", [
    (dict(mu=-0.5), "grasp 0, contact 0: friction coefficient must be > 0"),
    (dict(torsional_friction=0.01), "hard contacts"),
    (dict(normals=np.zeros((6, 3))), "normal has zero length"),
])
def test_bad_input_is_refused_by_name(kwargs, message):
    arguments = dict(positions=CUBE, normals=-CUBE, mu=0.5)
    arguments.update(kwargs)
    positions, normals, mu = (arguments.pop(k) for k in ("positions", "normals", "mu"))
    with pytest.raises(ValueError, match=message):
        robustness(positions, normals, mu, **arguments)


def test_a_contact_whose_cone_shrinks_away_is_left_out():
    """A seventh contact of tiny friction beside the cube's six (mu 1): tilts and drops
    past its cone leave it out, so the radii are those of the cube (arctan 1 and 1, up
    to the bracket), not of the smallest cone; holds_under proves HOLDS past it too."""
    positions = np.vstack([CUBE, [[0.5, 0.5, 1.0]]])
    normals = np.vstack([-CUBE, [[0.0, 0.0, -1.0]]])
    mu = np.array([1.0] * 6 + [0.01])
    radii = robustness(positions, normals, mu)
    assert radii.normal_angle >= np.arctan(1.0) * (1 - 2 * BRACKET_RTOL)
    assert radii.friction_drop >= 1.0 * (1 - 2 * BRACKET_RTOL)
    answer = holds_under(positions, normals, mu, normal_error=0.5, friction_error=0.2)
    assert answer.status == Holds.HOLDS and answer.bound == "shrunk_cones"


def test_rho_is_never_below_the_weaker_epsilon_form():
    """For any centre c and torque scale L, epsilon(c, L) L / sqrt(1 + mu^2) bounds rho
    from below (a unit-normal-force disc point over sqrt(1 + mu^2) is a unit-force
    generator, and h(u) >= epsilon |u| >= epsilon L |b|); the note behind issue 29 found
    rho within 1.00-1.05x of its best L. Certified bounds on both sides."""
    positions, normals = force_closure_grasps(41, 8, 5, 0.5)
    bounds = torque_inradius(prepare_grasps(positions, normals, 0.5))
    centre = positions.mean(axis=1)
    reach = np.linalg.norm(positions - centre[:, None], axis=-1).max(axis=1)
    best = np.zeros(len(positions))
    for factor in (0.25, 1.0, 4.0, 16.0):
        epsilon = epsilon_quality(positions, normals, 0.5, center=centre,
                                  torque_scale=factor * reach)
        weaker = epsilon.lower * factor * reach / np.sqrt(1 + 0.5 ** 2)
        assert np.all(weaker <= bounds.upper)
        best = np.maximum(best, weaker)
    assert np.all(bounds.upper / best < 1.5)


def test_warm_up_compiles_the_search_of_the_position_radius():
    """In a fresh process, after the core's warm_up (the node's start, make setup),
    robustness and epsilon_quality compile no new specialisation of the search: the
    problem is a run-time code of one type for epsilon and the torque inradius."""
    code = (
        "import numpy as np\n"
        "from grasp_fc_ros.core import epsilon_quality, robustness, warm_up\n"
        "from grasp_fc_ros.core.quality import epsilon_kernels as k\n"
        "warm_up()\n"
        "before = len(k.epsilon_batch.signatures)\n"
        "cube = np.vstack([np.eye(3), -np.eye(3)])\n"
        "robustness(cube, -cube, 0.5)\n"
        "epsilon_quality(cube, -cube, 0.5)\n"
        "print(before, len(k.epsilon_batch.signatures))\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    before, after = done.stdout.split()
    assert before == after and int(before) >= 1
