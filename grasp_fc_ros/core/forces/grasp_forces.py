"""Contact forces that hold a load with the least largest normal force (Boyd & Wegbreit).

For an external wrench W = (F, tau) on the object (torque about the caller's origin),
the grasp-force optimisation problem is

    s* = min  max_i n_i . f_i
         s.t. sum_i f_i + F = 0,  sum_i p_i x f_i + tau = 0,
              |f_t,i| <= mu_i n_i . f_i              (quadratic friction cones)
              n_i . f_i <= max_normal_force_i        (optional limits)

a second-order cone program (Boyd and Wegbreit, "Fast computation of optimal contact
forces", IEEE T-RO 2007). Each grasp is solved in the homogenised form

    maximise beta  s.t.  G f + beta W = 0,  n_i . f_i <= 1,  n_i . f_i <= beta f_max,i,
                         f_i in its cone,

always feasible (f = 0, beta = 0): the forces f / beta hold W with largest normal force
1 / beta, so s* = 1 / beta*, and beta* = 0 means no forces can hold W. The grasp is first
moved to its centroid, scaled to unit size and the wrench scaled to unit length (torque
moved and scaled along), so the solvers' tolerances are relative.

Two stages solve it. Hard grasps go first to the compiled interior-point method of
:mod:`.force_interior_point` (one 6 x 6 system per iteration); what it leaves, and every
soft grasp, goes to Clarabel, the batch stacked into one problem (which needs every block
feasible: hence the homogenised form). Every answer of either stage is checked in numpy
(:func:`_check_answers`) before it is returned: the forces are projected exactly onto
the equilibrium set, then must lie in every cone and within every limit to within
FORCE_TOL of s*, and s* must be within OPTIMALITY_TOL of a lower bound proved by the
solver's dual wrench (:func:`lower_bound`), which also certifies every s* = inf. A fast
answer that fails goes to Clarabel; a Clarabel answer that fails is solved again alone
with tight tolerances, and a grasp that fails then too gets s* = NaN.

Soft fingers (``torsional_friction``, :mod:`.contact_model`): each contact also applies
a torsional moment tau_i n_i, inside the elliptic cone with its force; the program then
has a 4-D cone per contact and the dual bound the soft work term.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from ..exact.certificates import grasp_maps, normalise_positions
from ..exact.stacked_socp import SOLVE_BATCH, BlockShape, solve_stacked, split_normal, tangent_bases
from ..model.contact_model import (
    HARD,
    ContactModel,
    cone_rows,
    model_of,
    torsion_scales,
    wrench_columns,
)
from ..model.grasp_input import GraspBatch, prepare_grasps
from .force_interior_point import UNDECIDED, solve_fast_forces

#: s* = inf is reported where a dual wrench proves s* >= 1 / INFEASIBLE_BETA for the unit
#: wrench of the normalised grasp (beta* <= 1e-9): no forces hold the load, or only
#: normal forces over 1e9 times it. Forces are returned only for beta* above it.
INFEASIBLE_BETA = 1e-9

#: How far outside its cone, or above its limit, a returned force may be, relative to
#: s*: Clarabel's feasibility tolerance (1e-8 by default) with a margin for the exact
#: projection onto equilibrium that follows.
FORCE_TOL = 1e-6

#: Largest equilibrium residual |G f + W| of returned forces, for the unit wrench of the
#: normalised grasp: the exact projection leaves rounding (~1e-15) unless W is outside
#: the range of a rank-deficient G, which this catches.
EQUILIBRIUM_TOL = 1e-9

#: Returned forces must have s* within this relative distance of the dual lower bound:
#: the solve is then optimal to that accuracy, not merely feasible.
OPTIMALITY_TOL = 1e-6

#: Residual |G f + W| (unit wrench, normalised grasp) above which the projection onto
#: equilibrium by the normal equations is redone with the pseudo-inverse: ~1e-15 where
#: G G^T is well conditioned; far more where G is (nearly) rank-deficient.
NORMAL_EQUATIONS_TOL = 1e-12

#: Relative rounding slack of the dual wrench's work a = G^T w (~500 eps).
CERT_SLACK = 1e-13

#: Bisection steps for the root of the dual bound where limits make it piecewise linear
#: (2^-45, ~3e-14 of its bracket).
ROOT_BISECTIONS = 45

#: Tolerances of a lone retry of a grasp whose batch did not converge or whose answer
#: failed the checks.
RETRY_TOL = 1e-11


class GraspForces(NamedTuple):
    """What :func:`optimal_contact_forces` returns, one shape whatever the contacts."""

    #: s* = min over equilibrating forces of max_i n_i . f_i (force unit of the wrench),
    #: shape () or (N,): 0 for a zero wrench; inf where no forces within the cones (and
    #: limits) can hold the wrench; NaN where the solver could not decide.
    max_normal_force: np.ndarray
    #: Optimal contact forces (world frame), shape (n, 3) or (N, n, 3); NaN where s* is
    #: inf or NaN.
    forces: np.ndarray
    #: The torsional moment of each contact about its normal (force unit x length
    #: unit), shape (n,) or (N, n): 0 at hard contacts, NaN where ``forces`` is.
    torques: np.ndarray


def optimal_contact_forces(positions: npt.ArrayLike, normals: npt.ArrayLike,
                           mu: npt.ArrayLike, wrench: npt.ArrayLike,
                           max_normal_force: npt.ArrayLike | None = None,
                           torsional_friction: npt.ArrayLike | None = None
                           ) -> GraspForces:
    """The least largest normal force that holds a wrench, and the contact forces.

    Parameters
    ----------
    positions : array_like, shape (n, 3) or (N, n, 3)
        Contact positions, in the length unit of the torque.
    normals : array_like, same shape
        Inward contact normals, any non-zero length.
    mu : float or array_like broadcastable to (N, n)
        Friction coefficients, > 0.
    wrench : array_like, shape (6,) or (N, 6)
        External wrench on the object: force (3) then torque (3) about the origin of
        ``positions``. One grasp with an (M, 6) wrench is solved for each of the M.
    max_normal_force : None, float or array_like broadcastable to (N, n)
        Limit on each contact's normal force, >= 0 (inf: none); None for no limits.
    torsional_friction : None, float or array_like broadcastable to (N, n)
        gamma of soft contacts (>= 0, the positions' length unit; 0 or None: hard).

    Returns
    -------
    GraspForces
        ``(max_normal_force, forces, torques)``, a named tuple: s*, the optimal contact
        forces and their torsional moments (0 at hard contacts).

    Raises
    ------
    ValueError
        On bad input, naming the grasp (and contact, or wrench) that is wrong.
    """
    positions, normals, wrench, single = _broadcast_wrench(positions, normals, wrench)
    grasps = prepare_grasps(positions, normals, mu, torsional_friction)
    limits = _limits(max_normal_force, grasps.mu.shape)
    s_star, forces, torques = solve_contact_forces(grasps, wrench, limits)
    if torques is None:                                  # a hard batch
        torques = np.zeros(s_star.shape + forces.shape[1:2])
    torques[np.isnan(forces[..., 0])] = np.nan
    if single:
        return GraspForces(s_star[0], forces[0], torques[0])
    return GraspForces(s_star, forces, torques)


def _broadcast_wrench(positions: npt.ArrayLike, normals: npt.ArrayLike, wrench: npt.ArrayLike
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """Shapes: positions (N, n, 3), wrench (N, 6), and whether the caller gave one grasp."""
    p = np.asarray(positions, dtype=np.float64)
    nrm = np.asarray(normals, dtype=np.float64)
    w = np.asarray(wrench, dtype=np.float64)
    if w.ndim not in (1, 2) or w.shape[-1] != 6:
        raise ValueError(f"wrench must have shape (6,) or (N, 6), got {w.shape}")
    bad = np.flatnonzero(~np.isfinite(w.reshape(-1, 6)).all(axis=1))
    if bad.size:
        raise ValueError(f"wrench {bad[0]} is not finite")
    single = p.ndim == 2 and w.ndim == 1
    if p.ndim == 2:
        p, nrm = p[None], nrm[None]
        if w.ndim == 2:
            p = np.broadcast_to(p, (w.shape[0],) + p.shape[1:])
            nrm = np.broadcast_to(nrm, (w.shape[0],) + nrm.shape[1:])
    if p.ndim != 3 or p.shape[-1] != 3:
        raise ValueError(f"positions must have shape (n, 3) or (N, n, 3), got {p.shape}")
    try:
        w = np.broadcast_to(w, (p.shape[0], 6))
    except ValueError:
        raise ValueError(f"wrench of shape {w.shape} does not match {p.shape[0]} grasps") from None
    return p, nrm, w, single


def _limits(max_normal_force: npt.ArrayLike | None, shape: tuple[int, ...]) -> np.ndarray:
    """Per-contact limits (N, n), inf where unlimited; validated."""
    if max_normal_force is None:
        return np.full(shape, np.inf)
    raw = np.asarray(max_normal_force, dtype=np.float64)
    try:
        limits = np.broadcast_to(raw, shape)
    except ValueError:
        raise ValueError(f"max_normal_force of shape {raw.shape} does not broadcast to "
                         f"(grasps, contacts) = {shape}") from None
    bad = np.isnan(limits) | (limits < 0)
    if bad.any():
        g, i = np.argwhere(bad)[0]
        raise ValueError(f"grasp {g}, contact {i}: max_normal_force must be >= 0 "
                         f"(inf for none), got {limits[g, i]}")
    return limits


def solve_contact_forces(grasps: GraspBatch, wrench: np.ndarray, limits: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """:func:`optimal_contact_forces` on validated input.

    Parameters
    ----------
    grasps : GraspBatch
        N grasps of n contacts.
    wrench : ndarray, shape (N, 6)
    limits : ndarray, shape (N, n)
        Normal-force limits, inf where none.

    Returns
    -------
    s_star : ndarray, shape (N,)
    forces : ndarray, shape (N, n, 3)
    torques : ndarray, shape (N, n), or None for a hard batch
    """
    n_grasps, n_contacts = grasps.mu.shape
    model = model_of(grasps.torsional)
    unit, centroid, size = normalise_positions(grasps.positions)
    # Torque about the centroid, then in units of the grasp's size.
    torque = wrench[:, 3:] - np.cross(centroid, wrench[:, :3])
    scaled = np.concatenate([wrench[:, :3], torque / size[:, None]], axis=1)
    magnitude = np.linalg.norm(scaled, axis=1)
    direction = scaled / np.where(magnitude > 0, magnitude, 1.0)[:, None]
    relative_limits = limits / np.where(magnitude > 0, magnitude, 1.0)[:, None]

    torsional_unit = None if grasps.torsional is None else grasps.torsional / size[:, None]
    gmap = wrench_columns(grasp_maps(unit), grasps.normals, torsional_unit)
    column_scale, weight = ((None, None) if torsional_unit is None
                            else torsion_scales(torsional_unit))
    s_star = np.zeros(n_grasps)
    forces = np.zeros((n_grasps, n_contacts, model.components))
    loaded = np.flatnonzero(magnitude > 0)
    limited = bool(np.isfinite(limits).any())
    rest = loaded
    if model is HARD and loaded.size:
        s, f, ok = _fast_stage(unit[loaded], gmap[loaded], grasps.normals[loaded],
                               grasps.mu[loaded], direction[loaded], relative_limits[loaded])
        done = loaded[ok]
        s_star[done] = s[ok] * magnitude[done]
        forces[done] = f[ok] * magnitude[done, None, None]
        rest = loaded[~ok]
    for start in range(0, rest.size, SOLVE_BATCH):
        chunk = rest[start:start + SOLVE_BATCH]
        s, f = _clarabel_stage(gmap[chunk], grasps.normals[chunk], grasps.mu[chunk],
                               direction[chunk], relative_limits[chunk], limited, model,
                               None if weight is None else weight[chunk])
        s_star[chunk] = s * magnitude[chunk]
        forces[chunk] = f * magnitude[chunk, None, None]
    if column_scale is None:                             # hard
        return s_star, forces, None
    # tau = c rho in the unit grasp, times its size in the caller's unit.
    return s_star, forces[..., :3], column_scale * forces[..., 3] * size[:, None]


def _block_shape(n_contacts: int, limited: bool, d: int = 3) -> BlockShape:
    """Rows: G f + beta W = 0 (6); n.f <= 1 (n); [n.f <= beta f_max (n)]; Q^d per
    contact (d generalised force components, :mod:`.contact_model`)."""
    n_vars = d * n_contacts + 1
    n_nonneg = 2 * n_contacts if limited else n_contacts
    pattern = np.zeros((6 + n_nonneg + d * n_contacts, n_vars), dtype=bool)
    pattern[:6, :] = True
    for i in range(n_contacts):
        columns = slice(d * i, d * i + d)
        pattern[6 + i, columns] = True
        if limited:
            pattern[6 + n_contacts + i, columns] = True
            pattern[6 + n_contacts + i, -1] = True
        pattern[6 + n_nonneg + d * i:6 + n_nonneg + d * (i + 1), columns] = True
    return BlockShape(pattern, zero_rows=6, nonneg_rows=n_nonneg, soc_sizes=(d,) * n_contacts)


def _fast_stage(unit: np.ndarray, gmap: np.ndarray, normals: np.ndarray, mu: np.ndarray,
                direction: np.ndarray, limits: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The compiled stage (:mod:`.force_interior_point`) on K hard grasps, its answers
    checked by :func:`_check_answers`.

    Returns
    -------
    s_star : ndarray, shape (K,)
    forces : ndarray, shape (K, n, 3)
    ok : ndarray of bool, shape (K,)
        The kernel finished and its answer passed the checks; the others are for
        :func:`_clarabel_stage`.
    """
    codes, beta, _, forces, wrench = solve_fast_forces(unit, normals, mu, limits, direction,
                                                       FORCE_TOL, OPTIMALITY_TOL,
                                                       1.0 / INFEASIBLE_BETA)
    s_star, forces, ok = _check_answers(beta, forces.reshape(beta.size, -1), wrench, gmap,
                                        normals, mu, direction, limits)
    return s_star, forces, ok & (codes != UNDECIDED)


def _clarabel_stage(gmap: np.ndarray, normals: np.ndarray, mu: np.ndarray,
                    direction: np.ndarray, limits: np.ndarray, limited: bool,
                    model: ContactModel = HARD, weight: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """K grasps in one Clarabel solve, each failed one again alone with RETRY_TOL; NaN
    where that fails too. Returns (s_star (K,), forces (K, n, d)) for the unit wrench."""
    s, f, ok = _solve_and_check(gmap, normals, mu, direction, limits, limited, model, weight)
    for k in np.flatnonzero(~ok):
        lone = slice(k, k + 1)
        s[k], f[k], ok[k] = (v[0] for v in _solve_and_check(
            gmap[lone], normals[lone], mu[lone], direction[lone], limits[lone], limited, model,
            None if weight is None else weight[lone], tol=RETRY_TOL))
    s[~ok] = np.nan
    f[~ok] = np.nan
    return s, f


def _solve_and_check(gmap: np.ndarray, normals: np.ndarray, mu: np.ndarray,
                     direction: np.ndarray, limits: np.ndarray, limited: bool,
                     model: ContactModel = HARD, weight: np.ndarray | None = None,
                     tol: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Solve the homogenised problem for K grasps in one Clarabel solve and check each
    answer (:func:`_check_answers`)."""
    n_grasps, n_contacts = mu.shape
    d = model.components
    shape = _block_shape(n_contacts, limited, d)
    n_nonneg = shape.nonneg_rows
    tangent, bitangent = tangent_bases(normals)
    a = np.zeros((n_grasps,) + shape.pattern.shape)
    b = np.zeros((n_grasps, shape.pattern.shape[0]))
    a[:, :6, :-1] = gmap
    a[:, :6, -1] = direction
    cone = -cone_rows(normals, tangent, bitangent, mu, model, weight)  # (K, n, d, d)
    for i in range(n_contacts):
        columns = slice(d * i, d * i + 3)                              # the force part
        a[:, 6 + i, columns] = normals[:, i]
        if limited:
            finite = np.isfinite(limits[:, i])
            # An unlimited contact's row reads 0 <= 1.
            a[:, 6 + n_contacts + i, columns] = np.where(finite[:, None], normals[:, i], 0)
            a[:, 6 + n_contacts + i, -1] = -np.where(finite, limits[:, i], 0.0)
            b[:, 6 + n_contacts + i] = np.where(finite, 0.0, 1.0)
        a[:, 6 + n_nonneg + d * i:6 + n_nonneg + d * (i + 1), d * i:d * (i + 1)] = cone[:, i]
    b[:, 6:6 + n_contacts] = 1.0
    q = np.zeros((n_grasps, shape.pattern.shape[1]))
    q[:, -1] = -1.0
    solution = solve_stacked(shape, a, b, q, tol)
    beta = solution.x[:, -1]
    with np.errstate(divide="ignore", invalid="ignore"):
        forces = solution.x[:, :-1] / beta[:, None]
    return _check_answers(beta, forces, solution.z[:, :6], gmap, normals, mu, direction,
                          limits, weight)


def _check_answers(beta: np.ndarray, forces: np.ndarray, wrench: np.ndarray, gmap: np.ndarray,
                   normals: np.ndarray, mu: np.ndarray, direction: np.ndarray,
                   limits: np.ndarray, weight: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Check K solver answers of the homogenised problem (either stage's).

    Parameters
    ----------
    beta : ndarray, shape (K,)
    forces : ndarray, shape (K, d n)
        The solver's forces divided by beta (generalised components, d per contact).
    wrench : ndarray, shape (K, 6)
        The solver's dual wrench (either sign), for :func:`lower_bound`.
    gmap, normals, mu, direction, limits, weight
        As in :func:`lower_bound`.

    Returns
    -------
    s_star : ndarray, shape (K,)
        Largest normal force of the checked forces, for the unit wrench; inf where the
        dual bound is at least 1 / INFEASIBLE_BETA.
    forces : ndarray, shape (K, n, d)
        Generalised forces, projected onto equilibrium; NaN where s_star is inf.
    ok : ndarray of bool, shape (K,)
        The forces passed the checks and are optimal to OPTIMALITY_TOL, or the dual
        bound certifies s* = inf.
    """
    n_grasps, n_contacts = mu.shape
    d = forces.shape[1] // n_contacts
    lower = lower_bound(wrench, gmap, normals, mu, direction, limits, weight)
    infeasible = lower >= 1.0 / INFEASIBLE_BETA
    forces = _project_to_equilibrium(forces, gmap, direction).reshape(n_grasps, n_contacts, d)
    normal_part, tangential = split_normal(forces[..., :3], normals)
    if d == 4:  # the soft cone: |(f_t, mu w rho)| <= mu f_n
        tangential = np.hypot(tangential, mu * weight * forces[..., 3])
    s_star = normal_part.max(axis=1)
    slack = FORCE_TOL * np.abs(s_star)[:, None]
    residual = np.einsum("gkv,gv->gk", gmap, forces.reshape(n_grasps, -1)) + direction
    fits = ((tangential <= mu * normal_part + slack).all(axis=1)
            & (normal_part <= limits + slack).all(axis=1)
            & (np.linalg.norm(residual, axis=1) <= EQUILIBRIUM_TOL))
    optimal = s_star <= lower * (1.0 + OPTIMALITY_TOL)
    ok = infeasible | (fits & optimal & (beta > INFEASIBLE_BETA))
    s_star = np.where(infeasible, np.inf, s_star)
    forces[infeasible] = np.nan
    return s_star, forces, ok


def lower_bound(wrench: np.ndarray, gmap: np.ndarray, normals: np.ndarray, mu: np.ndarray,
                direction: np.ndarray, limits: np.ndarray,
                weight: np.ndarray | None = None) -> np.ndarray:
    """Lower bound on s* (unit wrench, normalised grasp) proved by a dual wrench w.

    For any feasible (f, beta) of the homogenised problem, 0 = w . (G f + beta W) =
    sum_i a_i . f_i + beta w . W with a_i = B_i w, and a_i . f_i <= f_n,i l_i,
    l_i = a_n,i + mu_i |a_t,i| (the cone), with 0 <= f_n,i <= min(1, beta f_max,i). So
    g(beta) = sum_i max(l_i, 0) min(1, beta f_max,i) - beta (-w . W) >= 0. g is concave
    with g(0) = 0: where -w . W > 0, beta* is at most g's positive root, and
    s* = 1 / beta* at least its inverse (inf if every l_i <= 0: no forces hold W).

    Parameters
    ----------
    wrench : ndarray, shape (K, 6)
        Candidate dual wrench (either sign is tried).
    gmap : ndarray, shape (K, 6, d n)
        d = 4 for soft batches: each contact's rho column adds work b_i = c_i
        n_i . w_torque, and l_i = a_n,i + |(mu_i (|a_t,i| + slack), |b_i| / w_i + slack)|
        (|b_i| / w_i = gamma_i |n_i . w_torque|, the support of the soft cone).
    normals : ndarray, shape (K, n, 3)
    mu : ndarray, shape (K, n)
    direction : ndarray, shape (K, 6)
        The unit external wrench.
    limits : ndarray, shape (K, n)
        Normal-force limits for the unit wrench, inf where none.
    weight : ndarray, shape (K, n), optional
        Soft: the cone weight w of rho (:func:`.contact_model.torsion_scales`).

    Returns
    -------
    ndarray, shape (K,)
        The bound, the work inflated by its rounding slack; 0 where w proves nothing.
    """
    work = np.einsum("gkv,gk->gv", gmap, wrench).reshape(normals.shape[:2] + (-1,))
    normal_part, tangential = split_normal(work[..., :3], normals)
    slack = (CERT_SLACK * np.abs(wrench).max(axis=1))[:, None]
    best = np.zeros(wrench.shape[0])
    friction_work = mu * (tangential + slack)
    if work.shape[-1] == 4:
        friction_work = np.hypot(friction_work, np.abs(work[..., 3]) / weight + slack)
    for sign in (1.0, -1.0):
        excess = np.maximum(sign * normal_part + slack + friction_work, 0.0)
        along = -sign * (wrench * direction).sum(axis=1) - slack[:, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            high = np.where(along > 0, excess.sum(axis=1) / along, np.inf)    # g(high) <= 0
        low = np.zeros_like(high)
        finite = np.isfinite(high) & (high > 0)
        # Without limits g is linear and ``high`` is its root: no search.
        for _ in range(ROOT_BISECTIONS if np.isfinite(limits).any() else 0):
            middle = 0.5 * (low + high)
            ok = _dual_room(np.where(finite, middle, 0.0), excess, limits, along) >= 0
            low, high = np.where(ok, middle, low), np.where(ok, high, middle)
        with np.errstate(divide="ignore"):
            bound = np.where(along > 0, 1.0 / high, 0.0)
        best = np.maximum(best, bound)
    return best


def _dual_room(beta: np.ndarray, excess: np.ndarray, limits: np.ndarray,
               along: np.ndarray) -> np.ndarray:
    """g(beta) of :func:`lower_bound`, shape (K,): its bound on the work, less beta (-w . W)."""
    finite = np.isfinite(limits)
    share = np.where(finite, np.minimum(1.0, beta[:, None] * np.where(finite, limits, 0.0)), 1.0)
    return (excess * share).sum(axis=1) - beta * along


def _project_to_equilibrium(forces: np.ndarray, gmap: np.ndarray,
                            direction: np.ndarray) -> np.ndarray:
    """The nearest forces (K, d n) with G f + W = 0 exactly (up to rounding).

    The correction G^T (G G^T)^-1 r of the residual r; where that leaves more than
    NORMAL_EQUATIONS_TOL of residual (G G^T singular or ill-conditioned: collinear
    contacts), the least-squares correction with the pseudo-inverse instead.

    Parameters
    ----------
    forces : ndarray, shape (K, d n)
    gmap : ndarray, shape (K, 6, d n)
    direction : ndarray, shape (K, 6)
    """
    residual = np.einsum("gkv,gv->gk", gmap, forces) + direction
    finite = np.isfinite(residual).all(axis=1)
    projected = forces.copy()
    if not finite.any():
        return projected
    g, r = gmap[finite], residual[finite]
    try:
        with np.errstate(all="ignore"):
            step = np.linalg.solve(g @ g.transpose(0, 2, 1), r[..., None])[..., 0]
            trial = forces[finite] - np.einsum("gkv,gk->gv", g, step)
            left = np.linalg.norm(np.einsum("gkv,gv->gk", g, trial) + direction[finite], axis=1)
        poor = ~(left <= NORMAL_EQUATIONS_TOL)
    except np.linalg.LinAlgError:  # a singular G G^T in the batch
        trial, poor = forces[finite].copy(), np.ones(r.shape[0], dtype=bool)
    if poor.any():
        pinv = np.linalg.pinv(g[poor])                                 # (K, d n, 6)
        trial[poor] = forces[finite][poor] - np.einsum("gvk,gk->gv", pinv, r[poor])
    projected[finite] = trial
    return projected
