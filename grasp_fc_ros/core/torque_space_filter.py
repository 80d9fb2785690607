"""The torque-space filter: a necessary condition for force closure (paper section III).

If a grasp is force closure its wrenches positively span R^6, so their projections on
torque space positively span R^3 for every choice of origin (Proposition 3.1). The
filter tries a few origins placed at contact points (whose own torque set is then null
and is left out) and rejects the grasp when the torque sets of the other contacts fail
to positively span R^3 about any of them.

Origins:

* ``"seed"`` -- the paper's choice. q is the contact with the smallest x coordinate
  minus (1, 0, 0), a point outside the contacts' convex hull; the origins are the
  contacts nearest to and furthest from q.
* ``"all"`` -- every contact in turn. Still sound, and rejects more grasps that are not
  force closure, at n/2 times the cost.

The seed origins depend on the coordinate frame and on the length unit (the offset
(1, 0, 0) is in the caller's unit), as in the paper: which non-force-closure grasps
the filter catches can change with them. Its soundness, and so every final verdict,
does not.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from .grasp_input import GraspBatch, prepare_grasps
from .positive_span import positively_spans
from .torque_sets import cone_torque_sets, dot, friction_half_angle_sine

ORIGIN_CHOICES = ("seed", "all")

#: From this many grasps on, origins are tried one after another so that grasps
#: already rejected skip the rest; below it, all origins go in one pass, which pays
#: numpy's per-call overhead once instead of once per origin (measured crossover).
_ONE_ORIGIN_AT_A_TIME_MIN_GRASPS = 256


def torque_filter(positions, normals, mu, origins: str = "seed") -> np.ndarray:
    """Necessary condition for force closure: do the torque sets positively span R^3?

    Parameters
    ----------
    positions : array_like, shape (n, 3) or (N, n, 3)
        Contact positions (any length unit).
    normals : array_like, same shape as ``positions``
        Inward contact normals, any non-zero length.
    mu : float or array_like broadcastable to (N, n)
        Friction coefficients, > 0.
    origins : {"seed", "all"}
        Which contacts serve as torque origins (see module docstring).

    Returns
    -------
    ndarray of bool, shape () for one grasp or (N,)
        True: the grasp passes (it may be force closure). False: it is certainly not
        force closure.

    Raises
    ------
    ValueError
        On bad input (naming grasp and contact) or an unknown ``origins``.
    """
    grasps = prepare_grasps(positions, normals, mu)
    return grasps.unbatch(passes_torque_filter(grasps, origins))


def passes_torque_filter(grasps: GraspBatch, origins: str = "seed") -> np.ndarray:
    """:func:`torque_filter` on validated input. Returns shape (N,)."""
    # Component-first copies, (3, n, N): the grasp axis becomes the contiguous one.
    points = np.ascontiguousarray(grasps.positions.transpose(2, 1, 0))
    normals = np.ascontiguousarray(grasps.normals.transpose(2, 1, 0))
    sin_half_angle = friction_half_angle_sine(np.ascontiguousarray(grasps.mu.T))
    others_of = _other_contacts(points.shape[1])

    def spans_about(origin: np.ndarray, grasp: np.ndarray) -> np.ndarray:
        """Do the other contacts' torque sets about contact origin[k] of grasp[k] span?"""
        others = others_of[origin].T                                   # (n-1, K)
        lever_arms = points[:, others, grasp] - points[:, origin, grasp][:, None]
        return positively_spans(cone_torque_sets(
            lever_arms, normals[:, others, grasp], sin_half_angle[others, grasp]))

    origin = _origin_indices(points, origins)                          # (O, N)
    n_grasps = origin.shape[1]
    if n_grasps < _ONE_ORIGIN_AT_A_TIME_MIN_GRASPS:
        grasp = np.broadcast_to(np.arange(n_grasps), origin.shape)
        return spans_about(origin.ravel(), grasp.ravel()).reshape(origin.shape).all(axis=0)
    passing = np.ones(n_grasps, dtype=bool)
    # One origin after another: a grasp rejected about one origin is not tried again.
    for row in origin:
        grasp = np.flatnonzero(passing)
        passing[grasp] = spans_about(row[grasp], grasp)
    return passing


def _origin_indices(points: np.ndarray, origins: str) -> np.ndarray:
    """Indices (O, N) of the contacts used as origins; ``points`` is (3, n, N)."""
    n_contacts, n_grasps = points.shape[1:]
    if origins == "all":
        return np.broadcast_to(np.arange(n_contacts)[:, None], (n_contacts, n_grasps))
    if origins != "seed":
        raise ValueError(f"origins must be one of {ORIGIN_CHOICES}, got {origins!r}")
    grasp = np.arange(n_grasps)
    q = points[:, points[0].argmin(axis=0), grasp]
    q[0] -= 1.0
    offset = points - q[:, None, :]
    squared_distance = dot(offset, offset)                             # (n, N)
    return np.stack((squared_distance.argmin(axis=0), squared_distance.argmax(axis=0)))


@lru_cache(maxsize=64)
def _other_contacts(n_contacts: int) -> np.ndarray:
    """Table (n, n-1): row i lists every contact index except i."""
    index = np.arange(n_contacts)
    return np.array([np.delete(index, i) for i in range(n_contacts)])
