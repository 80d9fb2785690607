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

Everything is vectorised over a batch of independent problems; there is no per-problem
Python loop and no solver.
"""

from __future__ import annotations

from functools import lru_cache
from itertools import combinations

import numpy as np

from .tolerances import PARALLEL_TOL, SPAN_TOL
from .torque_sets import TorqueSetKind, TorqueSets, cross, dot

# Plain integers for the hot path: comparing with an IntEnum member looks it up each time.
_FAN = int(TorqueSetKind.FAN)
_PLANE = int(TorqueSetKind.PLANE)

#: Problems handled per vectorised pass of the pair test: long enough to amortise
#: numpy's per-call overhead over the loop on triples, short enough that the
#: (pairs, problems) intermediates stay in a core's cache.
_PAIR_TEST_CHUNK = 4096

#: Below this many problems the loop over triples costs more in numpy call overhead
#: (about 1,400 calls for six fingers) than it saves in arithmetic; measured crossover.
_TRIPLE_LOOP_MIN_PROBLEMS = 256


def positively_spans(sets: TorqueSets) -> np.ndarray:
    """Whether the torque sets of each problem positively span R^3.

    Parameters
    ----------
    sets : TorqueSets
        ``kind`` of shape (m, B) and vectors of shape (3, m, B): m torque sets for each
        of B problems.

    Returns
    -------
    ndarray of bool, shape (B,)
        False only where a separating direction was found: the sets certainly do not
        positively span R^3 (up to ``SPAN_TOL``).
    """
    has_plane = (sets.kind == _PLANE).any(axis=0)
    spans = np.empty(sets.kind.shape[1], dtype=bool)
    if has_plane.any():
        spans[has_plane] = _spans_with_plane(sets.subset((slice(None), has_plane)))
    fans_only = ~has_plane
    if fans_only.any():
        spans[fans_only] = _fans_span(sets.subset((slice(None), fans_only)))
    return spans


def _spans_with_plane(sets: TorqueSets) -> np.ndarray:
    """Positive span for problems that contain at least one plane. Shapes (m, B)."""
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
    return ((reaches_pos | crossing_plane).any(axis=0)
            & (reaches_neg | crossing_plane).any(axis=0))


@lru_cache(maxsize=64)
def _pairs_and_triples(n_vectors: int):
    """Pairs (a < b) as two index arrays (P,), and every triple (a < b < c) as the pair
    indices of (a, b), (a, c), (b, c) plus the index c: a list of 4-tuples."""
    first, second = np.triu_indices(n_vectors, 1)
    pair_index = {(a, b): p for p, (a, b) in enumerate(zip(first, second))}
    triples = [(pair_index[a, b], pair_index[a, c], pair_index[b, c], c)
               for a, b, c in combinations(range(n_vectors), 3)]
    return first, second, triples


def _fans_span(sets: TorqueSets) -> np.ndarray:
    """Positive span for problems whose sets are fans or null sets. Shapes (m, B).

    Null sets contribute zero vectors, which lie on every side of every plane and
    make no pair non-parallel, so they need no special case.
    """
    vectors = np.concatenate((sets.first, sets.second), axis=1)        # (3, K, B)
    spans = ~_separates_at_mean(vectors)
    undecided = np.flatnonzero(spans)
    pairs_and_triples = _pairs_and_triples(vectors.shape[1])
    for start in range(0, undecided.size, _PAIR_TEST_CHUNK):
        chunk = undecided[start:start + _PAIR_TEST_CHUNK]
        test = (_has_separating_pair if chunk.size >= _TRIPLE_LOOP_MIN_PROBLEMS
                else _has_separating_pair_few)
        spans[chunk] = ~test(vectors[:, :, chunk], *pairs_and_triples)
    return spans


def _separates_at_mean(vectors: np.ndarray) -> np.ndarray:
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
    ndarray of bool, shape (B,)
    """
    mean = vectors.sum(axis=1)                                         # (3, B)
    lowest = dot(mean[:, None], vectors).min(axis=0)
    length = np.sqrt(dot(mean, mean))
    return (length > PARALLEL_TOL) & (lowest >= -SPAN_TOL * length)


def _has_separating_pair_few(vectors: np.ndarray, first: np.ndarray, second: np.ndarray,
                             triples: list) -> np.ndarray:
    """:func:`_has_separating_pair` in a handful of numpy calls, for few problems.

    It computes every pair's side of every vector (K (K - 1) / 2 * K dot products), which
    is more arithmetic but far less per-call overhead than the loop over triples.
    """
    del triples  # same signature as _has_separating_pair; only pairs are needed here
    normals = cross(vectors[:, first], vectors[:, second])             # (3, P, B)
    sides = np.einsum("xpb,xkb->pkb", normals, vectors)                # (P, K, B)
    length = np.sqrt(dot(normals, normals))
    slack = SPAN_TOL * length
    one_side = (sides.min(axis=1) >= -slack) | (sides.max(axis=1) <= slack)
    is_pair = length > PARALLEL_TOL
    return (one_side & is_pair).any(axis=0) | ~is_pair.any(axis=0)


def _has_separating_pair(vectors: np.ndarray, first: np.ndarray, second: np.ndarray,
                         triples: list) -> np.ndarray:
    """Whether some pair's cross product has all vectors on one closed side.

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
    ndarray of bool, shape (B,)
    """
    normals = cross(vectors[:, first], vectors[:, second])             # (3, P, B)
    lowest = np.zeros(normals.shape[1:])
    highest = np.zeros(normals.shape[1:])
    for ab, ac, bc, c in triples:
        det = dot(normals[:, ab], vectors[:, c])
        for pair, side in ((ab, det), (bc, det), (ac, -det)):
            np.minimum(lowest[pair], side, out=lowest[pair])
            np.maximum(highest[pair], side, out=highest[pair])
    length = np.sqrt(dot(normals, normals))
    slack = SPAN_TOL * length
    one_side = (lowest >= -slack) | (highest <= slack)
    is_pair = length > PARALLEL_TOL
    return (one_side & is_pair).any(axis=0) | ~is_pair.any(axis=0)
