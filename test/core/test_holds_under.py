"""holds_under: HOLDS only where every perturbation inside the errors keeps force closure
(random perturbations judged by the exact test and circumscribed pyramids), BREAKS only
with a witness inside the errors that is certified not force closure (its separating
wrench checked by its definition and by verify_certificates), few UNDECIDED."""

import numpy as np
import pytest

from grasp_cases import ellipsoid_grasps
from grasp_fc_ros.core import (
    Holds,
    HoldsUnder,
    check_force_closure,
    holds_under,
    robustness,
    verify_certificates,
)
from reference_pyramids import pyramid_is_force_closure
from reference_robustness import random_moves, random_tilts, separates

CUBE = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]],
                float)
MU = 0.5


def closed_grasps(seed, count, n_contacts):
    positions, normals = ellipsoid_grasps(np.random.default_rng(seed), 4 * count, n_contacts)
    closed = check_force_closure(positions, normals, MU).force_closure
    return positions[closed][:count], normals[closed][:count]


def assert_witnesses(answer, positions, normals, mu, radius=0.0, tilt=0.0, drop=0.0):
    """Every BREAKS row: a grasp inside the errors, not force closure by the exact test,
    separated by its wrench (by definition and by verify_certificates); NaN elsewhere."""
    breaks = np.atleast_1d(answer.status) == Holds.BREAKS
    count = breaks.size
    radius, tilt, drop = (np.broadcast_to(np.asarray(x, float), (count,)) for x in
                          (radius, tilt, drop))
    mu = np.broadcast_to(np.asarray(mu, float), positions.shape[:2])
    wp, wn = answer.witness_positions.reshape(positions.shape), \
        answer.witness_normals.reshape(positions.shape)
    wmu, wrench = answer.witness_mu.reshape(mu.shape), answer.separating_wrench.reshape(-1, 6)
    assert np.isnan(wp[~breaks]).all() and np.isnan(wrench[~breaks]).all()
    for g in np.flatnonzero(breaks):
        moved = np.linalg.norm(wp[g] - positions[g], axis=1)
        assert np.all(moved <= radius[g] * (1 + 1e-9) + 1e-15), (g, moved, radius[g])
        angle = np.arctan2(np.linalg.norm(np.cross(wn[g], normals[g]), axis=1),
                           np.sum(wn[g] * normals[g], axis=1))
        assert np.all(angle <= tilt[g] + 1e-12), (g, angle, tilt[g])
        assert np.all(wmu[g] > 0) and np.all(np.abs(wmu[g] - mu[g]) <= drop[g] + 1e-12)
        assert separates(wp[g], wn[g], wmu[g], wrench[g]), g
    if breaks.any():
        verdict = check_force_closure(wp[breaks], wn[breaks], wmu[breaks])
        assert not verdict.force_closure.any()
        assert verify_certificates(wp[breaks], wn[breaks], wmu[breaks],
                                   separating_wrench=wrench[breaks])[1].all()


def assert_holds_is_sound(answer, positions, normals, mu, radius, tilt, drop, rng, rounds=3):
    """Random perturbations inside the errors of every HOLDS grasp keep force closure."""
    holds = np.atleast_1d(answer.status) == Holds.HOLDS
    if not holds.any():
        return
    p, n = positions[holds], normals[holds]
    r = np.broadcast_to(np.asarray(radius, float), holds.shape)[holds, None]
    t = np.broadcast_to(np.asarray(tilt, float), holds.shape)[holds, None]
    d = np.broadcast_to(np.asarray(drop, float), holds.shape)[holds, None]
    for _ in range(rounds):
        moved = p + random_moves(rng, p.shape, 0.999 * r)
        tilted = random_tilts(rng, n, 0.999 * t * rng.uniform(0.5, 1.0, p.shape[:2]))
        friction = mu - 0.999 * d * rng.uniform(0.5, 1.0, p.shape[:2])
        assert check_force_closure(moved, tilted, friction).force_closure.all()
        for g in range(len(p)):
            assert pyramid_is_force_closure(moved[g], tilted[g], friction[g], 16,
                                            inscribed=False)


def test_without_errors_the_answer_is_the_verdict_with_its_evidence():
    positions, normals = ellipsoid_grasps(np.random.default_rng(1), 30, 4)
    answer = holds_under(positions, normals, MU)
    closed = check_force_closure(positions, normals, MU).force_closure
    status = answer.status
    assert np.all(status[closed] == Holds.HOLDS)
    assert np.all(answer.bound[closed] == "shrunk_cones") and np.all(answer.bound[~closed] == "")
    assert np.all(status[~closed] != Holds.HOLDS)
    assert (status[~closed] == Holds.BREAKS).mean() > 0.9
    assert_witnesses(answer, positions, normals, MU)


@pytest.mark.parametrize("kind", ["normal", "friction"])
def test_normal_and_friction_errors_are_decided_at_half_and_past_the_radius(kind):
    """Below the radius the shrunk cones prove HOLDS; just past it (the bracket) the
    tilt witness or the whole friction drop breaks every grasp."""
    positions, normals = closed_grasps(2, 15, 5)
    radii = robustness(positions, normals, MU)
    radius = radii.normal_angle if kind == "normal" else radii.friction_drop
    argument = "normal_error" if kind == "normal" else "friction_error"
    half = holds_under(positions, normals, MU, **{argument: 0.5 * radius})
    assert np.all(half.status == Holds.HOLDS) and np.all(half.bound == "shrunk_cones")
    past = 1.003 * radius
    broken = holds_under(positions, normals, MU, **{argument: past})
    assert np.all(broken.status == Holds.BREAKS)
    errors = {"tilt": past} if kind == "normal" else {"drop": past}
    assert_witnesses(broken, positions, normals, MU, **errors)
    rng = np.random.default_rng(4)
    assert_holds_is_sound(half, positions, normals, MU, 0.0,
                          0.5 * radius if kind == "normal" else 0.0,
                          0.5 * radius if kind == "friction" else 0.0, rng)


def test_position_errors_hold_below_the_radius_and_mostly_break_at_five_times():
    positions, normals = closed_grasps(3, 12, 4)
    radius = robustness(positions, normals, MU).position_radius
    half = holds_under(positions, normals, MU, position_error=0.5 * radius)
    assert np.all(half.status == Holds.HOLDS)
    assert np.all(half.bound == "shrunk_cones+position_radius")
    assert_holds_is_sound(half, positions, normals, MU, 0.5 * radius, 0.0, 0.0,
                          np.random.default_rng(8))
    far = holds_under(positions, normals, MU, position_error=5 * radius)
    assert np.all(far.status != Holds.HOLDS)
    assert np.mean(far.status == Holds.BREAKS) >= 0.75
    assert_witnesses(far, positions, normals, MU, radius=5 * radius)


def test_mixed_errors_holds_is_sound_and_breaks_are_witnessed():
    positions, normals = closed_grasps(5, 12, 5)
    radii = robustness(positions, normals, MU)
    rng = np.random.default_rng(9)
    for share in (0.3, 0.7):
        errors = dict(position_error=share * radii.position_radius,
                      normal_error=share * radii.normal_angle,
                      friction_error=share * radii.friction_drop)
        answer = holds_under(positions, normals, MU, **errors)
        assert_witnesses(answer, positions, normals, MU, errors["position_error"],
                         errors["normal_error"], errors["friction_error"])
        assert_holds_is_sound(answer, positions, normals, MU, errors["position_error"],
                              errors["normal_error"], errors["friction_error"], rng)
        assert np.all(answer.bound[answer.status == Holds.HOLDS]
                      == "shrunk_cones+position_radius")
    assert np.mean(answer.status == Holds.UNDECIDED) <= 0.5


def test_tilts_past_the_cones_and_friction_that_may_vanish():
    """The cube holds at every friction: tilts of twice its cones' half-angle break it
    (tiny cones turned within the spare tilt); on three fingers on an equator (normal
    wrenches independent) friction that may drop to nothing breaks it (a frictionless
    witness with a little friction)."""
    tilted = holds_under(CUBE, -CUBE, MU, normal_error=2 * np.arctan(MU))
    assert tilted.status == Holds.BREAKS
    assert_witnesses(tilted, CUBE[None], -CUBE[None], MU, tilt=2 * np.arctan(MU))
    angle = 2 * np.pi * np.arange(3) / 3
    radial = np.stack([np.cos(angle), np.sin(angle), np.zeros(3)], axis=1)
    normals = -np.cos(0.2) * radial - np.sin(0.2) * np.array([0.0, 0.0, 1.0])
    bare = holds_under(radial, normals, MU, friction_error=MU)
    assert bare.status == Holds.BREAKS
    assert_witnesses(bare, radial[None], normals[None], MU, drop=MU)


def test_per_grasp_errors_shapes_and_empty_batch():
    positions, normals = closed_grasps(6, 4, 5)
    radii = robustness(positions, normals, MU)
    errors = radii.normal_angle * np.array([0.5, 2.0, 0.5, 2.0])
    answer = holds_under(positions, normals, MU, normal_error=errors)
    assert isinstance(answer, HoldsUnder)
    assert answer.status.dtype == np.int8 and answer.status.shape == (4,)
    np.testing.assert_array_equal(answer.status, [Holds.HOLDS, Holds.BREAKS] * 2)
    assert answer.witness_positions.shape == (4, 5, 3) and answer.witness_mu.shape == (4, 5)
    assert answer.separating_wrench.shape == (4, 6)
    one = holds_under(positions[1], normals[1], MU, normal_error=errors[1])
    assert one.status == Holds.BREAKS and one.witness_positions.shape == (5, 3)
    empty = holds_under(np.zeros((0, 4, 3)), np.ones((0, 4, 3)), MU, position_error=1.0)
    assert empty.status.shape == (0,) and empty.separating_wrench.shape == (0, 6)
    assert [int(h) for h in Holds] == [1, 2, 3]


@pytest.mark.parametrize("kwargs,message", [
    (dict(position_error=-1.0), "position_error of grasp 0 must be finite, >= 0"),
    (dict(normal_error=4.0), r"normal_error of grasp 0 must be finite, >= 0 and <= 3.14159"),
    (dict(friction_error=np.nan), "friction_error of grasp 0"),
    (dict(position_error=np.inf), "position_error of grasp 0 must be finite"),
    (dict(position_error=[0.1, 0.2]), r"position_error must be a number or have shape \(1,\)"),
    (dict(normal_error="a"), "normal_error must be real numbers"),
])
def test_bad_errors_are_refused_by_name(kwargs, message):
    with pytest.raises(ValueError, match=message):
        holds_under(CUBE[None], -CUBE[None], MU, **kwargs)
