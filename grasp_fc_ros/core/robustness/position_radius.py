"""The position radius: how far every contact may move, anywhere, with force closure kept.

Generators: the wrenches (f, p_i x f) of the forces f of length at most 1 in each cone
K_i. For a direction u = (a, b) (force part a, torque part b) their support function is

    H(a, b) = max(0, max_i max over f in K_i, |f| <= 1 of v_i . f),   v_i = a + b x p_i,

and the inner maximum is |v_i| where v_i lies in the cone, else
max(0, v_n,i cos(alpha_i) + |v_t,i| sin(alpha_i)) (a force on the cone's rim).
Moving contact i by d_i changes v_i . f by b . (d_i x f), at most |b| r in size when
|d_i| <= r. A grasp is force closure iff H(u) > 0 for every u != 0, so every grasp
with each contact moved by at most r is force closure whenever

    r < rho = min over |b| = 1, a of H(a, b) = min over u of H(u) / |u_t|

(directions with b = 0 keep their nominal H > 0). rho does not depend on the origin of
the torques (moving it only shifts a) and scales with the grasp. It is the radius of
the largest ball about the origin of the torque space {(0, tau)} inside the
generators' hull: :mod:`.epsilon_kernels` bounds it by the same certified expanding
polytope as epsilon, with ``problem=TORQUE_INRADIUS``. The grasp is centred at its
centroid and divided by its largest lever arm L first (conditioning, and no overflow
at extreme scales), and rho is scaled back by L.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._kernels.jit import kernel_array
from ..exact.certificates import normalise_positions
from ..model.grasp_input import GraspBatch
from ..quality import epsilon_kernels
from ..quality.epsilon import SEED_DIRECTIONS, search_workspace, wrench_rows

#: Relative accuracy of the torque inradius: the search stops once its certified lower
#: bound is within 1% of its upper bound. The radius is a lower bound either way; an
#: adversary breaks force closure only at ~2x it (docs/robustness.md#tightness), so a
#: finer bracket would not change what it tells a user, and each halving of the gap
#: costs ~20% more support points (docs/robustness.md#cost).
INRADIUS_RTOL = 1e-2

_EPS = float(np.finfo(np.float64).eps)

#: Seed directions past epsilon's 19 (the search tries all of them where the first 7
#: span too little): with unit-force generators a 3-contact grasp of the benchmark had
#: its 19 support points in one hyperplane, and these 64 span six dimensions.
EXTRA_SEEDS = 45


def _seeds() -> np.ndarray:
    """epsilon's seed directions (:data:`.quality.epsilon.SEED_DIRECTIONS`), then
    EXTRA_SEEDS random unit directions (seed fixed)."""
    extra = np.random.default_rng(29).standard_normal((EXTRA_SEEDS, 6))
    extra /= np.linalg.norm(extra, axis=1, keepdims=True)
    return np.ascontiguousarray(np.vstack([SEED_DIRECTIONS, extra]))


SEEDS = _seeds()


@dataclass(frozen=True)
class TorqueInradius:
    """Certified bounds on rho of each grasp (N,), in the positions' unit.

    Attributes
    ----------
    lower, upper : ndarray, shape (N,)
        lower <= rho <= upper; lower is what the position radius reports.
    direction : ndarray, shape (N, 6)
        u = (a, b), force part and torque about the caller's origin, |b| = 1: the
        direction whose H(u) gave ``upper`` (the nearest a move comes to breaking).
    converged : ndarray of bool, shape (N,)
        upper - lower <= INRADIUS_RTOL upper was reached (else the bounds are still valid).
    """

    lower: np.ndarray
    upper: np.ndarray
    direction: np.ndarray
    converged: np.ndarray


def torque_inradius(grasps: GraspBatch, rtol: float = INRADIUS_RTOL) -> TorqueInradius:
    """Certified bounds on rho for a batch of hard grasps that are force closure.

    Grasps that are not give lower 0 (the search finds no surface around the origin).

    Parameters
    ----------
    grasps : GraspBatch
        N hard grasps (``torsional`` None).
    rtol : float
        Relative accuracy of the bounds, in (0, 1).

    Returns
    -------
    TorqueInradius
    """
    n_grasps = grasps.positions.shape[0]
    if not n_grasps:
        return TorqueInradius(np.zeros(0), np.zeros(0), np.zeros((0, 6)), np.zeros(0, bool))
    unit, centre, size = normalise_positions(grasps.positions)
    lever = np.linalg.norm(unit, axis=-1).max(axis=1)
    lever = np.where(lever > 0.0, lever, 1.0)
    normal_rows, tangent_rows = wrench_rows(
        GraspBatch(unit, grasps.normals, grasps.mu, False, None), np.zeros((n_grasps, 3)),
        lever)
    lower, upper, direction, _, status = epsilon_kernels.epsilon_batch(
        normal_rows, tangent_rows, kernel_array(grasps.mu),
        _unit_force_scale(normal_rows, tangent_rows), epsilon_kernels.TORQUE_INRADIUS, rtol,
        SEEDS, search_workspace())
    length = lever * size
    return TorqueInradius(lower * length * (1.0 - 4.0 * _EPS),
                          upper * length * (1.0 + 4.0 * _EPS),
                          _caller_directions(direction, centre, length),
                          status == epsilon_kernels.CONVERGED)


def _caller_directions(direction: np.ndarray, centre: np.ndarray,
                       length: np.ndarray) -> np.ndarray:
    """The search's directions (u_f, u_t) (N, 6), whose work vector at contact i is
    u_f + u_t x (p_i - c) / length, as caller-frame (a, b) with |b| = 1 (the same work
    vector, up to the factor length / |u_t|): b = u_t / |u_t|, a = u_f length / |u_t|
    - b x c. Zero where u_t = 0."""
    size = np.linalg.norm(direction[:, 3:], axis=1)
    safe = np.where(size > 0.0, size, 1.0)
    torque = direction[:, 3:] / safe[:, None]
    force = direction[:, :3] * (length / safe)[:, None] - np.cross(torque, centre)
    caller = np.concatenate([force, torque], axis=1)
    caller[size == 0.0] = 0.0
    return caller


def _unit_force_scale(normal_rows: np.ndarray, tangent_rows: np.ndarray) -> np.ndarray:
    """Per grasp an upper bound on the length of a generator w_i(f), |f| <= 1 (N,): the
    scale of the search's rounding allowances. f = c n + s1 t1 + s2 t2 with every
    |coefficient| <= 1."""
    reach = (np.linalg.norm(normal_rows, axis=-1)
             + np.linalg.norm(tangent_rows, axis=-1).sum(axis=-1))
    return kernel_array(reach.max(axis=1))
