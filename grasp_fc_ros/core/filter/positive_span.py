"""Positive span of R^3 by torque sets: fans, planes and null sets (paper section IV-B).

A family of torque sets positively spans R^3 when every torque is a non-negative
combination of members of the sets. It fails exactly when some non-zero direction c
has c . v >= 0 for every v in every set (all sets lie in one closed half-space).

* With a plane P (normal a) among the sets: P together with the rest spans R^3 iff the
  rest reaches both open sides of P. A fan reaches the side of the sign of a . v of its
  boundary torques; another plane reaches both sides unless it is parallel to P. If one
  side is missing, c = a or c = -a separates.
* With fans only: the separating directions form a polyhedral cone whose extreme rays
  are perpendicular to two of the boundary torques. So the torques fail to span iff,
  for some pair (v_i, v_j) of non-parallel boundary torques, c = v_i x v_j has all
  boundary torques on one closed side. If no pair is non-parallel the torques span a
  line at most and cannot span R^3.
  That pair test costs O(K^3) for K boundary torques (compiled with numba: a loop
  over problems, no large intermediates). Two things bound it for many torques.
  First, a subset that spans proves that the whole set spans, and the torques extreme
  along 14 fixed directions usually do (a pair test on 14 vectors, whatever K).
  Second, what that leaves undecided from ``HULL_MIN_VECTORS`` torques on goes to the
  convex hull of the torques (Qhull, O(K log K) per problem) instead: they fail to span
  iff the origin is not strictly inside the hull, and then a facet the origin is not
  strictly behind gives a separating direction (its outward normal, negated).

Every separating direction is checked against every torque before a problem is called
non-spanning, so rounding (or a hull computed imprecisely) can only make a problem
pass. Small problems are vectorised over the batch (the pair test compiled) with no
solver and no per-problem Python loop; large ones loop over problems, each costing far
more than the loop.
"""

from __future__ import annotations

from typing import Literal, overload

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from .._kernels.jit import jit, kernel_array
from ..tolerances import PARALLEL_TOL, SPAN_TOL
from .torque_sets import TorqueSetKind, TorqueSets, cross, dot

# Plain integers for the hot path: comparing with an IntEnum member looks it up each time.
_FAN = int(TorqueSetKind.FAN)
_PLANE = int(TorqueSetKind.PLANE)

#: From this many boundary torques per problem (fans-only case, after the extreme-subset
#: proof) the convex-hull test replaces the pair test: the pair test's cost grows as K^3,
#: the hull's as K log K from a higher start; this is where they cross (tuned:
#: docs/performance.md#filter, from benchmarks/bench_filter.py --paths).
HULL_MIN_VECTORS = 36

#: Probe directions of :func:`_extremes_span`: the 6 axes and the 8 diagonals.
_PROBES = np.array([[x, y, z] for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)
                    if abs(x) + abs(y) + abs(z) in (1, 3)], dtype=float)


@overload
def positively_spans(sets: TorqueSets, directions: Literal[False] = False) -> np.ndarray: ...
@overload
def positively_spans(sets: TorqueSets,
                     directions: Literal[True]) -> tuple[np.ndarray, np.ndarray]: ...
@overload
def positively_spans(sets: TorqueSets,
                     directions: bool) -> np.ndarray | tuple[np.ndarray, np.ndarray]: ...


def positively_spans(sets: TorqueSets,
                     directions: bool = False) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Whether the torque sets of each problem positively span R^3.

    Parameters
    ----------
    sets : TorqueSets
        ``kind`` of shape (m, B) and vectors of shape (3, m, B): m torque sets for each
        of B problems.
    directions : bool
        Also return the separating direction found for each non-spanning problem.

    Returns
    -------
    spans : ndarray of bool, shape (B,)
        False only where a separating direction was found: the sets certainly do not
        positively span R^3 (up to ``SPAN_TOL``).
    direction : ndarray, shape (3, B), only if ``directions``
        Where ``spans`` is False, a unit c with c . v >= -SPAN_TOL |v| for every torque v
        of every set (all sets lie on c's side of the plane perpendicular to it); NaN
        where ``spans`` is True.
    """
    has_plane = (sets.kind == _PLANE).any(axis=0)
    spans = np.empty(sets.kind.shape[1], dtype=bool)
    direction = np.full((3, spans.size), np.nan) if directions else None
    for part, test in ((has_plane, _spans_with_plane), (~has_plane, _fans_span)):
        if part.any():
            spans[part], found = test(sets.subset((slice(None), part)), directions)
            if direction is not None and found is not None:
                direction[:, part] = found
    return spans if direction is None else (spans, direction)


def _spans_with_plane(sets: TorqueSets,
                      directions: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """Positive span for problems that contain at least one plane. Shapes (m, B).

    Returns spans (B,) and, with ``directions``, the separating direction (3, B):
    minus (plus) the pivot plane's normal where nothing reaches its positive (negative)
    side (None without ``directions``).
    """
    is_plane = sets.kind == _PLANE
    pivot = is_plane.argmax(axis=0)
    normal = sets.axis[:, pivot, np.arange(pivot.size)][:, None, :]    # (3, 1, B)

    is_fan = sets.kind == _FAN
    side_first = dot(sets.first, normal)
    side_second = dot(sets.second, normal)
    reaches_pos = is_fan & ((side_first > SPAN_TOL) | (side_second > SPAN_TOL))
    reaches_neg = is_fan & ((side_first < -SPAN_TOL) | (side_second < -SPAN_TOL))

    tilt = cross(sets.axis, normal)
    crossing_plane = is_plane & (dot(tilt, tilt) > PARALLEL_TOL ** 2)
    has_pos = (reaches_pos | crossing_plane).any(axis=0)
    has_neg = (reaches_neg | crossing_plane).any(axis=0)
    spans = has_pos & has_neg
    if not directions:
        return spans, None
    sign = np.where(has_pos, 1.0, -1.0)
    return spans, np.where(spans, np.nan, sign * normal[:, 0])


def _fans_span(sets: TorqueSets,
               directions: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """Positive span for problems whose sets are fans or null sets. Shapes (m, B).

    Null sets contribute zero vectors, which lie on every side of every plane and
    make no pair non-parallel, so they need no special case.

    Returns spans (B,) and, with ``directions``, the separating directions (3, B)
    (None without).
    """
    vectors = np.concatenate((sets.first, sets.second), axis=1)        # (3, K, B)
    found = _direction_at_mean(vectors)
    open_question = np.isnan(found[0])
    if vectors.shape[1] > _PROBES.shape[0]:
        open_question[open_question] = ~_extremes_span(vectors[:, :, open_question])
    undecided = np.flatnonzero(open_question)
    if vectors.shape[1] >= HULL_MIN_VECTORS:
        for problem in undecided:
            found[:, problem] = _hull_direction(vectors[:, :, problem].T)
    elif undecided.size:
        found[:, undecided] = _pair_test(vectors[:, :, undecided])
    spans = np.isnan(found[0])
    return spans, (found if directions else None)


def _direction_at_mean(vectors: np.ndarray) -> np.ndarray:
    """Cheap first try: does the mean of the vectors itself separate them?

    When all vectors lie in a half-space their mean often does (on random six-finger
    grasps, for a fair share of the problems), and checking one direction costs K dot products
    instead of the pair test's K (K - 1) / 2 cross and K (K - 1) (K - 2) / 6 triple
    products.

    Parameters
    ----------
    vectors : ndarray, shape (3, K, B)

    Returns
    -------
    ndarray, shape (3, B)
        The unit mean where it separates, NaN elsewhere.
    """
    mean = vectors.sum(axis=1)                                         # (3, B)
    lowest = dot(mean[:, None], vectors).min(axis=0)
    length = np.sqrt(dot(mean, mean))
    separates = (length > PARALLEL_TOL) & (lowest >= -SPAN_TOL * length)
    return np.where(separates, mean / np.where(separates, length, 1.0), np.nan)


def _extremes_span(vectors: np.ndarray) -> np.ndarray:
    """Cheap proof of spanning: do the vectors extreme along 14 fixed probes span?

    If a subset of the vectors positively spans R^3, so do all of them. Most problems
    with many vectors span, and the vectors furthest along the 6 axes and 8 diagonals
    usually already do; the pair test on those 14 costs little, whatever K. False
    proves nothing.

    Parameters
    ----------
    vectors : ndarray, shape (3, K, B)

    Returns
    -------
    ndarray of bool, shape (B,)
        True where the extreme subset (hence the whole set) positively spans R^3.
    """
    pick = np.einsum("dx,xkb->dkb", _PROBES, vectors).argmax(axis=1)  # (D, B)
    subset = vectors[:, pick, np.arange(pick.shape[1])]                # (3, D, B)
    return np.isnan(_pair_test(subset)[0])


def _pair_test(vectors: np.ndarray) -> np.ndarray:
    """The pair test's verdict as a separating direction per problem.

    A non-parallel pair (v_a, v_b) whose vectors all lie on one closed side of
    c = v_a x v_b gives that side's unit normal (the first such pair, pairs in
    ``np.triu_indices`` order). The side of v_c is the triple product det(v_a, v_b, v_c),
    and each triple product serves three pairs: for a < b < c, (a, b) and (b, c) see
    +det and (a, c) sees -det, det = (v_a x v_b) . v_c; a pair's own two vectors are on
    its plane (side 0). If no pair is non-parallel, the vectors lie on a line (or are
    zero) and any direction perpendicular to that line separates them.

    Parameters
    ----------
    vectors : ndarray, shape (3, K, B)
        K unit (or zero) vectors of each of B problems, component-first.

    Returns
    -------
    ndarray, shape (3, B)
        Unit separating directions; NaN where the vectors positively span R^3.
    """
    found, on_a_line = _pair_test_kernel(kernel_array(vectors))
    if on_a_line.any():
        found[:, on_a_line] = _perpendicular(vectors[:, :, on_a_line])
    return found


#: Outcomes of :func:`pair_test_problem`.
SPANS, SEPARATED, ON_A_LINE = 0, 1, 2


@jit
def _pair_test_kernel(vectors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Compiled core of :func:`_pair_test`: directions (3, B) (NaN where none, and where
    the problem's vectors are on a line) and the on-a-line flags (B,)."""
    n_vectors, n_problems = vectors.shape[1], vectors.shape[2]
    n_pairs = n_vectors * (n_vectors - 1) // 2
    normals = np.empty((n_pairs, 3))
    lowest = np.empty(n_pairs)
    highest = np.empty(n_pairs)
    found = np.full((3, n_problems), np.nan)
    on_a_line = np.zeros(n_problems, dtype=np.bool_)
    for problem in range(n_problems):
        on_a_line[problem] = pair_test_problem(vectors[:, :, problem], normals, lowest,
                                               highest, found[:, problem]) == ON_A_LINE
    return found, on_a_line


@jit
def pair_test_problem(v: np.ndarray, normals: np.ndarray, lowest: np.ndarray,
                      highest: np.ndarray, found: np.ndarray) -> int:
    """The pair test of :func:`_pair_test` on one problem.

    Parameters
    ----------
    v : ndarray, shape (3, K)
        The problem's unit (or zero) vectors, component-first.
    normals, lowest, highest : ndarray, shapes (P, 3), (P,), (P,), P >= K (K - 1) / 2
        Scratch.
    found : ndarray, shape (3,)
        Output where SEPARATED: the unit separating direction; untouched otherwise.

    Returns
    -------
    int
        SPANS, SEPARATED, or ON_A_LINE (no pair is non-parallel: any direction
        perpendicular to the line separates).
    """
    n_vectors = v.shape[1]
    pair = 0
    for a in range(n_vectors):
        for b in range(a + 1, n_vectors):
            # The same operations as torque_sets.cross.
            normals[pair, 0] = v[1, a] * v[2, b] - v[2, a] * v[1, b]
            normals[pair, 1] = v[2, a] * v[0, b] - v[0, a] * v[2, b]
            normals[pair, 2] = v[0, a] * v[1, b] - v[1, a] * v[0, b]
            lowest[pair] = 0.0
            highest[pair] = 0.0
            pair += 1
    for a in range(n_vectors):
        for b in range(a + 1, n_vectors):
            ab = a * n_vectors - a * (a + 1) // 2 + b - a - 1
            for c in range(b + 1, n_vectors):
                ac = a * n_vectors - a * (a + 1) // 2 + c - a - 1
                bc = b * n_vectors - b * (b + 1) // 2 + c - b - 1
                det = (normals[ab, 0] * v[0, c] + normals[ab, 1] * v[1, c]
                       + normals[ab, 2] * v[2, c])
                lowest[ab] = min(lowest[ab], det)
                highest[ab] = max(highest[ab], det)
                lowest[bc] = min(lowest[bc], det)
                highest[bc] = max(highest[bc], det)
                lowest[ac] = min(lowest[ac], -det)
                highest[ac] = max(highest[ac], -det)
    any_pair = False
    for pair in range(n_vectors * (n_vectors - 1) // 2):
        n0, n1, n2 = normals[pair, 0], normals[pair, 1], normals[pair, 2]
        length = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        if not length > PARALLEL_TOL:
            continue
        any_pair = True
        slack = SPAN_TOL * length
        if lowest[pair] >= -slack or highest[pair] <= slack:
            sign = 1.0 if lowest[pair] >= -slack else -1.0
            found[0] = sign * n0 / length
            found[1] = sign * n1 / length
            found[2] = sign * n2 / length
            return SEPARATED
    return SPANS if any_pair else ON_A_LINE


def warm_up() -> None:
    """Compile (or load from the cache) the pair test."""
    _pair_test(np.eye(3)[:, :, None] * np.ones((1, 1, 2)))


def _perpendicular(vectors: np.ndarray) -> np.ndarray:
    """A unit vector (3, B) perpendicular to each problem's longest vector (3, K, B)."""
    longest = vectors[:, dot(vectors, vectors).argmax(axis=0), np.arange(vectors.shape[2])]
    axis = np.eye(3)[np.abs(longest).argmin(axis=0)].T                 # least aligned
    normal = cross(longest, axis)
    length = np.sqrt(dot(normal, normal))
    # All vectors zero: every direction separates.
    return np.where(length > 0, normal / np.where(length > 0, length, 1.0),
                    np.array([[1.0], [0.0], [0.0]]))


def _hull_direction(vectors: np.ndarray) -> np.ndarray:
    """Separating direction of one problem's vectors (K, 3) from their convex hull.

    Qhull's facets satisfy e . x + offset <= 0 for every vector x (e the unit outward
    normal). The origin is strictly inside the hull iff every offset is negative; a
    facet with offset >= 0 has every vector on the side of -e. Flat inputs, which
    Qhull cannot hull, have rank <= 2 or lie in a plane off the origin: their separating
    direction is the plane's normal, from a singular value decomposition.
    Every candidate is checked against every vector.

    Returns
    -------
    ndarray, shape (3,)
        A unit separating direction, or NaN if the vectors positively span R^3 (or no
        separating direction could be confirmed).
    """
    vectors = vectors[np.abs(vectors).max(axis=1) > 0]
    if not len(vectors):
        return np.array([1.0, 0.0, 0.0])                               # all zero
    try:
        facets = ConvexHull(vectors).equations
        highest = facets[:, 3].argmax()
        candidates = [-facets[highest, :3]] if facets[highest, 3] >= -SPAN_TOL else []
    except (QhullError, ValueError):                                   # flat, or < 4
        # The normal of the plane through the origin, or through the centroid.
        through_origin = np.linalg.svd(vectors)[2][-1]
        through_centroid = np.linalg.svd(vectors - vectors.mean(axis=0))[2][-1]
        candidates = [through_origin, -through_origin, through_centroid, -through_centroid]
    for candidate in candidates:
        candidate = candidate / np.linalg.norm(candidate)
        if (vectors @ candidate).min(initial=0.0) >= -SPAN_TOL:
            return candidate
    return np.full(3, np.nan)
