"""The torque set of one friction cone, checked against sampled cone forces."""

import numpy as np
import pytest

from grasp_cases import rotate_towards
from grasp_fc_ros.core.filter.torque_sets import (
    TorqueSetKind,
    cone_torque_sets,
    friction_half_angle_sine,
)
from grasp_fc_ros.core.tolerances import FAN_WIDEN_RAD


def sampled_torques(lever_arm, normal, mu, rng, count=20000):
    """Torques r x f of forces sampled in the cone, boundary included: (count, 3)."""
    helper = np.eye(3)[np.abs(normal).argmin()]
    t1 = np.cross(normal, helper)
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(normal, t1)
    angle = rng.uniform(0, 2 * np.pi, count)
    radius = mu * np.sqrt(rng.uniform(0, 1, count))
    radius[: count // 2] = mu                     # half of them on the cone's surface
    forces = normal + radius[:, None] * (np.cos(angle)[:, None] * t1
                                         + np.sin(angle)[:, None] * t2)
    return np.cross(lever_arm, forces)


def one_set(lever_arm, normal, mu):
    sets = cone_torque_sets(np.asarray(lever_arm, float)[:, None],
                            np.asarray(normal, float)[:, None],
                            friction_half_angle_sine(np.array([mu])))
    return (TorqueSetKind(sets.kind[0]), sets.first[:, 0], sets.second[:, 0],
            sets.axis[:, 0])


def angles_in_fan(torques, first, second, axis):
    """Angle of each torque from the fan's centre, and the fan's half-angle."""
    centre = (first + second) / np.linalg.norm(first + second)
    across = np.cross(axis, centre)
    angle = np.arctan2(torques @ across, torques @ centre)
    half = np.arctan2(first @ across, first @ centre)
    return angle, abs(half)


@pytest.mark.parametrize("seed", range(40))
def test_fan_contains_every_sampled_torque_and_is_tight(seed):
    rng = np.random.default_rng(seed)
    mu = rng.uniform(0.05, 1.5)
    normal = rng.normal(size=3)
    normal /= np.linalg.norm(normal)
    theta = np.arctan(mu)
    # Lever arms outside the cone and outside its mirror image, both signs of r . n.
    angle = rng.uniform(theta + 0.05, np.pi - theta - 0.05)
    lever_arm = rotate_towards(normal, angle, rng) * rng.uniform(0.1, 10)
    kind, first, second, axis = one_set(lever_arm, normal, mu)
    assert kind == TorqueSetKind.FAN
    assert np.allclose(axis, lever_arm / np.linalg.norm(lever_arm))
    assert abs(first @ axis) < 1e-12 and abs(second @ axis) < 1e-12

    torques = sampled_torques(lever_arm, normal, mu, rng)
    angle_in_fan, half_angle = angles_in_fan(torques, first, second, axis)
    assert np.all(np.abs(angle_in_fan) <= half_angle + 1e-12)
    # Tight: sampled boundary torques reach the computed boundary (widening aside).
    assert np.abs(angle_in_fan).max() >= half_angle - FAN_WIDEN_RAD - 1e-3


@pytest.mark.parametrize("seed", range(20))
@pytest.mark.parametrize("mirror", [False, True])
def test_line_through_the_cone_gives_the_whole_plane(seed, mirror):
    """r strictly inside the cone, and also -r inside it (the paper's r . n < 0 case)."""
    rng = np.random.default_rng(seed)
    mu = rng.uniform(0.05, 1.5)
    normal = rng.normal(size=3)
    normal /= np.linalg.norm(normal)
    lever_arm = rotate_towards(normal, rng.uniform(0, 0.9) * np.arctan(mu), rng)
    if mirror:
        lever_arm = -lever_arm
    kind, _, _, axis = one_set(lever_arm, normal, mu)
    assert kind == TorqueSetKind.PLANE
    # The sampled torques really do go all the way round the plane.
    torques = sampled_torques(lever_arm, normal, mu, rng)
    in_plane = np.cross(axis, np.cross(torques, axis))
    basis_u = in_plane[np.argmax(np.linalg.norm(in_plane, axis=1))]
    basis_u /= np.linalg.norm(basis_u)
    basis_v = np.cross(axis, basis_u)
    angle = np.sort(np.arctan2(in_plane @ basis_v, in_plane @ basis_u))
    gaps = np.diff(np.concatenate([angle, [angle[0] + 2 * np.pi]]))
    assert gaps.max() < 0.2


def test_lever_arm_on_the_cone_surface_gives_a_plane_not_two_opposite_vectors():
    rng = np.random.default_rng(7)
    normal = np.array([0.0, 0.0, 1.0])
    for mu in (0.1, 0.5, 2.0):
        lever_arm = rotate_towards(normal, np.arctan(mu), rng)
        kind, *_ = one_set(lever_arm, normal, mu)
        assert kind == TorqueSetKind.PLANE


def test_contact_at_the_origin_has_a_null_torque_set():
    kind, first, second, axis = one_set([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], 0.5)
    assert kind == TorqueSetKind.NULL
    assert not first.any() and not second.any() and not axis.any()


@pytest.mark.parametrize("scale", [1e-150, 1e-9, 1.0, 1e9, 1e150])
def test_fan_does_not_depend_on_the_lever_arms_length(scale):
    normal = np.array([0.0, 0.6, 0.8])
    reference = one_set([1.0, -0.3, 0.2], normal, 0.4)
    scaled = one_set(np.array([1.0, -0.3, 0.2]) * scale, normal, 0.4)
    assert reference[0] == scaled[0] == TorqueSetKind.FAN
    for a, b in zip(reference[1:], scaled[1:], strict=True):
        assert np.allclose(a, b, atol=1e-14)
