"""Independent reference for the Ferrari-Canny epsilon (test-only): pyramids and Qhull.

Each circular friction cone (per unit normal force: a disc of radius mu about the
normal) is replaced by a polygon of ``sides`` vertices, either inscribed (vertices on
the circle: exact points of the cone, so the pyramid's wrench space lies inside W and
its epsilon is a lower bound) or circumscribed (edges tangent to the circle, vertices at
radius mu / cos(pi / sides): its wrench space contains W, so its epsilon is an upper
bound). The epsilon of a polytope is the least facet offset of the convex hull of its
points and the origin (scipy's Qhull), 0 when the origin is not strictly inside.

Soft fingers use the unit-ball polytopes of :mod:`reference_pyramids` in the scaled
coordinates (t / mu, tau / gamma) of the soft cone's cross-section. The L-infinity
budget's wrench space is the Minkowski sum of the per-contact hulls (with the origin):
its points are all sums of one point (or the origin) per contact.

The support function is written out here from the definition, without the core's
wrench rows, for recomputing upper = h(direction).
"""

import itertools

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from reference_pyramids import ball_polytope


def frame(positions, center, torque_scale=None):
    """Lever arms (p_i - c) / L (n, 3) and L of one grasp; L defaults to max |p_i - c|."""
    lever = np.asarray(positions, float) - np.asarray(center, float)
    scale = np.linalg.norm(lever, axis=1).max() if torque_scale is None else torque_scale
    return lever / scale, scale


def support_value(positions, normals, mu, direction, center=(0.0, 0.0, 0.0),
                  torque_scale=None, torsional=None, budget="l1"):
    """h(u) of one grasp for the unit wrench u = direction / |direction| (force,
    torque / L about c), from the definition."""
    lever, scale = frame(positions, center, torque_scale)
    normals = np.asarray(normals, float)
    normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    u = np.asarray(direction, float) / np.linalg.norm(direction)
    mu = np.broadcast_to(np.asarray(mu, float), (len(normals),))
    work = u[:3] + np.cross(u[3:], lever)                          # a_i
    along = np.sum(work * normals, axis=1)
    across = np.linalg.norm(work - along[:, None] * normals, axis=1)
    if torsional is None:
        each = along + mu * across
    else:
        gamma = np.broadcast_to(np.asarray(torsional, float), (len(normals),))
        twist = gamma * (normals @ u[3:]) / scale
        each = along + np.hypot(mu * across, twist)
    positive = np.maximum(each, 0.0)
    return positive.sum() if budget == "linf" else positive.max()


def _tangents(normal):
    helper = np.eye(3)[np.abs(normal).argmin()]
    first = np.cross(normal, helper)
    first /= np.linalg.norm(first)
    return first, np.cross(normal, first)


def contact_points(positions, normals, mu, center=(0.0, 0.0, 0.0), torque_scale=None,
                   sides=16, inscribed=True, torsional=None):
    """Per contact, the wrenches (sides, 6) of its polygon (or soft ball polytope) with
    unit normal force, in the frame (c, L)."""
    lever, scale = frame(positions, center, torque_scale)
    normals = np.asarray(normals, float)
    normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    mu = np.broadcast_to(np.asarray(mu, float), (len(normals),))
    gamma = (np.zeros(len(normals)) if torsional is None
             else np.broadcast_to(np.asarray(torsional, float), (len(normals),)))
    radius = 1.0 if inscribed else 1.0 / np.cos(np.pi / sides)
    angle = 2 * np.pi * np.arange(sides) / sides
    out = []
    for r, n, m, g in zip(lever, normals, mu, gamma, strict=True):
        t1, t2 = _tangents(n)
        if g > 0:
            ball = ball_polytope(sides, inscribed)
            forces = n + m * (ball[:, :1] * t1 + ball[:, 1:2] * t2)
            torques = np.cross(r, forces) + (g * ball[:, 2:3] / scale) * n
        else:
            forces = n + m * radius * (np.cos(angle)[:, None] * t1
                                       + np.sin(angle)[:, None] * t2)
            torques = np.cross(r, forces)
        out.append(np.concatenate([forces, torques], axis=1))
    return out


def hull_epsilon(points):
    """Least facet offset of conv(points and the origin) (k, 6); 0 if the origin is not
    strictly inside (or the points span less than 6 dimensions)."""
    cloud = np.vstack([np.zeros((1, 6)), points])
    try:
        hull = ConvexHull(cloud)
    except QhullError:
        return 0.0
    return max(0.0, float(-hull.equations[:, -1].max()))


def pyramid_epsilon(positions, normals, mu, center=(0.0, 0.0, 0.0), torque_scale=None,
                    sides=16, inscribed=True, torsional=None, budget="l1"):
    """epsilon of the inscribed (a lower bound) or circumscribed (an upper bound)
    polyhedral grasp."""
    per_contact = contact_points(positions, normals, mu, center, torque_scale, sides,
                                 inscribed, torsional)
    if budget == "l1":
        return hull_epsilon(np.vstack(per_contact))
    with_origin = [np.vstack([np.zeros((1, 6)), p]) for p in per_contact]
    sums = [np.sum(choice, axis=0) for choice in itertools.product(*with_origin)]
    return hull_epsilon(np.array(sums))


def pyramid_q1(positions, normals, mu, center, torque_scale, sides=8):
    """The dataset tools' Q1 (DexGraspBench q1.py, BODex chq1.py): ``sides`` edges of unit
    normal force at radius mu (inscribed), Qhull of their wrenches and the origin, least
    facet offset."""
    return pyramid_epsilon(positions, normals, mu, center, torque_scale, sides, True)
