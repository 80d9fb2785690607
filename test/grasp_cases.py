"""Random and adversarial grasps for the core's tests (test-only helpers)."""

import numpy as np

MU_PAPER = float(np.tan(np.radians(10.0)))


def ellipsoid_grasps(rng, n_grasps, n_contacts, axes=(1.0, 2.0, 3.0)):
    """Random contacts on an ellipsoid with inward normals: (N, n, 3) twice."""
    axes = np.asarray(axes)
    direction = rng.normal(size=(n_grasps, n_contacts, 3))
    direction /= np.linalg.norm(direction, axis=2, keepdims=True)
    positions = direction * axes
    normals = -positions / axes ** 2
    return positions, normals / np.linalg.norm(normals, axis=2, keepdims=True)


def random_rotation(rng):
    """A uniformly random rotation matrix (3, 3)."""
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def rotate_towards(normal, angle, rng):
    """A unit vector at ``angle`` (radians) from the unit ``normal``, random azimuth."""
    helper = rng.normal(size=3)
    tangent = np.cross(normal, helper)
    tangent /= np.linalg.norm(tangent)
    return np.cos(angle) * normal + np.sin(angle) * tangent


def adversarial_grasps(rng, n_contacts=6, mu=MU_PAPER):
    """Grasps built to hit the filter's edge cases, as (positions, normals) lists.

    Covers: a contact whose lever arm from another contact lies exactly on its friction
    cone's surface (half-plane torque set), -r inside the cone, r . n < 0, duplicate
    contacts, collinear and coplanar contacts, and antipodal pairs.
    """
    theta = np.arctan(mu)
    cases = []
    base_p, base_n = ellipsoid_grasps(rng, 1, n_contacts)
    base_p, base_n = base_p[0], base_n[0]
    for angle in (theta, np.pi - theta, 0.5 * theta, np.pi - 0.5 * theta, 0.0, np.pi):
        # Contact 1 sees contact 0 along a ray at `angle` from its normal.
        p, n = base_p.copy(), base_n.copy()
        ray = rotate_towards(n[1], angle, rng)
        p[1] = p[0] + ray * rng.uniform(0.5, 2.0)
        cases.append((p, n))
    p, n = base_p.copy(), base_n.copy()
    p[2], n[2] = p[1], n[1]                                   # duplicate contact
    cases.append((p, n))
    p, n = base_p.copy(), base_n.copy()
    p[2] = p[1]                                               # same point, other normal
    cases.append((p, n))
    line = np.outer(np.linspace(-1, 1, n_contacts), rng.normal(size=3))
    cases.append((line, base_n.copy()))                       # collinear contacts
    planar = base_p.copy()
    planar[:, 2] = 0.0
    cases.append((planar, base_n.copy()))                     # coplanar contacts
    in_plane = base_n.copy()
    in_plane[:, 2] = 0.0
    in_plane[np.linalg.norm(in_plane, axis=1) == 0] = [1.0, 0.0, 0.0]
    cases.append((planar, in_plane))                          # planar grasp, planar normals
    antipodal = np.concatenate([base_p[: n_contacts // 2], -base_p[: n_contacts // 2]])
    cases.append((antipodal, -antipodal))                     # antipodal pairs (sphere-like)
    return cases
