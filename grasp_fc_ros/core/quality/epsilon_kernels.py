"""Compiled kernels of :mod:`.epsilon`: an expanding polytope inside the grasp wrench
space W, certified facet by facet (numba).

Each grasp arrives as per-contact wrench rows in the torque-scaled frame of
:mod:`.epsilon`: ``normal_rows[i]`` = w_i(n_i), the wrench of the unit normal force, and
``tangent_rows[i]`` = (w_i(t1_i), w_i(t2_i), twist_i) with t1, t2 an orthonormal
tangent basis and twist_i = (0, gamma_i / (mu_i L) n_i) for a soft finger (zero for a
hard one). The work of contact i on a unit direction u is then

    a_n = <normal_rows[i], u>,  z = tangent_rows[i] u,  h_i(u) = a_n + mu_i |z|,

and its maximiser w_i(n_i) + mu_i sum_k (z_k / |z|) tangent_rows[i, k] is an exact
point of the contact's wrench disc (its centre where z = 0). W's support function is
h(u) = max(0, max_i h_i(u)) (budget L1: W = conv({0} and the discs)) or
sum_i max(0, h_i(u)) (budget L-infinity: W = the Minkowski sum of conv({0}, disc_i)).

The expanding polytope algorithm (EPA, as in collision detection) keeps a closed,
coherently oriented surface of 5-simplices whose vertices are such support points, and
replaces the facet nearest the origin by the cone from the support point in that
facet's normal direction, until that facet's offset reaches (1 - rtol) of the least
support value seen. Nothing in the result rests on the surface being a convex hull:

* upper: epsilon <= h(u) for every unit u, so the least support value queried is an
  upper bound, certified by its direction;
* lower: every facet's 6 x 6 determinant [v_1; v_2 - v_1; ...; v_6 - v_1] (rows scaled
  to unit length) is checked positive beyond its rounding bound. A closed
  pseudomanifold whose facets all project onto the sphere with positive orientation
  covers every direction (its degree is constant and at least one), so every ray from
  the origin meets some facet simplex inside W, no nearer than that facet's certified
  offset: min_j <m, v_j> / |m| for the facet's computed normal m, lowered by the dot
  products' rounding and by ``SUPPORT_ROUNDING_ULPS`` (how far a computed support point
  may lie from the exact one).

The surface starts as the simplex of support points in 7 fixed directions (those of a
regular simplex; 19, then all the seeds given, where these span too little), built
around an interior point of its own until the origin lies strictly inside every facet,
and only then switches to facets oriented about the origin.

The same search bounds the torque inradius of the position radius
(:mod:`grasp_fc_ros.core.robustness.position_radius`, ``problem=TORQUE_INRADIUS``):
W is then the hull of the origin and every contact's wrenches of forces of length at
most 1 in its cone, and the bounded quantity is min over u of h(u) / |u_t|, the radius
of the largest ball about the origin of the torque space {(0, tau)} inside W. A ray from the origin
in that space, (0, s tau) with |tau| = 1, meets a facet of unit normal m and certified
offset d no nearer than s = d / |m_t|: that facet's key, which the search refines
instead of d, and the least key is the lower bound. A convex hull that holds a ball of
radius r in that space has every key >= r (as every offset of a hull around a ball),
so keys, like offsets, only grow.
"""

from __future__ import annotations

from math import frexp, ldexp, sqrt
from typing import TypeAlias

import numpy as np

from .._kernels.jit import jit

_EPS = float(np.finfo(np.float64).eps)

#: A facet's orientation counts as certified only if the determinant of its row-scaled
#: 6 x 6 matrix exceeds this many times its rounding bound. Gaussian elimination with
#: partial pivoting returns the exact factors of a matrix within gamma_18 |L| |U| of it
#: (|L| <= 1); with the largest |U| entry g, each unit row moves by at most
#: kappa = gamma_18 6 sqrt(6) g, plus 3 ulps for forming and scaling the row, so the
#: determinant moves by at most (1 + kappa)^6 - 1 (Hadamard's inequality on each mixed
#: term). A factor of 4 covers the rounding of that bound and of the pivots' product.
DETERMINANT_SAFETY = 4.0

#: A computed support point (and a computed support value) may differ from the exact one
#: by this many ulps of the grasp's wrench scale (the largest |w_i(n_i)| + mu_i sum_k
#: |tangent_rows[i, k]|, summed over the contacts for the L-infinity budget): the normal
#: and tangent basis, the lever arm, the cross products, the 3-vector z and its
#: normalisation each err by a few ulps of the rows they make, ~30 in all.
SUPPORT_ROUNDING_ULPS = 64.0

#: A point is on the far side of a facet (the facet is visible from it) only if it lies
#: beyond the facet's plane by more than this fraction of the wrench scale, and by more
#: than ``VISIBLE_FRACTION`` of how far it lies beyond the facet it was queried for (a
#: retry after a refused insertion uses ``VISIBLE_RETRY`` of it). A facet barely
#: visible would be replaced by slivers whose orientation the determinant cannot
#: certify; one left in place makes the surface slightly non-convex there, which the
#: certificate does not need, but later insertions do: larger fractions left folds
#: that stalled the search (tuned: docs/epsilon.md#robustness).
VISIBLE_TOL = 1e-12
VISIBLE_FRACTION = 1e-6
VISIBLE_RETRY = 1e-3

#: The surface is switched to facets about the origin once every facet lies at least
#: this fraction of the wrench scale beyond the origin; nearer, the origin-based plane
#: of a facet would be ill-conditioned.
CONTAINMENT_TOL = 1e-10

#: The first surface is the simplex of the support points in this many seed directions;
#: where they span less than six dimensions, the hull of the first SEED_FALLBACK (the
#: simplex and +-each axis), then of all the seeds given (more only for the position
#: radius: :mod:`grasp_fc_ros.core.robustness.position_radius`).
SEED_SIMPLEX = 7
SEED_FALLBACK = 19

#: Status codes of a grasp.
CONVERGED, BUDGET, STUCK, NOT_CONTAINED, DEGENERATE = 0, 1, 2, 3, 4

#: What a search bounds (the ``problem`` argument): epsilon with the L1 or the
#: L-infinity budget (disc generators, the facets' offsets), or the torque inradius of
#: :mod:`grasp_fc_ros.core.robustness.position_radius` (unit-force generators; facets
#: keyed by their distance from the origin along the torque space).
EPSILON_L1, EPSILON_LINF, TORQUE_INRADIUS = 0, 1, 2

#: Room of the per-insertion scratch: facets seen by one new point, ridges of the
#: horizon. An insertion needing more is refused (the facet is marked stuck).
_MAX_VISIBLE = 4096
_MAX_HORIZON = 4096

#: Facets an insertion may count as visible beyond those it sees, to avoid slivers.
_MAX_FORCED = 8

#: Bits per point index in the sorted key of a new facet's sub-ridge (4 indices).
_KEY_BITS = 15

#: The arrays of one search, as :func:`workspace` makes them (13 arrays).
Workspace: TypeAlias = tuple[np.ndarray, ...]

#: A double-double value (hi, lo), |lo| <= ulp(hi) / 2.
DoubleDouble: TypeAlias = tuple[float, float]


@jit
def _contact_work(normal_rows: np.ndarray, tangent_rows: np.ndarray, mu: np.ndarray, i: int,
                  u: np.ndarray, z: np.ndarray, problem: int) -> tuple[float, float, float]:
    """h_i(u) of contact i; z (3,) <- tangent_rows[i] u. Returns (h_i, |z|, a_n).

    Unit-force generators (``TORQUE_INRADIUS``): the largest work of a force of length
    at most 1 in the cone, |v| where the work vector v = (a_n, z) lies in the cone
    (|z| <= mu_i a_n), else its disc value scaled by cos(atan mu_i) (a rim force)."""
    a_n = 0.0
    for k in range(3):
        z[k] = 0.0
    for c in range(6):
        a_n += normal_rows[i, c] * u[c]
        for k in range(3):
            z[k] += tangent_rows[i, k, c] * u[c]
    size = sqrt(z[0] * z[0] + z[1] * z[1] + z[2] * z[2])
    if problem == TORQUE_INRADIUS:
        if size <= mu[i] * a_n:
            return sqrt(a_n * a_n + size * size), size, a_n
        return (a_n + mu[i] * size) / sqrt(1.0 + mu[i] * mu[i]), size, a_n
    return a_n + mu[i] * size, size, a_n


@jit
def _add_disc_point(normal_rows: np.ndarray, tangent_rows: np.ndarray, mu: np.ndarray, i: int,
                    z: np.ndarray, size: float, a_n: float, problem: int,
                    point: np.ndarray) -> None:
    """point += contact i's support point for the normal work a_n and the tangential
    work z (3,) of length size: a point of its disc (rows w_i(n_i + t), |t| <= mu_i),
    or for ``TORQUE_INRADIUS`` of its unit forces (w_i(v / |v|) inside the cone, the
    disc point over sqrt(1 + mu_i^2) on its rim)."""
    base, scale = 1.0, mu[i] / size if size > 0.0 else 0.0
    if problem == TORQUE_INRADIUS:
        if size <= mu[i] * a_n:
            base = 1.0 / sqrt(a_n * a_n + size * size)
            scale = base
            base *= a_n
        else:
            base = 1.0 / sqrt(1.0 + mu[i] * mu[i])
            scale *= base
    for c in range(6):
        point[c] += base * normal_rows[i, c] + scale * (z[0] * tangent_rows[i, 0, c]
                                                        + z[1] * tangent_rows[i, 1, c]
                                                        + z[2] * tangent_rows[i, 2, c])


@jit
def support(normal_rows: np.ndarray, tangent_rows: np.ndarray, mu: np.ndarray, problem: int,
            u: np.ndarray, point: np.ndarray) -> float:
    """Support value h(u) of W and a maximiser, written to ``point`` (6,).

    L1 (and ``TORQUE_INRADIUS``): the best contact's point, or the origin where no
    contact does positive work. L-infinity: the sum of the points of the contacts doing
    positive work.
    """
    z = np.empty(3)
    for c in range(6):
        point[c] = 0.0
    if problem == EPSILON_LINF:
        total = 0.0
        for i in range(normal_rows.shape[0]):
            work, size, a_n = _contact_work(normal_rows, tangent_rows, mu, i, u, z, problem)
            if work > 0.0:
                total += work
                _add_disc_point(normal_rows, tangent_rows, mu, i, z, size, a_n, problem, point)
        return total
    best, best_i = 0.0, -1
    for i in range(normal_rows.shape[0]):
        work, size, a_n = _contact_work(normal_rows, tangent_rows, mu, i, u, z, problem)
        if work > best:
            best, best_i = work, i
    if best_i >= 0:
        _, size, a_n = _contact_work(normal_rows, tangent_rows, mu, best_i, u, z, problem)
        _add_disc_point(normal_rows, tangent_rows, mu, best_i, z, size, a_n, problem, point)
    return best


@jit
def _facet_plane(points: np.ndarray, vertices: np.ndarray, reference: np.ndarray,
                 matrix: np.ndarray, normal: np.ndarray) -> float:
    """The plane of a facet: ``normal`` (6,) <- m with <m, v_1 - ref> = 1 and
    <m, v_k - v_1> = 0 (so the plane is {x: <m, x - ref> = 1}, facing away from ref).

    Returns the determinant of the row-scaled matrix [v_1 - ref; v_k - v_1] in the
    facet's vertex order less its rounding bound times ``DETERMINANT_SAFETY`` (so > 0
    certifies the orientation), or -inf where the matrix is singular. ``matrix`` is
    (6, 7) scratch.
    """
    first = vertices[0]
    for c in range(6):
        matrix[0, c] = points[first, c] - reference[c]
    for k in range(1, 6):
        for c in range(6):
            matrix[k, c] = points[vertices[k], c] - points[first, c]
    for k in range(6):
        norm = 0.0
        for c in range(6):
            norm += matrix[k, c] * matrix[k, c]
        norm = sqrt(norm)
        if norm == 0.0:
            return -np.inf
        for c in range(6):
            matrix[k, c] /= norm
        matrix[k, 6] = 1.0 / norm if k == 0 else 0.0
    determinant, growth = 1.0, 0.0
    for col in range(6):
        pivot, size = col, abs(matrix[col, col])
        for r in range(col + 1, 6):
            if abs(matrix[r, col]) > size:
                pivot, size = r, abs(matrix[r, col])
        if size == 0.0:
            return -np.inf
        if pivot != col:
            determinant = -determinant
            for c in range(col, 7):
                matrix[col, c], matrix[pivot, c] = matrix[pivot, c], matrix[col, c]
        determinant *= matrix[col, col]
        for c in range(col, 6):
            growth = max(growth, abs(matrix[col, c]))
        for r in range(col + 1, 6):
            factor = matrix[r, col] / matrix[col, col]
            for c in range(col + 1, 7):
                matrix[r, c] -= factor * matrix[col, c]
    for col in range(5, -1, -1):
        value = matrix[col, 6]
        for c in range(col + 1, 6):
            value -= matrix[col, c] * normal[c]
        normal[col] = value / matrix[col, col]
    kappa = 18.0 * _EPS / (1.0 - 18.0 * _EPS) * 6.0 * sqrt(6.0) * growth + 3.0 * _EPS
    return determinant - DETERMINANT_SAFETY * _determinant_drift(kappa)


@jit
def _certified_offset(points: np.ndarray, vertices: np.ndarray, normal: np.ndarray,
                      allowance: float) -> float:
    """A lower bound, valid despite rounding, on |x| over the facet's simplex:
    min_j <m, v_j> / |m| less the dot products' error and ``allowance``."""
    least = np.inf
    for k in range(6):
        dot, size = 0.0, 0.0
        for c in range(6):
            dot += normal[c] * points[vertices[k], c]
            size += abs(normal[c] * points[vertices[k], c])
        least = min(least, dot - 8.0 * _EPS * size)
    norm = 0.0
    for c in range(6):
        norm += normal[c] * normal[c]
    norm = sqrt(norm)
    if not norm > 0.0 or not least > 0.0:
        return -np.inf
    return least / norm * (1.0 - 8.0 * _EPS) - allowance


@jit
def _set_facet(points: np.ndarray, facet: int, reference: np.ndarray, origin_based: bool,
               allowance: float, problem: int, vertices: np.ndarray, normals: np.ndarray,
               offsets: np.ndarray, certified: np.ndarray, matrix: np.ndarray,
               normal: np.ndarray) -> bool:
    """Compute facet ``facet``'s plane about ``reference``; False if its orientation
    is not certified (a fold or a sliver). About the origin, ``certified`` gets the
    facet's key (:func:`_facet_key`)."""
    if not (_facet_plane(points, vertices[facet], reference, matrix, normal) > 0.0
            or _orientation_dd(points, vertices[facet], reference)):
        return False
    norm = 0.0
    for c in range(6):
        norm += normal[c] * normal[c]
    norm = sqrt(norm)
    shift = 0.0
    for c in range(6):
        normals[facet, c] = normal[c] / norm
        shift += normal[c] * reference[c]
    offsets[facet] = (1.0 + shift) / norm
    certified[facet] = (_facet_key(normals[facet], problem,
                                   _certified_offset(points, vertices[facet], normal,
                                                     allowance))
                        if origin_based else -np.inf)
    return True


@jit
def _facet_key(unit_normal: np.ndarray, problem: int, offset: float) -> float:
    """What a facet with certified ``offset`` and unit normal m proves: for epsilon the
    offset itself; for ``TORQUE_INRADIUS`` the offset over |m_t| (rounded up), the
    distance from the origin to the facet's plane along the torque space (inf for a
    facet parallel to it)."""
    if problem != TORQUE_INRADIUS or not offset > 0.0:
        return offset
    torque = sqrt(unit_normal[3] * unit_normal[3] + unit_normal[4] * unit_normal[4]
                  + unit_normal[5] * unit_normal[5]) * (1.0 + 8.0 * _EPS)
    return offset / torque * (1.0 - 2.0 * _EPS) if torque > 0.0 else np.inf


@jit
def _insert(points: np.ndarray, q: int, start: int, reference: np.ndarray,
            origin_based: bool, allowance: float, problem: int, tol: float, floor: float,
            vertices: np.ndarray, neighbours: np.ndarray, normals: np.ndarray,
            offsets: np.ndarray, certified: np.ndarray, alive: np.ndarray,
            stuck: np.ndarray, marks: np.ndarray, stamp: int, n_facets: int,
            scratch_int: np.ndarray, scratch_new: np.ndarray, matrix: np.ndarray,
            normal: np.ndarray) -> int:
    """Replace the facets visible from point ``q`` (reached from facet ``start``) by the
    cone from q over their horizon. Returns the new facet count, or -1 (nothing
    changed) if the insertion would break the surface or overflow its arrays.

    A new facet whose orientation cannot be certified (a sliver: q barely beyond the
    facet across its horizon ridge, or nearly in line with that ridge), or whose
    certified offset falls below ``floor`` (which a convex hull growing around the
    origin never does: the surface has turned non-convex there), is avoided by counting
    the facet across its horizon ridge as visible too (if q lies at most ``tol`` beneath
    it), up to ``_MAX_FORCED`` times.
    """
    visible = scratch_int[0]
    n_visible = _visible_from(points, q, start, tol, neighbours, normals, offsets, marks,
                              stamp, visible)
    if n_visible < 0:
        return -1
    for _ in range(_MAX_FORCED + 1):
        n_horizon = _horizon(neighbours, marks, stamp, visible, n_visible, scratch_int[1],
                             scratch_int[2])
        if n_horizon < 0 or n_facets + n_horizon > vertices.shape[0]:
            return -1
        failed = _new_facets(points, q, reference, origin_based, allowance, problem, floor,
                             vertices, normals, offsets, certified, n_facets, n_horizon,
                             scratch_int[1], scratch_int[2], matrix, normal)
        if failed < 0:
            break
        forced = neighbours[scratch_int[1, failed], scratch_int[2, failed]]
        beyond = -offsets[forced]
        for c in range(6):
            beyond += normals[forced, c] * points[q, c]
        # Only a facet q is at most ``tol`` beneath: replacing one q lies clearly beneath
        # would fold the surface.
        if beyond < -tol or n_visible == visible.shape[0]:
            return -1
        marks[forced] = stamp
        visible[n_visible] = forced
        n_visible += 1
    else:
        return -1
    horizon_facet, horizon_slot = scratch_int[1], scratch_int[2]
    if not _pair_sub_ridges(vertices, neighbours, n_facets, n_horizon, horizon_slot,
                            scratch_new):
        return -1
    for h in range(n_horizon):
        f = n_facets + h
        g, j = horizon_facet[h], horizon_slot[h]
        outside = neighbours[g, j]
        neighbours[f, j] = outside
        for s in range(6):
            if neighbours[outside, s] == g:
                neighbours[outside, s] = f
        alive[f] = True
        stuck[f] = False
        marks[f] = 0
    for t in range(n_visible):
        alive[visible[t]] = False
    return n_facets + n_horizon


@jit
def _visible_from(points: np.ndarray, q: int, start: int, tol: float, neighbours: np.ndarray,
                  normals: np.ndarray, offsets: np.ndarray, marks: np.ndarray, stamp: int,
                  visible: np.ndarray) -> int:
    """The facets that q lies beyond by more than ``tol``, connected to ``start`` (breadth
    first), into ``visible``; marks them ``stamp`` (and those seen but not visible
    -stamp). Returns their count, or -1 if there are more than ``visible`` holds."""
    n_visible = 1
    visible[0] = start
    marks[start] = stamp
    head = 0
    while head < n_visible:
        g = visible[head]
        head += 1
        for j in range(6):
            nb = neighbours[g, j]
            if marks[nb] == stamp or marks[nb] == -stamp:
                continue
            beyond = -offsets[nb]
            for c in range(6):
                beyond += normals[nb, c] * points[q, c]
            if beyond > tol:
                if n_visible == visible.shape[0]:
                    return -1
                marks[nb] = stamp
                visible[n_visible] = nb
                n_visible += 1
            else:
                marks[nb] = -stamp
    return n_visible


@jit
def _horizon(neighbours: np.ndarray, marks: np.ndarray, stamp: int, visible: np.ndarray,
             n_visible: int, horizon_facet: np.ndarray, horizon_slot: np.ndarray) -> int:
    """The ridges between visible facets (marked ``stamp``) and the others, as (visible
    facet, slot opposite the ridge). Returns their count, or -1 on overflow."""
    n_horizon = 0
    for t in range(n_visible):
        g = visible[t]
        for j in range(6):
            if marks[neighbours[g, j]] != stamp:
                if n_horizon == horizon_facet.shape[0]:
                    return -1
                horizon_facet[n_horizon] = g
                horizon_slot[n_horizon] = j
                n_horizon += 1
    return n_horizon


@jit
def _new_facets(points: np.ndarray, q: int, reference: np.ndarray, origin_based: bool,
                allowance: float, problem: int, floor: float, vertices: np.ndarray,
                normals: np.ndarray,
                offsets: np.ndarray, certified: np.ndarray, first: int, count: int,
                horizon_facet: np.ndarray, horizon_slot: np.ndarray, matrix: np.ndarray,
                normal: np.ndarray) -> int:
    """Facets first..first+count-1: each horizon facet with q in place of the vertex
    opposite its horizon ridge (which keeps the surface's orientation coherent).
    Returns -1, or the first horizon index whose facet's orientation is not certified
    or (about the origin) whose certified offset is below ``floor``."""
    for h in range(count):
        f = first + h
        g, j = horizon_facet[h], horizon_slot[h]
        for c in range(6):
            vertices[f, c] = vertices[g, c]
        vertices[f, j] = q
        if not _set_facet(points, f, reference, origin_based, allowance, problem, vertices,
                          normals, offsets, certified, matrix, normal):
            return h
        if origin_based and certified[f] < floor:
            return h
    return -1


@jit
def _pair_sub_ridges(vertices: np.ndarray, neighbours: np.ndarray, first: int, count: int,
                     slots: np.ndarray, scratch: np.ndarray) -> bool:
    """Link the new facets first..first+count-1 (each with q in slot ``slots[h]``)
    across their ridges through q: each ridge must be shared by exactly two."""
    n_keys = 5 * count
    if n_keys > scratch.shape[1]:
        return False
    keys, owners = scratch[0], scratch[1]
    k = 0
    for h in range(count):
        f = first + h
        for s in range(6):
            if s == slots[h]:
                continue
            keys[k] = _ridge_key(vertices[f], s, slots[h])
            owners[k] = h * 6 + s
            k += 1
    order = np.argsort(keys[:n_keys])
    t = 0
    while t < n_keys:
        if t + 1 >= n_keys or keys[order[t]] != keys[order[t + 1]]:
            return False
        if t + 2 < n_keys and keys[order[t + 2]] == keys[order[t]]:
            return False
        a, b = owners[order[t]], owners[order[t + 1]]
        neighbours[first + a // 6, a % 6] = first + b // 6
        neighbours[first + b // 6, b % 6] = first + a // 6
        t += 2
    return True


@jit
def _ridge_key(vertices: np.ndarray, skip_a: int, skip_b: int) -> int:
    """The four vertex indices of ``vertices`` (6,) other than slots skip_a and skip_b,
    sorted and packed into one integer (a sorting network: no allocation)."""
    a = b = c = d = 0
    m = 0
    for slot in range(6):
        if slot != skip_a and slot != skip_b:
            if m == 0:
                a = vertices[slot]
            elif m == 1:
                b = vertices[slot]
            elif m == 2:
                c = vertices[slot]
            else:
                d = vertices[slot]
            m += 1
    if a > b:
        a, b = b, a
    if c > d:
        c, d = d, c
    if a > c:
        a, c = c, a
    if b > d:
        b, d = d, b
    if b > c:
        b, c = c, b
    return (((a << _KEY_BITS | b) << _KEY_BITS | c) << _KEY_BITS) | d


@jit
def certified_upper(normal_rows: np.ndarray, tangent_rows: np.ndarray, mu: np.ndarray,
                    problem: int, u: np.ndarray, allowance: float) -> float:
    """An upper bound, valid despite rounding, on h(u / |u|), where ``allowance`` bounds
    the rounding of every contact's work (and, L-infinity, of their sum): 0 where every
    contact's work plus it is <= 0. Divided by a lower bound on |u|; for
    ``TORQUE_INRADIUS`` on |u_t| instead (h(u) / |u_t|, inf where u_t = 0)."""
    z = np.empty(3)
    total, most = 0.0, -np.inf
    for i in range(normal_rows.shape[0]):
        work, _, _ = _contact_work(normal_rows, tangent_rows, mu, i, u, z, problem)
        total += max(work, 0.0)
        most = max(most, work)
    if most + allowance <= 0.0:
        return 0.0
    bound = (total if problem == EPSILON_LINF else most) + allowance
    norm = 0.0
    for c in range(3 if problem == TORQUE_INRADIUS else 0, 6):
        norm += u[c] * u[c]
    if not norm > 0.0:
        return np.inf
    return bound / (sqrt(norm) * (1.0 - 8.0 * _EPS))


@jit
def _initial_simplex(points: np.ndarray, n_points: int, tol: float, chosen: np.ndarray) -> bool:
    """Seven affinely independent points among the first ``n_points`` (greedy: each
    next point is the farthest from the affine hull of those chosen). False if the
    points span less than 6 dimensions by ``tol``."""
    basis = np.zeros((6, 6))
    chosen[0] = 0
    residual = np.empty(6)
    for k in range(1, 7):
        best, best_p = -1.0, -1
        for p in range(n_points):
            for c in range(6):
                residual[c] = points[p, c] - points[chosen[0], c]
            for b in range(k - 1):
                dot = 0.0
                for c in range(6):
                    dot += basis[b, c] * residual[c]
                for c in range(6):
                    residual[c] -= dot * basis[b, c]
            size = 0.0
            for c in range(6):
                size += residual[c] * residual[c]
            if size > best:
                best, best_p = size, p
        if not sqrt(best) > tol:
            return False
        chosen[k] = best_p
        for c in range(6):
            residual[c] = points[best_p, c] - points[chosen[0], c]
        for b in range(k - 1):
            dot = 0.0
            for c in range(6):
                dot += basis[b, c] * residual[c]
            for c in range(6):
                residual[c] -= dot * basis[b, c]
        size = sqrt(best)
        for c in range(6):
            basis[k - 1, c] = residual[c] / size
    return True


@jit
def _simplex_surface(points: np.ndarray, chosen: np.ndarray, reference: np.ndarray,
                     allowance: float, problem: int, vertices: np.ndarray,
                     neighbours: np.ndarray,
                     normals: np.ndarray, offsets: np.ndarray, certified: np.ndarray,
                     alive: np.ndarray, stuck: np.ndarray, marks: np.ndarray,
                     matrix: np.ndarray, normal: np.ndarray) -> bool:
    """The boundary of the simplex ``chosen`` (7,) as facets 0..6, oriented outward
    about ``reference`` (its centroid). False if an orientation is not certified."""
    for k in range(7):
        s = 0
        for other in range(7):
            if other != k:
                vertices[k, s] = chosen[other]
                neighbours[k, s] = other
                s += 1
        if _facet_plane(points, vertices[k], reference, matrix, normal) < 0.0:
            vertices[k, 0], vertices[k, 1] = vertices[k, 1], vertices[k, 0]
            neighbours[k, 0], neighbours[k, 1] = neighbours[k, 1], neighbours[k, 0]
        if not _set_facet(points, k, reference, False, allowance, problem, vertices, normals,
                          offsets, certified, matrix, normal):
            return False
        alive[k] = True
        stuck[k] = False
        marks[k] = 0
    return True


@jit
def _least_facet(n_facets: int, alive: np.ndarray, keys: np.ndarray) -> int:
    """The alive facet with the least key (ties: the first)."""
    best, best_f = np.inf, -1
    for f in range(n_facets):
        if alive[f] and (best_f < 0 or keys[f] < best):
            best, best_f = keys[f], f
    return best_f


@jit
def _query(normal_rows: np.ndarray, tangent_rows: np.ndarray, mu: np.ndarray, problem: int,
           allowance: float, direction: np.ndarray, point: np.ndarray, best: float,
           best_dir: np.ndarray) -> tuple[float, float]:
    """Support point in ``direction`` (to ``point``); returns (h, certified upper bound),
    and keeps the direction in ``best_dir`` if it improves on ``best``."""
    h = support(normal_rows, tangent_rows, mu, problem, direction, point)
    bound = certified_upper(normal_rows, tangent_rows, mu, problem, direction, allowance)
    if bound < best:
        for c in range(6):
            best_dir[c] = direction[c]
    return h, bound


@jit
def _seed_surface(normal_rows: np.ndarray, tangent_rows: np.ndarray, mu: np.ndarray,
                  problem: int, allowance: float, tol: float, contain_tol: float,
                  seeds: np.ndarray, n_seeds: int, points: np.ndarray, vertices: np.ndarray,
                  neighbours: np.ndarray, normals: np.ndarray, offsets: np.ndarray,
                  certified: np.ndarray, alive: np.ndarray, stuck: np.ndarray,
                  marks: np.ndarray, scratch_int: np.ndarray, scratch_new: np.ndarray,
                  matrix: np.ndarray, normal: np.ndarray, direction: np.ndarray,
                  reference: np.ndarray, upper: float) -> tuple[int, int, float]:
    """The first surface: the hull of the support points in the first ``n_seeds``
    directions of ``seeds``, oriented about their simplex's centroid (``reference``).
    Returns (facets, insertions so far, upper), facets 0 if the points span less than
    six dimensions."""
    for k in range(n_seeds):
        _, bound = _query(normal_rows, tangent_rows, mu, problem, allowance, seeds[k], points[k],
                          upper, direction)
        upper = min(upper, bound)
    chosen = np.empty(7, np.int64)
    if not _initial_simplex(points, n_seeds, contain_tol, chosen):
        return 0, 0, upper
    for c in range(6):
        reference[c] = 0.0
        for k in range(7):
            reference[c] += points[chosen[k], c] / 7.0
    if not _simplex_surface(points, chosen, reference, allowance, problem, vertices, neighbours,
                            normals, offsets, certified, alive, stuck, marks, matrix, normal):
        return 0, 0, upper
    n_facets, stamp = 7, 0
    for p in range(n_seeds):
        start = -1
        for f in range(n_facets):
            if alive[f]:
                beyond = -offsets[f]
                for c in range(6):
                    beyond += normals[f, c] * points[p, c]
                if beyond > tol:
                    start = f
                    break
        if start >= 0:
            stamp += 1
            grown = _insert(points, p, start, reference, False, allowance, problem, tol, -np.inf,
                            vertices, neighbours, normals, offsets, certified, alive, stuck,
                            marks, stamp, n_facets, scratch_int, scratch_new, matrix, normal)
            if grown > 0:
                n_facets = grown
    return n_facets, stamp, upper


@jit
def _epsilon_one(normal_rows: np.ndarray, tangent_rows: np.ndarray, mu: np.ndarray,
                 scale: float, problem: int, rtol: float, seeds: np.ndarray, max_points: int,
                 points: np.ndarray, vertices: np.ndarray, neighbours: np.ndarray,
                 normals: np.ndarray, offsets: np.ndarray, certified: np.ndarray,
                 alive: np.ndarray, stuck: np.ndarray, marks: np.ndarray,
                 scratch_int: np.ndarray, scratch_new: np.ndarray, matrix: np.ndarray,
                 normal: np.ndarray, direction: np.ndarray) -> tuple[float, float, int, int]:
    """Certified bounds on one grasp's epsilon. Returns (lower, upper, points used,
    status); ``direction`` (6,) <- the direction certifying upper.

    The first surface uses the support points in the first ``SEED_SIMPLEX`` rows of
    ``seeds`` (a regular simplex of directions), or the first ``SEED_FALLBACK``, then
    all of them, where those do not span six dimensions (several directions with one
    support point)."""
    allowance = SUPPORT_ROUNDING_ULPS * _EPS * scale
    tol = VISIBLE_TOL * scale
    reference = np.zeros(6)
    upper = np.inf
    n_points, n_facets, stamp = 0, 0, 0
    tried = 0
    for n_seeds in (SEED_SIMPLEX, min(SEED_FALLBACK, seeds.shape[0]), seeds.shape[0]):
        if n_seeds == tried:
            continue
        tried = n_points = n_seeds
        n_facets, stamp, upper = _seed_surface(
            normal_rows, tangent_rows, mu, problem, allowance, tol, CONTAINMENT_TOL * scale,
            seeds, n_seeds, points, vertices, neighbours, normals, offsets, certified, alive,
            stuck, marks, scratch_int, scratch_new, matrix, normal, direction, reference, upper)
        if n_facets > 0:
            break
    if n_facets == 0:
        return 0.0, upper, n_points, DEGENERATE
    origin = np.zeros(6)
    for phase in range(2):
        origin_based = phase == 1
        keys = certified if origin_based else offsets
        while True:
            f = _least_facet(n_facets, alive, keys)
            least = keys[f]
            if origin_based and least >= (1.0 - rtol) * upper:
                return max(least, 0.0), upper, n_points, CONVERGED
            if not origin_based and least > CONTAINMENT_TOL * scale:
                break
            if stuck[f]:
                return (max(least, 0.0) if origin_based else 0.0), upper, n_points, \
                    (STUCK if origin_based else NOT_CONTAINED)
            h, bound = _query(normal_rows, tangent_rows, mu, problem, allowance, normals[f],
                              points[n_points], upper, direction)
            upper = min(upper, bound)
            if h - offsets[f] <= tol:
                stuck[f] = True
                continue
            if n_points == max_points:
                return (max(least, 0.0) if origin_based else 0.0), upper, n_points, BUDGET
            grown = -1
            for fraction in (VISIBLE_FRACTION, VISIBLE_RETRY):
                stamp += 1
                visible_tol = max(tol, fraction * (h - offsets[f]))
                grown = _insert(points, n_points, f, origin if origin_based else reference,
                                origin_based, allowance, problem, visible_tol,
                                least - visible_tol,
                                vertices, neighbours, normals, offsets, certified, alive, stuck,
                                marks, stamp, n_facets, scratch_int, scratch_new, matrix, normal)
                if grown >= 0:
                    break
            if grown < 0:
                stuck[f] = True
                continue
            n_points += 1
            n_facets = grown
        # The origin is inside every facet: orient them about it from now on.
        for f in range(n_facets):
            if alive[f]:
                certified[f] = -np.inf
                stuck[f] = False
                _set_facet(points, f, origin, True, allowance, problem, vertices, normals,
                           offsets, certified, matrix, normal)
    return 0.0, upper, n_points, STUCK


def workspace(max_points: int, max_facets: int) -> Workspace:
    """The arrays of one search (a grasp's surface and scratch), for :func:`epsilon_batch`:
    reused from grasp to grasp and, by the caller, from call to call. Nothing in them
    needs clearing: every facet is written in full when it is made."""
    return (np.empty((max_points + 1, 6)),                       # points
            np.empty((max_facets, 6), np.int64),                 # vertices
            np.empty((max_facets, 6), np.int64),                 # neighbours
            np.empty((max_facets, 6)),                           # normals
            np.empty(max_facets), np.empty(max_facets),          # offsets, certified
            np.empty(max_facets, np.bool_), np.empty(max_facets, np.bool_),  # alive, stuck
            np.empty(max_facets, np.int64),                      # marks
            np.empty((3, max(_MAX_VISIBLE, _MAX_HORIZON)), np.int64),
            np.empty((2, 5 * _MAX_HORIZON), np.int64),
            np.empty((6, 7)), np.empty(6))


@jit
def epsilon_batch(normal_rows: np.ndarray, tangent_rows: np.ndarray, mu: np.ndarray,
                  scale: np.ndarray, problem: int, rtol: float, seeds: np.ndarray,
                  arrays: Workspace
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_epsilon_one` for every grasp of a batch.

    Parameters
    ----------
    normal_rows : ndarray, shape (N, n, 6)
    tangent_rows : ndarray, shape (N, n, 3, 6)
    mu : ndarray, shape (N, n)
    scale : ndarray, shape (N,)
        Wrench scale of each grasp (bounds |support point|).
    problem : int
        What is bounded: ``EPSILON_L1``, ``EPSILON_LINF`` or ``TORQUE_INRADIUS``.
    rtol : float
    seeds : ndarray, shape (S, 6)
        Unit directions of the first support points: a regular simplex (the first
        ``SEED_SIMPLEX`` rows), then more for grasps where those span too little.
    arrays : tuple
        :func:`workspace` (its sizes are the budgets of support points and facets).

    Returns
    -------
    lower, upper : ndarray, shape (N,)
    direction : ndarray, shape (N, 6)
    n_points : ndarray of int64, shape (N,)
    status : ndarray of int64, shape (N,)
    """
    (points, vertices, neighbours, normals, offsets, certified, alive, stuck, marks,
     scratch_int, scratch_new, matrix, normal) = arrays
    n_grasps = normal_rows.shape[0]
    lower, upper = np.empty(n_grasps), np.empty(n_grasps)
    direction = np.zeros((n_grasps, 6))
    n_points, status = np.empty(n_grasps, np.int64), np.empty(n_grasps, np.int64)
    for g in range(n_grasps):
        lower[g], upper[g], n_points[g], status[g] = _epsilon_one(
            normal_rows[g], tangent_rows[g], mu[g], scale[g], problem, rtol, seeds,
            points.shape[0] - 1, points, vertices, neighbours, normals, offsets, certified,
            alive, stuck, marks, scratch_int, scratch_new, matrix, normal, direction[g])
    return lower, upper, direction, n_points, status


# Double-double arithmetic for the orientation of facets that double precision cannot
# certify (thin facets: nearly collinear points of one contact's disc rim). A value is
# hi + lo with |lo| <= ulp(hi) / 2; each operation below errs by at most DD_UNIT
# relative (the accurate sum of Joldes, Muller and Popescu errs by 3 u^2, their product
# by 5 u^2, the quotient by ~10 u^2; u = eps / 2).

#: Relative error of one double-double operation, with margin (u = eps / 2).
DD_UNIT = 16.0 * (_EPS / 2.0) ** 2

#: Entries below this (after scaling each row by a power of two to a largest entry in
#: [0.5, 1)) could underflow in the error-free products; such a facet is not certified.
_DD_TINY = 2.0 ** -480

_SPLITTER = 134217729.0  # 2^27 + 1, Dekker's split

#: Margin on the comparison of log|det| with the log of its bound: six logarithms of
#: at most ~700 in magnitude, each within an ulp or two.
_LOG_MARGIN = 1e-9


@jit
def _two_sum(a: float, b: float) -> DoubleDouble:
    s = a + b
    bb = s - a
    return s, (a - (s - bb)) + (b - bb)


@jit
def _quick_two_sum(a: float, b: float) -> DoubleDouble:
    s = a + b
    return s, b - (s - a)


@jit
def _two_prod(a: float, b: float) -> DoubleDouble:
    p = a * b
    c = _SPLITTER * a
    a_hi = c - (c - a)
    a_lo = a - a_hi
    c = _SPLITTER * b
    b_hi = c - (c - b)
    b_lo = b - b_hi
    return p, ((a_hi * b_hi - p) + a_hi * b_lo + a_lo * b_hi) + a_lo * b_lo


@jit
def _dd_add(a_hi: float, a_lo: float, b_hi: float, b_lo: float) -> DoubleDouble:
    s, e = _two_sum(a_hi, b_hi)
    t, f = _two_sum(a_lo, b_lo)
    e += t
    s, e = _quick_two_sum(s, e)
    e += f
    return _quick_two_sum(s, e)


@jit
def _dd_mul(a_hi: float, a_lo: float, b_hi: float, b_lo: float) -> DoubleDouble:
    p, e = _two_prod(a_hi, b_hi)
    e += a_hi * b_lo + a_lo * b_hi
    return _quick_two_sum(p, e)


@jit
def _dd_div(a_hi: float, a_lo: float, b_hi: float, b_lo: float) -> DoubleDouble:
    q = a_hi / b_hi
    p_hi, p_lo = _dd_mul(q, 0.0, b_hi, b_lo)
    r_hi, r_lo = _dd_add(a_hi, a_lo, -p_hi, -p_lo)
    q2 = r_hi / b_hi
    return _quick_two_sum(q, q2)


@jit
def _orientation_dd(points: np.ndarray, vertices: np.ndarray, reference: np.ndarray) -> bool:
    """True if det[v_1 - ref; ...; v_6 - ref] > 0 is certified in double-double
    arithmetic (the rows formed exactly, scaled by powers of two)."""
    hi, lo = np.empty((6, 6)), np.empty((6, 6))
    row_norms = 1.0
    for k in range(6):
        largest = 0.0
        for c in range(6):
            hi[k, c], lo[k, c] = _two_sum(points[vertices[k], c], -reference[c])
            largest = max(largest, abs(hi[k, c]))
        if largest == 0.0:
            return False
        _, exponent = frexp(largest)
        norm = 0.0
        for c in range(6):
            hi[k, c] = ldexp(hi[k, c], -exponent)
            lo[k, c] = ldexp(lo[k, c], -exponent)
            if hi[k, c] != 0.0 and abs(hi[k, c]) < _DD_TINY:
                return False
            norm += hi[k, c] * hi[k, c]
        row_norms *= sqrt(norm) * (1.0 + 4.0 * _EPS) + 8.0 * _EPS
    sign, growth = 1.0, 0.0
    for col in range(6):
        pivot, size = col, abs(hi[col, col])
        for r in range(col + 1, 6):
            if abs(hi[r, col]) > size:
                pivot, size = r, abs(hi[r, col])
        if size == 0.0:
            return False
        if pivot != col:
            sign = -sign
            for c in range(col, 6):
                hi[col, c], hi[pivot, c] = hi[pivot, c], hi[col, c]
                lo[col, c], lo[pivot, c] = lo[pivot, c], lo[col, c]
        if hi[col, col] < 0.0:
            sign = -sign
        for c in range(col, 6):
            growth = max(growth, abs(hi[col, c]))
        for r in range(col + 1, 6):
            f_hi, f_lo = _dd_div(hi[r, col], lo[r, col], hi[col, col], lo[col, col])
            for c in range(col + 1, 6):
                p_hi, p_lo = _dd_mul(f_hi, f_lo, hi[col, c], lo[col, c])
                hi[r, c], lo[r, c] = _dd_add(hi[r, c], lo[r, c], -p_hi, -p_lo)
    # |det| is the product of the pivots' magnitudes: compare its logarithm.
    # (The logarithms err by far less than the margin _LOG_MARGIN.)
    log_det = 0.0
    for col in range(6):
        log_det += np.log(abs(hi[col, col]))
    gamma = 18.0 * DD_UNIT / (1.0 - 18.0 * DD_UNIT)
    kappa = 2.0 * gamma * 6.0 * sqrt(6.0) * growth
    bound = DETERMINANT_SAFETY * _determinant_drift(kappa) * row_norms
    return sign > 0.0 and log_det > np.log(bound) + _LOG_MARGIN


@jit
def _determinant_drift(kappa: float) -> float:
    """(1 + kappa)^6 - 1 bounded above without cancellation (6 k + 18 k^2 >= it for
    k <= 0.1): how far a determinant with unit rows moves when each row moves by kappa."""
    return 6.0 * kappa * (1.0 + 3.0 * kappa) if kappa <= 0.1 else np.inf


@jit
def certified_upper_batch(normal_rows: np.ndarray, tangent_rows: np.ndarray, mu: np.ndarray,
                          scale: np.ndarray, problem: int, directions: np.ndarray) -> np.ndarray:
    """:func:`certified_upper` of each grasp's direction (N, 6), with the rounding
    allowance of its wrench scale (N,)."""
    out = np.empty(directions.shape[0])
    for g in range(directions.shape[0]):
        out[g] = certified_upper(normal_rows[g], tangent_rows[g], mu[g], problem, directions[g],
                                 SUPPORT_ROUNDING_ULPS * _EPS * scale[g])
    return out
