"""The fast path of :func:`.pipeline.check_force_closure` for one grasp (numba).

Through the general path, a call with one grasp spends many times longer in numpy
overhead (validation, normalisation, batching, dispatch) than in its exact test
(docs/performance.md#one-grasp). Here one compiled call validates the
grasp, normalises it with the same floating-point operations as
:func:`.grasp_input.unit_vectors` and :func:`.certificates.normalise_positions` (so the
fast stage sees bit-identical input and the verdict cannot depend on the path), and runs
the fast exact stage. Anything it does not settle (invalid input, whose error message the
general path words; a grasp the fast stage leaves undecided) returns to the general path.
"""

from __future__ import annotations

import numpy as np

from . import force_interior_point, interior_point, positive_span
from ._kernels.jit import jit
from .tolerances import MAX_ABS_COORDINATE, MAX_FRICTION_COEFFICIENT, MIN_NORMAL_COMPONENT

#: Largest contact count the fast path takes: a one-grasp query of more contacts is
#: dominated by the exact test itself, not by the overhead this path saves.
MAX_FAST_CONTACTS = 64


@jit
def _prepare_one(positions: np.ndarray, normals: np.ndarray, mu: float, unit: np.ndarray,
                 directions: np.ndarray, friction: np.ndarray) -> bool:
    """Validate one grasp (n, 3), (n, 3), scalar mu like :func:`.grasp_input._all_valid`
    and normalise it into ``unit``, ``directions`` (n, 3) and ``friction`` (n,).
    False (outputs undefined) where the input is not valid."""
    n = positions.shape[0]
    if not (mu > 0.0 and mu <= MAX_FRICTION_COEFFICIENT):
        return False
    peak = 0.0
    for i in range(n):
        largest = 0.0
        for k in range(3):
            coordinate = abs(positions[i, k])
            if not coordinate <= MAX_ABS_COORDINATE:
                return False
            peak = max(peak, coordinate)
            component = normals[i, k]
            if not np.isfinite(component):
                return False
            largest = max(largest, abs(component))
        if not largest >= MIN_NORMAL_COMPONENT:
            return False
        # unit_vectors: divide by the largest |component|, then by the length.
        square = 0.0
        for k in range(3):
            directions[i, k] = normals[i, k] / largest
            square += directions[i, k] * directions[i, k]
        length = np.sqrt(square)
        for k in range(3):
            directions[i, k] = directions[i, k] / length
        friction[i] = mu
    # normalise_positions: scale by the peak, centre at the mean, scale to unit size.
    if not peak > 0.0:
        peak = 1.0
    size = 0.0
    for k in range(3):
        total = 0.0
        for i in range(n):
            total += positions[i, k] / peak
        centre = total / n
        for i in range(n):
            unit[i, k] = positions[i, k] / peak - centre
            size = max(size, abs(unit[i, k]))
    if not size > 0.0:
        size = 1.0
    for i in range(n):
        for k in range(3):
            unit[i, k] = unit[i, k] / size
    return True


def check_one(positions: np.ndarray, normals: np.ndarray, mu: float,
              want_optimum: bool) -> tuple[bool, float, float] | None:
    """Decide one valid grasp on the fast stage, or say it must take the general path.

    Parameters
    ----------
    positions, normals : ndarray of float64, shape (n, 3), C-contiguous and writable
        (:func:`~._kernels.jit.kernel_array`)
    mu : float
    want_optimum : bool
        As ``margin="optimum"``.

    Returns
    -------
    tuple (force_closure, t_lo, t_hi) or None
        None where the input is not valid or the fast stage did not decide the grasp.
    """
    n = positions.shape[0]
    unit, directions, friction = np.empty((1, n, 3)), np.empty((1, n, 3)), np.empty((1, n))
    if not _prepare_one(positions, normals, mu, unit[0], directions[0], friction[0]):
        return None
    # A second compiled call rather than one kernel calling the other: numba would
    # compile the whole exact stage again into that kernel (a long cold compile).
    codes, t_lo, t_hi, _, _, _ = interior_point._solve_all(unit, directions, friction,
                                                           want_optimum, False, 0.0, 0.0)
    if codes[0] == interior_point.UNDECIDED:
        return None
    return bool(codes[0] == interior_point.FORCE_CLOSURE), t_lo[0], t_hi[0]


def warm_up() -> None:
    """Compile (or load from the cache) every numba kernel of the core (the fast exact
    stage, the filter's pair test, this path, the fast s* stage): a ROS node calls this
    before it reports ready, so no query pays the compile."""
    interior_point.warm_up()
    positive_span.warm_up()
    force_interior_point.warm_up()
    corners = np.array([[1.0, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]])
    for optimum in (False, True):
        check_one(corners, -corners, 0.5, optimum)
