"""The torque filter of :mod:`.torque_space_filter` on one grasp, compiled (numba).

The one-grasp path (:mod:`.one_grasp`) runs the filter where the batched pipeline would
(``use_filter``, :func:`.torque_space_filter.resolve_use_filter`), without numpy's
per-call overhead, which dwarfs the filter's work on one grasp. It follows the numpy
filter step by step with the same floating-point operations: the same origins (the seed's
two contacts, or every contact), the same torque sets (:func:`.torque_sets.cone_torque_sets`,
widened fans, planes near half-planes), and the same positive-span tests
(:mod:`.positive_span`: planes first, then the mean direction, then the pair test,
:func:`.positive_span.pair_test_problem` itself).

Two things can differ at the last bit, numpy's ``arcsin`` (its own SIMD code, against
libm's here) and the order of a short sum, so a decision may differ only where a
triple product or a side test sits within rounding of its SPAN_TOL threshold. Either
filter is sound (a rejection is a verified separating direction), so the force-closure
verdict never depends on which one ran.

Only problems the pair test decides alone are taken: at most ``MAX_FILTER_CONTACTS``
contacts (K <= 14 boundary torques per origin, where the numpy filter needs neither its
extreme-subset proof nor the convex hull).
"""

from __future__ import annotations

import math

import numpy as np

from .._kernels.jit import Vector3, jit, row
from ..tolerances import FAN_WIDEN_RAD, HALF_PLANE_MARGIN_RAD, PARALLEL_TOL, SPAN_TOL
from .positive_span import SPANS, pair_test_problem
from .torque_sets import TorqueSetKind

#: Most contacts whose filter runs compiled: 2 (n - 1) boundary torques per origin stay
#: within the pair test's 14 probes' count (:data:`.positive_span._PROBES`), so the numpy
#: filter decides them by the mean direction and the pair test alone, as here.
MAX_FILTER_CONTACTS = 8

_NULL, _FAN, _PLANE = (int(TorqueSetKind.NULL), int(TorqueSetKind.FAN),
                       int(TorqueSetKind.PLANE))

#: As :func:`.torque_sets.cone_torque_sets` computes them.
_PLANE_FROM = np.pi / 2 - HALF_PLANE_MARGIN_RAD
_PARALLEL_TOL_SQUARED = PARALLEL_TOL ** 2


@jit
def seed_origins(points: np.ndarray) -> tuple[int, int]:
    """The ``"seed"`` origins of :func:`.torque_space_filter._origin_indices`.

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        Contact positions (caller's frame).

    Returns
    -------
    (int, int)
        The contacts nearest to and furthest from q, the contact of least x minus
        (1, 0, 0) (first ones on ties).
    """
    n = points.shape[0]
    least = 0
    for i in range(1, n):
        if points[i, 0] < points[least, 0]:
            least = i
    q0, q1, q2 = points[least, 0] - 1.0, points[least, 1], points[least, 2]
    peak = 0.0
    for i in range(n):
        peak = max(peak, abs(points[i, 0] - q0))
        peak = max(peak, abs(points[i, 1] - q1))
        peak = max(peak, abs(points[i, 2] - q2))
    # Scaling by a power of two (np.frexp / np.ldexp there) keeps the order of the
    # distances and stops their squares from overflowing. A product by 2^-e is x 2^-e
    # rounded once, as ldexp gives it, and 2^-e is representable (e <= 1024).
    scale = math.ldexp(1.0, -math.frexp(peak)[1])
    nearest = furthest = 0
    low = high = 0.0
    for i in range(n):
        o0 = (points[i, 0] - q0) * scale
        o1 = (points[i, 1] - q1) * scale
        o2 = (points[i, 2] - q2) * scale
        squared = o0 * o0 + o1 * o1 + o2 * o2
        if i == 0 or squared < low:
            low, nearest = squared, i
        if i == 0 or squared > high:
            high, furthest = squared, i
    return nearest, furthest


@jit
def torque_set(lever: Vector3, normal: Vector3,
               sin_half_angle: float) -> tuple[int, Vector3, Vector3, Vector3]:
    """The torque set of one friction cone about an origin, as
    :func:`.torque_sets.cone_torque_sets` computes it.

    Parameters
    ----------
    lever : Vector3
        Lever arm r = p - o.
    normal : Vector3
        Unit inward normal.
    sin_half_angle : float
        sin(atan(mu)).

    Returns
    -------
    kind : int
        TorqueSetKind NULL, FAN or PLANE.
    first, second : Vector3
        The boundary torques (0 for planes and null sets).
    axis : Vector3
        r / |r| (0 for a null set).
    """
    scale = max(max(abs(lever[0]), abs(lever[1])), abs(lever[2]))
    null = scale == 0.0
    if null:
        scale = 1.0
    r0, r1, r2 = lever[0] / scale, lever[1] / scale, lever[2] / scale
    length = 1.0 if null else np.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
    h0, h1, h2 = r0 / length, r1 / length, r2 / length
    c0 = h1 * normal[2] - h2 * normal[1]
    c1 = h2 * normal[0] - h0 * normal[2]
    c2 = h0 * normal[1] - h1 * normal[0]
    s = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
    half_angle = np.arcsin(min(sin_half_angle / s, 1.0)) + FAN_WIDEN_RAD
    plane = not null and not half_angle < _PLANE_FROM
    fan = not null and not plane
    if fan:
        c0, c1, c2 = c0 / s, c1 / s, c2 / s
    a0 = h1 * c2 - h2 * c1
    a1 = h2 * c0 - h0 * c2
    a2 = h0 * c1 - h1 * c0
    cos_b = np.cos(half_angle) if fan else 0.0
    sin_b = np.sin(half_angle) if fan else 0.0
    first = (cos_b * c0 + sin_b * a0, cos_b * c1 + sin_b * a1, cos_b * c2 + sin_b * a2)
    second = (cos_b * c0 - sin_b * a0, cos_b * c1 - sin_b * a1, cos_b * c2 - sin_b * a2)
    if null:
        return _NULL, first, second, (0.0, 0.0, 0.0)
    return (_PLANE if plane else _FAN), first, second, (h0, h1, h2)


@jit
def spans_with_plane(kinds: np.ndarray, sets: np.ndarray, count: int) -> bool:
    """:func:`.positive_span._spans_with_plane` for one problem.

    Parameters
    ----------
    kinds : ndarray of int64, shape (>= count,)
    sets : ndarray, shape (>= count, 3, 3)
        As :func:`torque_set` gives them; at least one PLANE among the first ``count``.
    count : int

    Returns
    -------
    bool
        The sets reach both open sides of the first plane.
    """
    pivot = 0
    while kinds[pivot] != _PLANE:
        pivot += 1
    n0, n1, n2 = sets[pivot, 2, 0], sets[pivot, 2, 1], sets[pivot, 2, 2]
    has_pos = has_neg = False
    for j in range(count):
        if kinds[j] == _FAN:
            side_first = sets[j, 0, 0] * n0 + sets[j, 0, 1] * n1 + sets[j, 0, 2] * n2
            side_second = sets[j, 1, 0] * n0 + sets[j, 1, 1] * n1 + sets[j, 1, 2] * n2
            has_pos = has_pos or side_first > SPAN_TOL or side_second > SPAN_TOL
            has_neg = has_neg or side_first < -SPAN_TOL or side_second < -SPAN_TOL
        elif kinds[j] == _PLANE:
            a0, a1, a2 = sets[j, 2, 0], sets[j, 2, 1], sets[j, 2, 2]
            t0 = a1 * n2 - a2 * n1
            t1 = a2 * n0 - a0 * n2
            t2 = a0 * n1 - a1 * n0
            if t0 * t0 + t1 * t1 + t2 * t2 > _PARALLEL_TOL_SQUARED:
                has_pos = has_neg = True
    return has_pos and has_neg


@jit
def fans_span(vectors: np.ndarray, normals: np.ndarray, lowest: np.ndarray,
              highest: np.ndarray, found: np.ndarray) -> bool:
    """:func:`.positive_span._fans_span` for one problem of at most 14 vectors: the mean
    direction, then the pair test.

    Parameters
    ----------
    vectors : ndarray, shape (3, K)
        First then second boundary torques of every set, component-first.
    normals, lowest, highest, found
        Scratch of :func:`.positive_span.pair_test_problem`.

    Returns
    -------
    bool
        The vectors positively span R^3.
    """
    k = vectors.shape[1]
    m0, m1, m2 = vectors[0, 0], vectors[1, 0], vectors[2, 0]
    for j in range(1, k):
        m0 += vectors[0, j]
        m1 += vectors[1, j]
        m2 += vectors[2, j]
    lowest_side = np.inf
    for j in range(k):
        lowest_side = min(lowest_side,
                          m0 * vectors[0, j] + m1 * vectors[1, j] + m2 * vectors[2, j])
    length = np.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
    if length > PARALLEL_TOL and lowest_side >= -SPAN_TOL * length:
        return False
    return pair_test_problem(vectors, normals, lowest, highest, found) == SPANS


@jit
def passes_filter(points: np.ndarray, directions: np.ndarray, sin_half_angle: np.ndarray,
                  all_origins: bool) -> bool:
    """The torque filter of one grasp of at most MAX_FILTER_CONTACTS contacts.

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        Contact positions (caller's frame).
    directions : ndarray, shape (n, 3)
        Unit inward normals (:func:`.grasp_input.unit_vectors`).
    sin_half_angle : ndarray, shape (n,)
        sin(atan(mu_i)) (:func:`.torque_sets.friction_half_angle_sine`).
    all_origins : bool
        ``origins="all"`` (every contact), else ``"seed"``.

    Returns
    -------
    bool
        False: the torque sets about some origin fail to span R^3, the grasp is
        certainly not force closure.
    """
    n = points.shape[0]
    m = n - 1
    pairs = m * (2 * m - 1)
    # One allocation for all the scratch (a noticeable part of the call on small grasps).
    scratch = np.empty(15 * m + 5 * pairs + 3)
    sets = scratch[:9 * m].reshape((m, 3, 3))
    vectors = scratch[9 * m:15 * m].reshape((3, 2 * m))
    normals = scratch[15 * m:15 * m + 3 * pairs].reshape((pairs, 3))
    lowest = scratch[15 * m + 3 * pairs:15 * m + 4 * pairs]
    highest = scratch[15 * m + 4 * pairs:15 * m + 5 * pairs]
    found = scratch[15 * m + 5 * pairs:]
    kinds = np.empty(m, dtype=np.int64)
    seed = seed_origins(points) if not all_origins else (0, 0)
    for index in range(n if all_origins else 2):
        origin = index if all_origins else seed[index]
        has_plane = False
        for j in range(m):
            other = j + 1 if j >= origin else j
            lever = (points[other, 0] - points[origin, 0], points[other, 1] - points[origin, 1],
                     points[other, 2] - points[origin, 2])
            kind, first, second, axis = torque_set(lever, row(directions, other),
                                                   sin_half_angle[other])
            kinds[j] = kind
            for c in range(3):
                sets[j, 0, c], sets[j, 1, c], sets[j, 2, c] = first[c], second[c], axis[c]
            has_plane = has_plane or kind == _PLANE
        if has_plane:
            spans = spans_with_plane(kinds, sets, m)
        else:
            for j in range(m):
                for c in range(3):
                    vectors[c, j] = sets[j, 0, c]
                    vectors[c, m + j] = sets[j, 1, c]
            spans = fans_span(vectors, normals, lowest, highest, found)
        if not spans:
            return False
    return True
