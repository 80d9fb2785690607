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
  That pair test costs O(K^3) for K boundary torques (and its broadcast form O(K^3)
  memory). Two things bound it for many torques. First, a subset that spans proves
  that the whole set spans, and the torques extreme along 14 fixed directions usually
  do (a pair test on 14 vectors, whatever K). Second, what that leaves undecided from
  ``HULL_MIN_VECTORS`` torques on goes to the convex hull of the torques (Qhull,
  O(K log K) per problem) instead: they fail to span iff the origin is not strictly
  inside the hull, and then a facet the origin is not strictly behind gives a
  separating direction (its outward normal, negated).

Every separating direction is checked against every torque before a problem is called
non-spanning, so rounding (or a hull computed imprecisely) can only make a problem
pass. Small problems are vectorised over the batch with no solver and no per-problem
Python loop; large ones loop over problems, each costing far more than the loop.
"""

from __future__ import annotations

from functools import lru_cache
from itertools import combinations

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from .tolerances import PARALLEL_TOL, SPAN_TOL
from .torque_sets import TorqueSetKind, TorqueSets, cross, dot

# Plain integers for the hot path: comparing with an IntEnum member looks it up each time.
_FAN = int(TorqueSetKind.FAN)
_PLANE = int(TorqueSetKind.PLANE)

#: Problems handled per vectorised pass of the pair test: long enough to amortise
#: numpy's per-call overhead over the loop on triples, short enough that the
#: (pairs, problems) intermediates stay in a core's cache.
_PAIR_TEST_CHUNK = 4096

#: From this many boundary torques per problem (fans-only case, after the extreme-subset
#: proof) the convex-hull test replaces the pair test. Measured (benchmarks/
#: bench_filter.py --paths, box grasps, mu = 0.01, a loaded machine): the pair test's
#: cost grows as K^3, the hull's (about 0.1 ms per call) as K log K; they cross between
#: K = 26 and 38 (14 to 20 contacts).
HULL_MIN_VECTORS = 36

#: Probe directions of :func:`_extremes_span`: the 6 axes and the 8 diagonals.
_PROBES = np.array([[x, y, z] for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)
                    if abs(x) + abs(y) + abs(z) in (1, 3)], dtype=float)

#: Below this many problems the loop over triples costs more in numpy call overhead
#: (about 1,400 calls for six fingers) than it saves in arithmetic; measured crossover.
_TRIPLE_LOOP_MIN_PROBLEMS = 256


def positively_spans(sets: TorqueSets, directions: bool = False):
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
            found = test(sets.subset((slice(None), part)), directions)
            if directions:
                spans[part], direction[:, part] = found
            else:
                spans[part] = found
    return (spans, direction) if directions else spans


def _spans_with_plane(sets: TorqueSets, directions: bool = False):
    """Positive span for problems that contain at least one plane. Shapes (m, B).

    Returns spans (B,), and with ``directions`` also the separating direction (3, B):
    minus (plus) the pivot plane's normal where nothing reaches its positive (negative)
    side.
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
        return spans
    sign = np.where(has_pos, 1.0, -1.0)
    return spans, np.where(spans, np.nan, sign * normal[:, 0])


@lru_cache(maxsize=64)
def _pairs_and_triples(n_vectors: int):
    """Pairs (a < b) as two index arrays (P,), and every triple (a < b < c) as the pair
    indices of (a, b), (a, c), (b, c) plus the index c: a list of 4-tuples."""
    first, second = np.triu_indices(n_vectors, 1)
    pair_index = {(a, b): p for p, (a, b) in enumerate(zip(first, second))}
    triples = [(pair_index[a, b], pair_index[a, c], pair_index[b, c], c)
               for a, b, c in combinations(range(n_vectors), 3)]
    return first, second, triples


def _fans_span(sets: TorqueSets, directions: bool = False):
    """Positive span for problems whose sets are fans or null sets. Shapes (m, B).

    Null sets contribute zero vectors, which lie on every side of every plane and
    make no pair non-parallel, so they need no special case.

    Returns spans (B,), and with ``directions`` also the separating directions (3, B).
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
    else:
        pairs_and_triples = _pairs_and_triples(vectors.shape[1])
        for start in range(0, undecided.size, _PAIR_TEST_CHUNK):
            chunk = undecided[start:start + _PAIR_TEST_CHUNK]
            test = (_pair_sides if chunk.size >= _TRIPLE_LOOP_MIN_PROBLEMS
                    else _pair_sides_few)
            part = vectors[:, :, chunk]
            found[:, chunk] = _separating_pair(part, *test(part, *pairs_and_triples))
    spans = np.isnan(found[0])
    return (spans, found) if directions else spans


def _direction_at_mean(vectors: np.ndarray) -> np.ndarray:
    """Cheap first try: does the mean of the vectors itself separate them?

    When all vectors lie in a half-space their mean often does (about one problem in
    ten on random six-finger grasps), and checking one direction costs K dot products
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
    sides = (_pair_sides if subset.shape[2] >= _TRIPLE_LOOP_MIN_PROBLEMS
             else _pair_sides_few)
    found = _separating_pair(subset, *sides(subset, *_pairs_and_triples(_PROBES.shape[0])))
    return np.isnan(found[0])


def _pair_sides_few(vectors: np.ndarray, first: np.ndarray, second: np.ndarray,
                    triples: list):
    """:func:`_pair_sides` in a handful of numpy calls, for few problems.

    It computes every pair's side of every vector (K (K - 1) / 2 * K dot products), which
    is more arithmetic but far less per-call overhead than the loop over triples.
    """
    del triples  # same signature as _pair_sides; only pairs are needed here
    normals = cross(vectors[:, first], vectors[:, second])             # (3, P, B)
    sides = np.einsum("xpb,xkb->pkb", normals, vectors)                # (P, K, B)
    return normals, sides.min(axis=1), sides.max(axis=1)


def _pair_sides(vectors: np.ndarray, first: np.ndarray, second: np.ndarray,
                triples: list):
    """Every pair's cross product and the lowest and highest side of any vector on it.

    The side of v_c for the pair (v_a, v_b) is the triple product det(v_a, v_b, v_c),
    and each triple product serves three pairs: (a, b) sees +det, (a, c) sees -det and
    (b, c) sees +det. Computing each once costs 120 instead of 450 dot products for
    six fingers (K = 10). A pair's own two vectors are on its plane (side 0).

    Parameters
    ----------
    vectors : ndarray, shape (3, K, B)
        K unit (or zero) vectors of each of B problems, component-first.
    first, second : ndarray of int, shape (P,)
        The pairs (a < b).
    triples : list of (int, int, int, int)
        Per triple a < b < c: the pair indices of (a, b), (a, c), (b, c), and c.

    Returns
    -------
    normals : ndarray, shape (3, P, B)
        v_a x v_b per pair.
    lowest, highest : ndarray, shape (P, B)
        min and max over the vectors of their side det(v_a, v_b, v).
    """
    normals = cross(vectors[:, first], vectors[:, second])             # (3, P, B)
    lowest = np.zeros(normals.shape[1:])
    highest = np.zeros(normals.shape[1:])
    for ab, ac, bc, c in triples:
        det = dot(normals[:, ab], vectors[:, c])
        for pair, side in ((ab, det), (bc, det), (ac, -det)):
            np.minimum(lowest[pair], side, out=lowest[pair])
            np.maximum(highest[pair], side, out=highest[pair])
    return normals, lowest, highest


def _separating_pair(vectors: np.ndarray, normals: np.ndarray, lowest: np.ndarray,
                     highest: np.ndarray) -> np.ndarray:
    """The pair test's verdict as a separating direction per problem.

    A non-parallel pair whose vectors all lie on one closed side of its cross product
    gives that side's unit normal. If no pair is non-parallel, the vectors lie on a line
    (or are zero) and any direction perpendicular to that line separates them.

    Parameters
    ----------
    vectors : ndarray, shape (3, K, B)
    normals : ndarray, shape (3, P, B)
    lowest, highest : ndarray, shape (P, B)
        From :func:`_pair_sides` or :func:`_pair_sides_few`.

    Returns
    -------
    ndarray, shape (3, B)
        Unit separating directions; NaN where the vectors positively span R^3.
    """
    length = np.sqrt(dot(normals, normals))
    slack = SPAN_TOL * length
    is_pair = length > PARALLEL_TOL
    above = (lowest >= -slack) & is_pair
    below = (highest <= slack) & is_pair
    one_side = above | below
    pair = one_side.argmax(axis=0)                                     # (B,)
    problem = np.arange(pair.size)
    sign = np.where(above[pair, problem], 1.0, -1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        found = sign * normals[:, pair, problem] / length[pair, problem]
    on_a_line = ~is_pair.any(axis=0)
    found[:, on_a_line] = _perpendicular(vectors[:, :, on_a_line])
    return np.where(one_side.any(axis=0) | on_a_line, found, np.nan)


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
