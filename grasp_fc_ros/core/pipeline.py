"""The filtered pipeline: the torque filter first, the exact test on the survivors
(paper section V, Fig. 4b)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from .exact_test import solve_exact
from .grasp_input import GraspBatch, prepare_grasps
from .torque_space_filter import passes_torque_filter, resolve_use_filter


class Status(IntEnum):
    """How a grasp was decided; also the ``uint8`` status codes of the ROS messages."""

    FORCE_CLOSURE = 0      #: the exact test found a verified strictly internal force
    NOT_FORCE_CLOSURE = 1  #: decided by the exact test (incl. a rank-deficient grasp map)
    FILTERED_OUT = 2       #: rejected by the torque filter: certainly not force closure
    INVALID_INPUT = 3      #: bad input (produced by callers that validate per grasp)
    SOLVER_FAILURE = 4     #: the solver could not decide, even after a retry


@dataclass(frozen=True)
class ForceClosureResult:
    """Verdicts of :func:`check_force_closure`: 0-d arrays for one grasp, (N,) for a batch.

    Attributes
    ----------
    force_closure : ndarray of bool
        The grasp is force closure.
    filtered_out : ndarray of bool
        Rejected by the torque filter; the exact test was not run.
    margin : ndarray of float
        The exact test's optimum: how deep inside every friction cone an equilibrating
        internal force can be (mu f_n - |f_t|, normal forces summing to one).
        NaN where the exact test was not run.
    status : ndarray of uint8
        A :class:`Status` code per grasp.
    timing : dict
        Seconds spent in ``"filter_s"`` and ``"exact_s"``.
    """

    force_closure: np.ndarray
    filtered_out: np.ndarray
    margin: np.ndarray
    status: np.ndarray
    timing: dict = field(default_factory=dict)


def check_force_closure(positions, normals, mu, use_filter: bool | str = "auto",
                        origins: str = "seed") -> ForceClosureResult:
    """Decide force closure of one grasp or a batch: the filter, then the exact test.

    Parameters
    ----------
    positions : array_like, shape (n, 3) or (N, n, 3)
        Contact positions (any length unit).
    normals : array_like, same shape as ``positions``
        Inward contact normals, any non-zero length.
    mu : float or array_like broadcastable to (N, n)
        Friction coefficients, > 0.
    use_filter : bool or "auto"
        Run the torque filter first and the exact test only on the grasps it passes.
        The verdicts are the same either way; the filter only saves time. "auto" (the
        default) runs it only where it is measured to pay (:func:`filter_worthwhile`,
        by contact count: up to 8 contacts); its cost is bounded for every n anyway.
    origins : {"seed", "all"}
        Torque origins of the filter (see :func:`torque_filter`).

    Returns
    -------
    ForceClosureResult

    Raises
    ------
    ValueError
        On bad input, naming the grasp and contact.
    """
    return run_pipeline(prepare_grasps(positions, normals, mu), use_filter, origins)


def run_pipeline(grasps: GraspBatch, use_filter: bool | str = True,
                 origins: str = "seed") -> ForceClosureResult:
    """:func:`check_force_closure` on validated input."""
    n_grasps = grasps.positions.shape[0]
    use_filter = resolve_use_filter(use_filter, grasps.positions.shape[1], origins)
    start = time.perf_counter()
    if use_filter:
        passed = passes_torque_filter(grasps, origins)
    else:
        passed = np.ones(n_grasps, dtype=bool)
    filtered = time.perf_counter()

    survivors = np.flatnonzero(passed)
    exact = solve_exact(GraspBatch(grasps.positions[survivors], grasps.normals[survivors],
                                   grasps.mu[survivors], single=False))
    finished = time.perf_counter()

    force_closure = np.zeros(n_grasps, dtype=bool)
    force_closure[survivors] = exact.force_closure
    margin = np.full(n_grasps, np.nan)
    margin[survivors] = exact.margin
    status = np.full(n_grasps, Status.FILTERED_OUT, dtype=np.uint8)
    status[survivors] = np.select(
        [exact.solver_failure, exact.force_closure],
        [Status.SOLVER_FAILURE, Status.FORCE_CLOSURE], Status.NOT_FORCE_CLOSURE)
    return ForceClosureResult(
        force_closure=grasps.unbatch(force_closure),
        filtered_out=grasps.unbatch(~passed),
        margin=grasps.unbatch(margin),
        status=grasps.unbatch(status),
        timing={"filter_s": filtered - start, "exact_s": finished - filtered})


def exact_force_closure(positions, normals, mu) -> np.ndarray:
    """The exact force-closure test alone (no filter).

    Parameters
    ----------
    positions : array_like, shape (n, 3) or (N, n, 3)
    normals : array_like, same shape as ``positions``
    mu : float or array_like broadcastable to (N, n)

    Returns
    -------
    ndarray of bool, shape () for one grasp or (N,)
        True where the grasp is force closure (with a verified witness).

    Raises
    ------
    ValueError
        On bad input, naming the grasp and contact.
    """
    grasps = prepare_grasps(positions, normals, mu)
    return grasps.unbatch(solve_exact(grasps).force_closure)
