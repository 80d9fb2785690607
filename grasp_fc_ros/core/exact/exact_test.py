"""The exact force-closure test: a second-order cone program, fast stage then Clarabel.

A grasp of n hard contacts with Coulomb friction is force closure iff its grasp map
G (6 x 3n) has rank 6 and some internal force lies strictly inside every friction cone
(Han, Trinkle and Li). The quadratic friction cone mu f_n >= |f_t| is a second-order
cone, so the internal-force question is an SOCP without any linearisation:

    maximise  t
    subject to  G f = 0                                      (equilibrium)
                sum_i n_i . f_i <= 1                         (bounds the forces)
                (mu_i n_i . f_i - t, f_i tangential) in Q^3  (each force t deep in its cone)

f = 0, t = 0 is always feasible and t is bounded, so the optimum t* >= 0 exists, and
t* > 0 iff a strictly internal force exists. t* (the *margin*) is unchanged by
translation, rotation and uniform scaling of the grasp.

Soft fingers (:mod:`.contact_model`): each contact also has a torsion variable rho,
the cone becomes (mu n_i . f_i - t, f_i tangential, mu_i w_i rho_i) in Q^4 and G gets
the columns (0, c_i n_i) (gamma scaled with the grasp, so t* stays invariant under
uniform scaling with gamma scaled along). Soft batches skip the fast stage.

Each grasp goes first to the fast stage (:mod:`.interior_point`), which decides it only
from a certificate: a verified internal force (force closure) or a wrench bounding t*
below ``MARGIN_TOL`` (not force closure). What it cannot certify (near the threshold,
near rank deficiency, numerical breakdown, its iteration limit) goes to the Clarabel
path below, which also serves the tests as the reference (``solve_exact(..., fast=False)``).
Both paths report t* as a certified interval [margin, margin_upper].

On the Clarabel path, many grasps are solved as one block-separable problem, so Python
and set-up costs are paid once per batch. Verdicts do not depend on the batch:

* force closure is reported only with a witness checked in numpy: the solver's forces,
  projected onto the null space of G, must lie ``MARGIN_TOL`` deep inside every cone
  after allowing for the rounding of the projection, with a total normal force that is
  positive beyond that rounding (:func:`.certificates.certified_internal_force`);
* not force closure is reported only when the grasp's optimum plus the whole batch's
  duality gap stays below ``MARGIN_TOL``, or when the solver's equilibrium multipliers,
  read as a wrench, bound t* below it (:func:`.certificates.wrench_bound`);
* anything in between, and every grasp of a batch whose solve did not reach Solved or
  AlmostSolved, is solved again on its own with tighter tolerances; if that too is
  undecided, the grasp is reported as a solver failure, never guessed.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any, TypeAlias

import clarabel
import numpy as np
from scipy import sparse  # clarabel's Python API takes scipy CSC matrices

from ..model.contact_model import (
    HARD,
    ContactModel,
    cone_rows,
    model_of,
    torsion_scales,
    wrench_columns,
)
from ..model.grasp_input import GraspBatch
from ..tolerances import MARGIN_TOL, RANK_TOL
from .certificates import certified_internal_force, grasp_maps, normalise_positions, wrench_bound
from .interior_point import FORCE_CLOSURE, UNDECIDED, solve_fast
from .stacked_socp import tangent_bases

#: What ``margin`` asks for (see :func:`solve_exact`).
MARGIN_CHOICES = ("optimum", "bound")

#: Grasps per Clarabel solve: CPU time per grasp is flat up to about this size and grows
#: beyond it, as the slowest grasp of a batch sets its iteration count (tuned:
#: docs/performance.md#exact-stage).
SOLVE_BATCH = 64

#: Per-grasp answers of the Clarabel path: force_closure, t_lo, t_hi, failure (or
#: undecided), forces, wrench.
BatchAnswers: TypeAlias = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                np.ndarray]

_ACCEPTED = (clarabel.SolverStatus.Solved, clarabel.SolverStatus.AlmostSolved)

#: Interior-point iterations allowed per solve. Batches here converge in 10-30; the
#: limit only ends a stuck solve, whose grasps are then retried alone.
MAX_ITERATIONS = 200

#: Gap and feasibility tolerances of a lone retry: five orders of magnitude below
#: MARGIN_TOL, so that the retry decides every grasp not within 1e-11 of the threshold.
RETRY_TOL = 1e-11


def _settings(tight: bool) -> clarabel.DefaultSettings:
    """Clarabel settings for a batch solve, or (``tight``) for a lone retry."""
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    settings.max_iter = MAX_ITERATIONS
    if tight:
        settings.tol_gap_abs = settings.tol_gap_rel = RETRY_TOL
        settings.tol_feas = RETRY_TOL
    else:
        # Iterative refinement of each KKT solve costs much of the batch solve time here
        # (docs/performance.md#exact-stage), and its accuracy is not needed: force closure
        # needs a witness verified in numpy, and grasps the batch cannot settle are
        # retried alone, refined.
        settings.iterative_refinement_enable = False
    return settings


@dataclass(frozen=True)
class ExactResult:
    """Exact verdicts of a batch of N grasps of n contacts.

    Attributes
    ----------
    force_closure : ndarray of bool, shape (N,)
        True only with a verified witness.
    margin : ndarray of float, shape (N,)
        A certified lower bound on the SOCP optimum t* (dimensionless, normal forces
        summing to one): the depth of a verified internal force, 0 where none was found,
        and 0 for a rank-deficient grasp map (whose margin is 0 by definition).
    margin_upper : ndarray of float, shape (N,)
        A certified upper bound on t* (from a wrench, :func:`.certificates.wrench_bound`);
        inf where none was found.
    solver_failure : ndarray of bool, shape (N,)
        The solver could not decide the grasp, even alone with tight tolerances.
    forces : ndarray, shape (N, n, 3)
        The verified internal force (normal parts summing to one, global components)
        where ``force_closure``; NaN elsewhere.
    wrench : ndarray, shape (N, 6)
        The bounding wrench about the centroid of the unit-size grasp (see
        :func:`.certificates.normalise_positions`) where not force closure; NaN where
        none.
    torques : ndarray, shape (N, n), or None
        Soft batches: the torsional moments tau_i about the normals of the internal force
        (caller's length unit, with ``forces``); None for hard batches.
    """

    force_closure: np.ndarray
    margin: np.ndarray
    margin_upper: np.ndarray
    solver_failure: np.ndarray
    forces: np.ndarray
    wrench: np.ndarray
    torques: np.ndarray | None = None


def solve_exact(grasps: GraspBatch, margin: str = "optimum", certificates: bool = False,
                fast: bool = True) -> ExactResult:
    """Run the exact test on every grasp of a validated batch.

    Parameters
    ----------
    grasps : GraspBatch
        N grasps of n contacts.
    margin : {"optimum", "bound"}
        "optimum": [margin, margin_upper] brackets t* within MARGIN_ACCURACY (where the
        fast stage decides; Clarabel's accuracy elsewhere). "bound": stop at the verdict;
        the interval is whatever was certified by then.
    certificates : bool
        Also look for a separating wrench of each not-force-closure grasp.
    fast : bool
        Try the fast interior-point stage first; False runs the Clarabel path alone
        (the reference the tests compare with). Soft batches (``grasps.torsional``)
        always run the Clarabel path: the fast stage is hard-only.

    Returns
    -------
    ExactResult
    """
    if margin not in MARGIN_CHOICES:
        raise ValueError(f"margin must be one of {MARGIN_CHOICES}, got {margin!r}")
    n_grasps, n_contacts = grasps.mu.shape
    model = model_of(grasps.torsional)
    if fast and model is HARD:
        # The kernel normalises each grasp itself: a numpy pass over the batch costs a
        # measurable share of the fast stage (docs/performance.md#exact-stage); the
        # Clarabel path below normalises only when it has grasps to solve.
        codes, t_lo, t_hi, _, forces, wrench = solve_fast(
            grasps.positions, grasps.normals, grasps.mu, margin == "optimum", certificates,
            normalise=True)
    else:
        codes = np.full(n_grasps, UNDECIDED)
        t_lo, t_hi = np.full(n_grasps, -np.inf), np.full(n_grasps, np.inf)
        forces = np.full((n_grasps, n_contacts, model.components), np.nan)
        wrench = np.full((n_grasps, 6), np.nan)
    force_closure = codes == FORCE_CLOSURE
    failure = np.zeros(n_grasps, dtype=bool)
    slow = np.flatnonzero(codes == UNDECIDED)
    torsional_unit = None
    if slow.size or model is not HARD:
        unit, _, size = normalise_positions(grasps.positions)
        # gamma in the unit grasp's length: torques scale with the grasp, forces do not.
        torsional_unit = None if model is HARD else grasps.torsional / size[:, None]
    if slow.size:
        (force_closure[slow], t_lo[slow], t_hi[slow], failure[slow], forces[slow],
         wrench[slow]) = _solve_clarabel(grasps, unit, slow, model, torsional_unit)
    forces[~force_closure] = np.nan
    wrench[force_closure] = np.nan
    torques = None
    if torsional_unit is not None:                       # soft
        # tau = c rho in the unit grasp, times its size in the caller's unit.
        column_scale = torsion_scales(torsional_unit)[0]
        forces, torques = forces[..., :3], column_scale * forces[..., 3] * size[:, None]
    return ExactResult(force_closure, np.maximum(t_lo, 0.0), t_hi, failure, forces, wrench,
                       torques)


def _solve_clarabel(grasps: GraspBatch, unit: np.ndarray, subset: np.ndarray,
                    model: ContactModel = HARD, torsional_unit: np.ndarray | None = None
                    ) -> BatchAnswers:
    """The Clarabel path on the grasps ``subset``: batched solves, lone retries.

    ``torsional_unit`` (N, n): gamma in the unit grasp's length, for a soft ``model``.

    Returns
    -------
    force_closure, t_lo, t_hi, failure : ndarrays, shape (k,)
    forces : ndarray, shape (k, n, d)
        Generalised forces (d = model.components).
    wrench : ndarray, shape (k, 6)
    """
    grasp_map = wrench_columns(grasp_maps(unit[subset]), grasps.normals[subset],
                               None if torsional_unit is None else torsional_unit[subset])
    left, singular, row_space = np.linalg.svd(grasp_map, full_matrices=False)
    sigma_min = singular[:, -1]
    full_rank = sigma_min > RANK_TOL * singular[:, 0]
    k, n_contacts = subset.size, grasps.mu.shape[1]
    force_closure = np.zeros(k, dtype=bool)
    failure = np.zeros(k, dtype=bool)
    # A rank-deficient grasp map leaves a wrench no contact force can resist: margin 0.
    t_lo, t_hi = np.zeros(k), np.where(full_rank, np.inf, 0.0)
    forces = np.full((k, n_contacts, model.components), np.nan)
    wrench = np.where(full_rank[:, None], np.nan, left[:, :, -1])
    candidates = np.flatnonzero(full_rank)
    for start in range(0, candidates.size, SOLVE_BATCH):
        chunk = candidates[start:start + SOLVE_BATCH]
        decided = _solve_batch(grasps, unit, grasp_map, row_space, sigma_min, subset, chunk,
                               tight=False, model=model, torsional_unit=torsional_unit)
        for position in np.flatnonzero(decided[3]):
            lone = chunk[position:position + 1]
            again = _solve_batch(grasps, unit, grasp_map, row_space, sigma_min, subset, lone,
                                 tight=True, model=model, torsional_unit=torsional_unit)
            for values, value in zip(decided, again, strict=True):
                values[position] = value[0]
        (force_closure[chunk], t_lo[chunk], t_hi[chunk], failure[chunk], forces[chunk],
         wrench[chunk]) = decided
    return force_closure, t_lo, t_hi, failure, forces, wrench


@lru_cache(maxsize=32)
def _socp_pattern(n_grasps: int, n_contacts: int, components: int = 3
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[int, int], list[Any],
                             sparse.csc_matrix]:
    """Sparsity pattern of the stacked constraint matrix A, fixed for (N, n, d).

    Rows: 6N equilibrium rows, then N force-bound rows, then d rows per contact for its
    second-order cone. Columns: per grasp, d n generalised forces (d = 3 hard, 4 soft,
    see :mod:`.contact_model`) then the margin t.
    Returns (indices, indptr, csc_order, shape, cones, zero P): the CSC structure of A,
    the order that puts values listed row-block by row-block into CSC order, and the
    cone list and the (empty) quadratic cost Clarabel needs.
    """
    d = components
    n_vars = d * n_contacts + 1
    grasp = np.arange(n_grasps)[:, None, None]
    force_cols = grasp * n_vars + np.arange(d * n_contacts)[None, None, :]   # (N,1,dn)
    margin_col = grasp[:, :, 0] * n_vars + d * n_contacts                     # (N,1)

    eq_rows = np.broadcast_to(grasp * 6 + np.arange(6)[None, :, None],
                              (n_grasps, 6, d * n_contacts))
    eq_cols = np.broadcast_to(force_cols, eq_rows.shape)
    bound_rows = np.broadcast_to(6 * n_grasps + grasp[:, :, 0], (n_grasps, d * n_contacts))
    bound_cols = force_cols[:, 0]
    soc_base = 7 * n_grasps + (grasp[:, :, 0] * n_contacts + np.arange(n_contacts)) * d  # (N, n)
    contact_cols = (grasp[:, :, 0] * n_vars)[..., None] + (
        np.arange(n_contacts)[:, None] * d + np.arange(d))                    # (N, n, d)
    soc_rows = np.broadcast_to(soc_base[:, :, None, None] + np.arange(d)[:, None],
                               (n_grasps, n_contacts, d, d))
    soc_cols = np.broadcast_to(contact_cols[:, :, None, :], soc_rows.shape)
    margin_rows = soc_base
    margin_cols = np.broadcast_to(margin_col, soc_base.shape)

    rows = np.concatenate([a.ravel() for a in (eq_rows, bound_rows, soc_rows, margin_rows)])
    cols = np.concatenate([a.ravel() for a in (eq_cols, bound_cols, soc_cols, margin_cols)])
    shape = (7 * n_grasps + d * n_contacts * n_grasps, n_grasps * n_vars)
    order = sparse.csc_matrix((np.arange(1, rows.size + 1, dtype=np.float64), (rows, cols)),
                              shape=shape)
    cones = ([clarabel.ZeroConeT(6 * n_grasps), clarabel.NonnegativeConeT(n_grasps)]
             + [clarabel.SecondOrderConeT(d)] * (n_grasps * n_contacts))
    no_quadratic_cost = sparse.csc_matrix((shape[1], shape[1]))
    return (order.indices, order.indptr, order.data.astype(np.int64) - 1, shape, cones,
            no_quadratic_cost)


def _solve_batch(grasps: GraspBatch, unit: np.ndarray, grasp_map: np.ndarray,
                 row_space: np.ndarray, sigma_min: np.ndarray, subset: np.ndarray,
                 chunk: np.ndarray, tight: bool, model: ContactModel = HARD,
                 torsional_unit: np.ndarray | None = None) -> BatchAnswers:
    """Solve the SOCP of the grasps ``subset[chunk]`` together and decide each one.

    ``grasp_map``, ``row_space`` and ``sigma_min`` are indexed like ``subset``;
    ``torsional_unit`` (gamma of the unit grasps, soft ``model`` only) like ``grasps``.

    Returns
    -------
    force_closure, t_lo, t_hi, undecided : ndarrays, shape (len(chunk),)
    forces : ndarray, shape (len(chunk), n, d)
    wrench : ndarray, shape (len(chunk), 6)
    """
    normals, mu = grasps.normals[subset[chunk]], grasps.mu[subset[chunk]]
    n_grasps, n_contacts = mu.shape
    d = model.components
    gamma = None if torsional_unit is None else torsional_unit[subset[chunk]]
    weight = None if gamma is None else torsion_scales(gamma)[1]
    tangent, bitangent = tangent_bases(normals)
    bound = normals if d == 3 else np.concatenate(
        [normals, np.zeros((n_grasps, n_contacts, 1))], axis=2)
    # Clarabel's form: A x + s = b with s in the cones, so each row of A holds -s(x).
    values = np.concatenate([
        grasp_map[chunk].ravel(),                                      # G f + s = 0, s = 0
        bound.reshape(n_grasps, -1).ravel(),                           # n.f + s = 1, s >= 0
        -cone_rows(normals, tangent, bitangent, mu, model, weight).ravel(),
        np.ones(n_grasps * n_contacts),                                # -(mu n.f - t)
    ])
    indices, indptr, order, shape, cones, p = _socp_pattern(n_grasps, n_contacts, d)
    a = sparse.csc_matrix((values[order], indices, indptr), shape=shape)
    b = np.zeros(shape[0])
    b[6 * n_grasps:7 * n_grasps] = 1.0
    n_vars = d * n_contacts + 1
    q = np.zeros(shape[1])
    q[n_vars - 1::n_vars] = -1.0

    solution = clarabel.DefaultSolver(p, q, a, b, cones, _settings(tight)).solve()
    x = np.asarray(solution.x).reshape(n_grasps, n_vars)
    witness, forces = certified_internal_force(
        x[:, :-1].reshape(n_grasps, n_contacts, d), grasp_map[chunk], row_space[chunk],
        sigma_min[chunk], normals, mu, model, weight)
    force_closure = witness >= MARGIN_TOL
    # The multipliers of the equilibrium rows are a wrench; either sign gives a valid
    # bound, so keep the better one.
    duals = np.asarray(solution.z)[:6 * n_grasps].reshape(n_grasps, 6)
    candidates = np.stack([duals, -duals])
    bounds = np.stack([wrench_bound(c, unit[subset[chunk]], normals, mu, gamma)[0]
                       for c in candidates])
    better = np.argmin(bounds, axis=0)
    upper = bounds[better, np.arange(n_grasps)]
    wrench = np.where(np.isfinite(upper)[:, None], candidates[better, np.arange(n_grasps)], np.nan)
    if solution.status in _ACCEPTED:
        gap = abs(solution.obj_val - solution.obj_val_dual)
        surely_not = (np.maximum(x[:, -1], 0.0) + gap < MARGIN_TOL) | (upper < MARGIN_TOL)
        undecided = ~force_closure & ~surely_not
    elif tight:
        undecided = ~force_closure
    else:
        # A batch that did not converge gives no optimum: retry every grasp alone.
        undecided = np.ones(n_grasps, dtype=bool)
    return force_closure, witness, upper, undecided, forces, wrench
