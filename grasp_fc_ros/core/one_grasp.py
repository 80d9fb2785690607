"""The fast path of :func:`.pipeline.check_force_closure` for one grasp (numba).

Through the general path, a call with one grasp spends many times longer in numpy
overhead (validation, normalisation, batching, dispatch) than in its filter and exact
test (docs/performance.md#one-grasp). Here one compiled call validates the grasp,
normalises it with the same floating-point operations as
:func:`.grasp_input.unit_vectors` and :func:`.certificates.normalise_positions` (so the
fast stage sees bit-identical input and the verdict cannot depend on the path), runs the
torque filter where the batched pipeline would (:mod:`.one_grasp_filter`), and the fast
exact stage on what passes. Anything it does not settle (invalid input, whose error
message the general path words; a grasp the fast stage leaves undecided) returns to the
general path.
"""

from __future__ import annotations

import numpy as np

from ._kernels.grasp_map import normalise_grasp
from ._kernels.jit import jit
from .exact import interior_point
from .exact.interior_point import UNDECIDED, solve_one
from .filter import positive_span
from .filter.one_grasp_filter import passes_filter
from .forces import force_interior_point
from .tolerances import MAX_ABS_COORDINATE, MAX_FRICTION_COEFFICIENT, MIN_NORMAL_COMPONENT

#: Largest contact count the fast path takes: a one-grasp query of more contacts is
#: dominated by the exact test itself, not by the overhead this path saves.
MAX_FAST_CONTACTS = 64

#: Codes of :func:`decide_one` beyond the exact stage's (FORCE_CLOSURE,
#: NOT_FORCE_CLOSURE): rejected by the filter; or for the general path (invalid input,
#: or undecided by the fast stage).
FILTERED_OUT, GENERAL_PATH = 4, 5

#: ``filter_origins`` of :func:`decide_one`: no filter, the seed's origins, every contact.
NO_FILTER, SEED_ORIGINS, ALL_ORIGINS = 0, 1, 2


@jit
def _prepare_one(positions: np.ndarray, normals: np.ndarray, mu: float, unit: np.ndarray,
                 directions: np.ndarray, friction: np.ndarray) -> bool:
    """Validate one grasp (n, 3), (n, 3), scalar mu like :func:`.grasp_input._all_valid`
    and normalise it into ``unit``, ``directions`` (n, 3) and ``friction`` (n,).
    False (outputs undefined) where the input is not valid."""
    peak = _validate_one(positions, normals, mu, directions, friction)
    if not peak >= 0.0:
        return False
    normalise_grasp(positions, peak, unit)
    return True


@jit
def _validate_one(positions: np.ndarray, normals: np.ndarray, mu: float,
                  directions: np.ndarray, friction: np.ndarray) -> float:
    """The validation and normal directions of :func:`_prepare_one`: the largest
    |coordinate|, or -1 (outputs undefined) where the input is not valid."""
    n = positions.shape[0]
    if not (mu > 0.0 and mu <= MAX_FRICTION_COEFFICIENT):
        return -1.0
    peak = 0.0
    for i in range(n):
        largest = 0.0
        for k in range(3):
            coordinate = abs(positions[i, k])
            if not coordinate <= MAX_ABS_COORDINATE:
                return -1.0
            peak = max(peak, coordinate)
            component = normals[i, k]
            if not np.isfinite(component):
                return -1.0
            largest = max(largest, abs(component))
        if not largest >= MIN_NORMAL_COMPONENT:
            return -1.0
        # unit_vectors: divide by the largest |component|, then by the length.
        square = 0.0
        for k in range(3):
            directions[i, k] = normals[i, k] / largest
            square += directions[i, k] * directions[i, k]
        length = np.sqrt(square)
        for k in range(3):
            directions[i, k] = directions[i, k] / length
        friction[i] = mu
    return peak


@jit
def decide_one(positions: np.ndarray, normals: np.ndarray, mu: float, filter_origins: int,
               want_optimum: bool) -> tuple[int, float, float]:
    """Validate, normalise, filter and decide one grasp.

    Parameters
    ----------
    positions, normals : ndarray of float64, shape (n, 3), C-contiguous and writable
        (:func:`~._kernels.jit.kernel_array`); the filter takes at most
        :data:`.one_grasp_filter.MAX_FILTER_CONTACTS` contacts.
    mu : float
    filter_origins : int
        NO_FILTER, SEED_ORIGINS or ALL_ORIGINS.
    want_optimum : bool
        As ``margin="optimum"``.

    Returns
    -------
    (int, float, float)
        code and the certified bounds t_lo, t_hi on t*: FORCE_CLOSURE or
        NOT_FORCE_CLOSURE (:mod:`.interior_point`), FILTERED_OUT (bounds NaN), or
        GENERAL_PATH (invalid input, or undecided by the fast stage; bounds NaN).
    """
    n = positions.shape[0]
    # One allocation (a noticeable part of a call on few contacts): unit, directions,
    # friction and, for the filter, sin(atan(mu)).
    scratch = np.empty(8 * n)
    unit, directions = scratch[:3 * n].reshape((n, 3)), scratch[3 * n:6 * n].reshape((n, 3))
    friction, sin_half_angle = scratch[6 * n:7 * n], scratch[7 * n:]
    peak = _validate_one(positions, normals, mu, directions, friction)
    if not peak >= 0.0:
        return GENERAL_PATH, np.nan, np.nan
    if filter_origins != NO_FILTER:
        # friction_half_angle_sine, per contact as the batched filter computes it.
        for i in range(n):
            sin_half_angle[i] = friction[i] / np.sqrt(1.0 + friction[i] * friction[i])
        if not passes_filter(positions, directions, sin_half_angle,
                             filter_origins == ALL_ORIGINS):
            return FILTERED_OUT, np.nan, np.nan
    normalise_grasp(positions, peak, unit)
    code, t_lo, t_hi = solve_one(unit, directions, friction, want_optimum)
    if code == UNDECIDED:
        return GENERAL_PATH, np.nan, np.nan
    return code, t_lo, t_hi


def check_one(positions: np.ndarray, normals: np.ndarray, mu: float,
              want_optimum: bool) -> tuple[int, float, float] | None:
    """Decide one valid grasp on the fast stage (no filter), or say it must take the
    general path.

    Parameters
    ----------
    positions, normals, mu, want_optimum
        As :func:`decide_one`.

    Returns
    -------
    tuple (code, t_lo, t_hi) or None
        As :func:`decide_one` (FORCE_CLOSURE or NOT_FORCE_CLOSURE); None for its
        GENERAL_PATH.
    """
    decided = decide_one(positions, normals, mu, NO_FILTER, want_optimum)
    return None if decided[0] == GENERAL_PATH else decided


def warm_up() -> None:
    """Compile (or load from the cache) every numba kernel of the core (the fast exact
    stage, the filter's pair test, this path, the fast s* stage, the epsilon search): the
    install (``make setup``) calls this to fill numba's cache, and a ROS node before it
    reports ready, so no query or first call pays the compile (loading the cache then
    takes well under a second)."""
    from .quality import epsilon  # (which imports this module through the pipeline)

    interior_point.warm_up()
    positive_span.warm_up()
    force_interior_point.warm_up()
    corners = np.array([[1.0, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]])
    for optimum in (False, True):
        for origins in (NO_FILTER, SEED_ORIGINS, ALL_ORIGINS):
            decide_one(corners, -corners, 0.5, origins, optimum)
    epsilon.warm_up()
