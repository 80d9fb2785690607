"""Independent reference for the exact test (test-only): friction pyramids and an LP.

Each quadratic friction cone is replaced by an m-sided pyramid, either inscribed (inside
the cone: if its grasp is force closure, so is the true one) or circumscribed (around
the cone: if its grasp is not force closure, neither is the true one). A polyhedral
grasp is force closure iff its primitive wrenches W have rank 6 and some strictly
positive combination of them sums to zero, decided here with scipy's LP solver.

Soft-finger contacts (torsional friction gamma): in the scaled coordinates
(f_t / mu, tau / gamma) per unit normal force the elliptic soft cone's cross-section is
the unit ball, so a polytope with vertices on the unit sphere gives an inscribed
polyhedral cone, and the same polytope scaled by one over its inradius a circumscribed
one (:func:`ball_polytope`); each vertex is a primitive wrench (f, p x f + tau n).
"""

from functools import lru_cache

import numpy as np
from scipy.optimize import linprog
from scipy.spatial import ConvexHull


def pyramid_edges(normal, mu, sides, inscribed):
    """Unit edge directions (sides, 3) of a pyramid inscribed in / circumscribing a cone."""
    helper = np.eye(3)[np.abs(normal).argmin()]
    t1 = np.cross(normal, helper)
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(normal, t1)
    radius = mu * (np.cos(np.pi / sides) if inscribed else 1.0 / np.cos(np.pi / sides))
    angle = 2 * np.pi * np.arange(sides) / sides
    edges = normal + radius * (np.cos(angle)[:, None] * t1 + np.sin(angle)[:, None] * t2)
    return edges / np.linalg.norm(edges, axis=1, keepdims=True)


def pyramid_margin(positions, normals, mu, sides=8, inscribed=True):
    """Largest s with W lam = 0, lam >= s, sum(lam) = 1; 0 if W has rank < 6.

    positions, normals: (n, 3); normals unit. Returns s (> 0 iff force closure).
    """
    frictions = np.broadcast_to(np.asarray(mu, float), (len(positions),))
    return _lp_margin(_pyramid_wrench_columns(positions, normals, frictions, sides, inscribed))


def _pyramid_wrench_columns(positions, normals, frictions, sides, inscribed):
    """Primitive wrenches (6, n*sides) of per-contact pyramids, grasp at unit size.

    frictions: (n,) friction coefficient of each contact.
    """
    centred = positions - positions.mean(axis=0)
    centred = centred / np.abs(centred).max()
    columns = [np.concatenate([f, np.cross(p, f)])
               for p, n, mu in zip(centred, normals, frictions, strict=True)
               for f in pyramid_edges(n, mu, sides, inscribed)]
    return np.array(columns).T


def _lp_margin(wrenches):
    """max s with W lam = 0, lam >= s, sum(lam) = 1 for wrenches W (6, k); 0 if W has
    rank < 6 or no such lam exists."""
    if np.linalg.matrix_rank(wrenches, tol=1e-9) < 6:
        return 0.0
    k = wrenches.shape[1]
    # Variables (lam_1..lam_k, s): maximise s.
    cost = np.zeros(k + 1)
    cost[-1] = -1.0
    a_eq = np.vstack([np.hstack([wrenches, np.zeros((6, 1))]),
                      np.hstack([np.ones(k), [0.0]])])
    b_eq = np.concatenate([np.zeros(6), [1.0]])
    a_ub = np.hstack([-np.eye(k), np.ones((k, 1))])                    # s - lam <= 0
    result = _linprog_robust(cost, A_ub=a_ub, b_ub=np.zeros(k), A_eq=a_eq, b_eq=b_eq,
                             bounds=[(0, None)] * k + [(None, None)])
    if result.status == 2:        # infeasible: no equilibrium with sum(lam) = 1 at all
        return 0.0
    return max(result.x[-1], 0.0)


def pyramid_is_force_closure(positions, normals, frictions, sides=8, inscribed=True,
                             tol=1e-9):
    """Polyhedral force closure with per-contact friction: rank 6 and an LP margin > tol
    (the LP of :func:`pyramid_margin`)."""
    wrenches = _pyramid_wrench_columns(positions, normals, np.asarray(frictions, float),
                                       sides, inscribed)
    return _lp_margin(wrenches) > tol


def _linprog_robust(*args, **kwargs):
    """linprog with HiGHS; its dual simplex, then its interior point, if the default
    ends with an unknown status (seen on near-degenerate pyramids). Raises if all fail."""
    for method in ("highs", "highs-ds", "highs-ipm"):
        result = linprog(*args, method=method, **kwargs)
        if result.status in (0, 2):
            return result
    raise AssertionError(result.message)


def pyramid_minimum_friction(positions, normals, ratios=1.0, sides=8, inscribed=True,
                             high=1e2, steps=36):
    """Least friction mu (contacts mu * ratios_i) at which the pyramid grasp is FC.

    Bisection on :func:`pyramid_is_force_closure`, geometric while the bracket spans
    orders of magnitude. Returns (low, high) with not FC at low (or low = 0) and FC at
    high; (inf, inf) if not FC at ``high``. Inscribed pyramids give an upper bound on
    the true mu*, circumscribed ones a lower bound.
    """
    ratios = np.broadcast_to(np.asarray(ratios, float), (len(positions),))
    def fc(mu):
        return pyramid_is_force_closure(positions, normals, mu * ratios, sides, inscribed)
    return _bisect_friction(fc, high, steps)


def pyramid_min_max_force(positions, normals, mu, wrench, sides=8, inscribed=True,
                          max_normal_force=None):
    """Least largest normal force of pyramid forces holding ``wrench`` (LP), or inf.

    Torque about the origin of ``positions`` (not normalised: an independent frame).
    f_i = sum_j lam_ij e_ij with unit edges e_ij; minimise s subject to
    sum_i (f_i, p_i x f_i) + wrench = 0, n_i . f_i <= s, n_i . f_i <= limit_i, lam >= 0.
    """
    frictions = np.broadcast_to(np.asarray(mu, float), (len(positions),))
    edges = [pyramid_edges(n, m, sides, inscribed) for n, m in zip(normals, frictions, strict=True)]
    return _min_max_force_lp(positions, normals, edges, [np.zeros(len(e)) for e in edges],
                             wrench, max_normal_force)


def _min_max_force_lp(positions, normals, edges, twists, wrench, max_normal_force=None):
    """The LP of the pyramid s*: contact i's wrench is sum_j lam_ij (e_ij, p_i x e_ij +
    tau_ij n_i) over its ``edges[i]`` (k_i, 3) and ``twists[i]`` (k_i,), lam >= 0;
    minimise s subject to equilibrium with ``wrench``, n_i . f_i <= s and the limits."""
    n_contacts = len(positions)
    columns, normal_parts, owner = [], [], []
    for i, (p, n) in enumerate(zip(positions, normals, strict=True)):
        for f, tau in zip(edges[i], twists[i], strict=True):
            columns.append(np.concatenate([f, np.cross(p, f) + tau * n]))
            normal_parts.append(f @ n)
            owner.append(i)
    wrenches, normal_parts, owner = np.array(columns).T, np.array(normal_parts), np.array(owner)
    k = wrenches.shape[1]
    # Variables (lam_1..lam_k, s): minimise s.
    cost = np.zeros(k + 1)
    cost[-1] = 1.0
    per_contact = np.zeros((n_contacts, k))
    per_contact[owner, np.arange(k)] = normal_parts
    a_ub = [np.hstack([per_contact, -np.ones((n_contacts, 1))])]
    b_ub = [np.zeros(n_contacts)]
    if max_normal_force is not None:
        limits = np.broadcast_to(np.asarray(max_normal_force, float), (n_contacts,))
        finite = np.isfinite(limits)
        a_ub.append(np.hstack([per_contact[finite], np.zeros((finite.sum(), 1))]))
        b_ub.append(limits[finite])
    result = _linprog_robust(cost, A_ub=np.vstack(a_ub), b_ub=np.concatenate(b_ub),
                             A_eq=np.hstack([wrenches, np.zeros((6, 1))]),
                             b_eq=-np.asarray(wrench, float), bounds=[(0, None)] * (k + 1))
    if result.status == 2:
        return np.inf
    return result.x[-1]


@lru_cache(maxsize=8)
def ball_polytope(points=64, inscribed=True):
    """Vertices (points, 3) of a polytope inside (on the unit sphere, a Fibonacci
    lattice) or around (the same divided by its inradius) the unit ball."""
    k = np.arange(points) + 0.5
    z = 1.0 - 2.0 * k / points
    azimuth = np.pi * (1.0 + 5.0 ** 0.5) * k
    radius = np.sqrt(1.0 - z * z)
    vertices = np.stack([radius * np.cos(azimuth), radius * np.sin(azimuth), z], axis=1)
    if inscribed:
        return vertices
    inradius = -ConvexHull(vertices).equations[:, -1].max()     # facets n.x + d <= 0
    return vertices / inradius


def _soft_wrench_columns(positions, normals, frictions, torsional, points, inscribed):
    """Primitive wrenches (6, k) of per-contact polyhedral soft cones, grasp at unit size
    (gamma scaled along). A hard contact (gamma = 0) gets its pyramid of ``points`` sides."""
    centred = positions - positions.mean(axis=0)
    scale = np.abs(centred).max()
    centred = centred / scale
    columns = []
    for p, n, mu, gamma in zip(centred, normals, frictions, torsional / scale, strict=True):
        if gamma == 0:
            edges, twists = pyramid_edges(n, mu, points, inscribed), np.zeros(points)
        else:
            helper = np.eye(3)[np.abs(n).argmin()]
            t1 = np.cross(n, helper)
            t1 /= np.linalg.norm(t1)
            t2 = np.cross(n, t1)
            ball = ball_polytope(points, inscribed)
            edges = n + mu * (ball[:, :1] * t1 + ball[:, 1:2] * t2)
            twists = gamma * ball[:, 2]
        columns += [np.concatenate([f, np.cross(p, f) + tau * n])
                    for f, tau in zip(edges, twists, strict=True)]
    return np.array(columns).T


def soft_pyramid_is_force_closure(positions, normals, frictions, torsional, points=64,
                                  inscribed=True, tol=1e-9):
    """Polyhedral force closure of soft contacts (hard where gamma = 0): rank 6 and an
    LP margin > tol. Inscribed: FC implies the true grasp is FC; circumscribed: not FC
    implies the true grasp is not FC."""
    n = len(positions)
    wrenches = _soft_wrench_columns(positions, normals,
                                    np.broadcast_to(np.asarray(frictions, float), (n,)),
                                    np.broadcast_to(np.asarray(torsional, float), (n,)),
                                    points, inscribed)
    return _lp_margin(wrenches) > tol


def soft_pyramid_min_max_force(positions, normals, mu, torsional, wrench, points=64,
                               inscribed=True):
    """Least largest normal force of polyhedral soft-cone contact wrenches holding
    ``wrench`` (LP), or inf. Torque about the origin of ``positions`` (no normalising).

    Each contact's wrench is sum_j lam_ij (e_ij, p_i x e_ij + tau_ij n_i) over the
    vertices of :func:`ball_polytope` (pyramid edges where gamma = 0), lam >= 0;
    minimise s subject to equilibrium and n_i . f_i <= s. Inscribed cones give an upper
    bound on the true s*, circumscribed ones a lower bound.
    """
    n_contacts = len(positions)
    frictions = np.broadcast_to(np.asarray(mu, float), (n_contacts,))
    gammas = np.broadcast_to(np.asarray(torsional, float), (n_contacts,))
    edges, twists = [], []
    for n, m, gamma in zip(normals, frictions, gammas, strict=True):
        if gamma == 0:
            edges.append(pyramid_edges(n, m, points, inscribed))
            twists.append(np.zeros(points))
            continue
        helper = np.eye(3)[np.abs(n).argmin()]
        t1 = np.cross(n, helper)
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(n, t1)
        ball = ball_polytope(points, inscribed)
        edges.append(n + m * (ball[:, :1] * t1 + ball[:, 1:2] * t2))
        twists.append(gamma * ball[:, 2])
    return _min_max_force_lp(positions, normals, edges, twists, wrench)


def soft_pyramid_minimum_friction(positions, normals, torsional, points=32, inscribed=True,
                                  high=1e2, steps=30):
    """Least friction at which polyhedral soft cones make the grasp FC: (low, high) as
    :func:`pyramid_minimum_friction` (inscribed: an upper bound on the true mu*,
    circumscribed: a lower bound); gamma stays fixed."""
    def fc(mu):
        return soft_pyramid_is_force_closure(positions, normals, mu, torsional, points,
                                             inscribed)
    return _bisect_friction(fc, high, steps)


def _bisect_friction(fc, high, steps):
    """(low, high): not FC at low (or low = 0), FC at high, after ``steps`` bisections of
    the predicate ``fc(mu)``, geometric while the bracket spans orders of magnitude;
    (inf, inf) if not FC at ``high``."""
    if not fc(high):
        return np.inf, np.inf
    low = 0.0
    for _ in range(steps):
        middle = np.sqrt(max(low, 1e-9) * high) if high > 4 * max(low, 1e-9) else 0.5 * (low + high)
        if fc(middle):
            high = middle
        else:
            low = middle
    return low, high
