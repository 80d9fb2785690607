"""The minimum friction coefficient of a grasp, certified from both sides.

Contact i has friction ``mu * ratios_i``. The grasp is force closure for every mu above
a threshold mu* and for none below it (the cones grow with mu, and force closure asks
for a strictly internal force, an open condition), so mu* is the boundary

    mu* = inf over forces f with G f = 0, all f_n,i > 0  of  max_i |f_t,i| / (r_i f_n,i)

(with G of rank 6; mu* = inf otherwise). It is a generalised fractional program:
quasi-convex, one SOCP per fixed mu, not one SOCP. Each solve is the exact test's SOCP
with a signed margin,

    t(lam) = max t  s.t.  G f = 0,  sum_i f_n,i = 1,  (lam r_i f_n,i - t, f_t,i) in Q^3,

positive above mu* and not positive below; a safeguarded Newton/secant search (see
:class:`_RootState`) picks the next lam. Each solve runs the fast exact stage in its
signed mode (:func:`.interior_point.solve_fast`), Clarabel where that does not converge.
Every solve yields two certificates, both checked in numpy, never taken on trust:

* an upper bound: the solver's forces, projected exactly onto null(G), with every normal
  force positive, are inside every cone of friction ``U = max_i |f_t,i| / (r_i f_n,i)``
  (with a slack for rounding), so the grasp is force closure for every mu > U;
* a lower bound: the equilibrium multipliers give a wrench w; with a_i = B_i w the work
  of unit forces at contact i, it bounds the margin at any mu (:func:`margin_bound`); L is
  the largest mu where that bound is at most CERT_MARGIN. Where a_n,i + L r_i |a_t,i| <= 0
  for all i (every contact wrench in the half-space w . x <= 0) the bound is 0.

Iteration stops when U - L <= max(REL_TOL U, ABS_TOL); the answer is U. Rank-deficient
grasps, and grasps certified not force closure up to ``MU_CAP``, get inf; grasps with
U <= ABS_TOL get 0 (force closure for every positive friction, e.g. frictionless force
closure). The whole design and its measurements: docs/quality.md.

Relation to :func:`check_force_closure`: it reports force closure only with an internal
force at least ``MARGIN_TOL`` deep in every cone (normal forces summing to one), i.e. for
margin t*(mu) >= MARGIN_TOL, not t*(mu) > 0. Below mu* it therefore always says no. Just
above mu*, t*(mu) grows from 0 roughly like (mu - mu*) * min_i r_i f_n,i, so it says yes
only from mu* + O(MARGIN_TOL * n / r) on: at mu*(1 + 1e-5) only where that slope is large
enough. ``margin=MARGIN_TOL`` computes that numerical boundary instead (see
:func:`minimum_friction`).

Soft fingers (``torsional_friction``, :mod:`.contact_model`): gamma is fixed while mu
varies; the soft cone (mu f_n - t, f_t, mu w rho) in Q^4 still grows with mu, so mu*
is defined the same way. Each certificate gets the soft form: the upper bound is the
least mu with mu (f_n - d) - margin S >= |(|f_t| + d, mu w (|rho| + d))| (a quadratic
in mu), the lower bound's wrench does the torsional work |gamma n . w_torque| too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ..exact.certificates import grasp_maps, normalise_positions
from ..exact.interior_point import CONVERGED, solve_fast
from ..exact.stacked_socp import SOLVE_BATCH, BlockShape, solve_stacked, split_normal, tangent_bases
from ..model.contact_model import HARD, SOFT, ContactModel, model_of, torsion_scales, wrench_columns
from ..model.grasp_input import GraspBatch, prepare_grasps
from ..tolerances import MAX_FRICTION_COEFFICIENT, RANK_TOL

#: Relative and absolute width of the certified interval [L, U] at which iteration stops
#: (the issue's 1e-6 relative or 1e-9 absolute).
REL_TOL = 1e-6
ABS_TOL = 1e-9

#: A grasp certified not force closure at friction scale MU_CAP is reported inf. It is
#: the largest friction coefficient the core accepts (MAX_FRICTION_COEFFICIENT, 1e3; no
#: physical contact comes near it), so that inf means exactly "not force closure at any
#: friction check_force_closure can be asked about" (with ratios 1), and the search never
#: solves at frictions beyond those the solvers are known to handle (see
#: MAX_FRICTION_COEFFICIENT).
MU_CAP = MAX_FRICTION_COEFFICIENT

#: First friction tried when no closed-form upper bound is at hand, and the factor by
#: which it grows while no solve has found a witness.
MU_START = 10.0
ESCALATE = 100.0

#: SOCP solves allowed per grasp, well above what random grasps need
#: (docs/performance.md#minimum-friction): the limit only ends a grasp whose certificates
#: stall (it is then reported NaN, not guessed).
MAX_SOLVES = 40

#: A grasp whose solves improved neither bound this many times in a row (each after the
#: first alone, at a new lam) is given up: reported NaN with its certified bounds. Seen
#: on rare 4-finger box grasps (a lone side contact that only friction balances), where
#: Clarabel cannot resolve the margin (~1e-9) near mu* to the needed accuracy.
MAX_STALLS = 3

#: Relative rounding slack of the lower certificate: the work a = G^T w is computed to
#: about eps * |w|. 1e-13 is ~500 eps: generous, yet far below REL_TOL.
CERT_SLACK = 1e-13

#: Relative rounding bound of a sum of products (~ n eps for the sizes here, with room):
#: used to bound the equilibrium residual of witness forces and the eigenvalue of the
#: 6 x 6 matrix their correction solves with.
ROUNDING = 1e-14

#: Weights of the witness correction below this fraction of the largest are raised to
#: it, so that the 6 x 6 system stays solvable.
WEIGHT_FLOOR = 1e-12

#: Cone rows are scaled by max(lam, MARGIN_SCALE_FLOOR): below it, dividing by lam would
#: make the tangential rows too stiff for the solver, and 1e-3 already resolves lam to
#: ~1e-11 absolute, below ABS_TOL.
MARGIN_SCALE_FLOOR = 1e-3

#: The lower bound L certifies that at friction L no equilibrium force lies more than
#: CERT_MARGIN deep in every cone (the exact test's margin, normal forces summing to
#: one), not that the margin is exactly 0: a separating wrench must do exactly zero
#: work at contacts loaded strictly inside their cones, which floating point cannot
#: show. 1e-9 is three orders below MARGIN_TOL, under which check_force_closure already
#: calls a grasp not force closure, and above the solver's accuracy (~1e-11, SOLVER_TOL).
CERT_MARGIN = 1e-9

#: Clarabel's gap and feasibility tolerances here. Where a sub-grasp is in equilibrium
#: on its own, t(lam) is flat at 0 just below mu*, and the separating wrench must do no
#: work at that sub-grasp's contacts: only multipliers accurate far below CERT_MARGIN
#: certify anything there.
SOLVER_TOL = 1e-11

#: Primal-dual gap of the fast stage's solves, relative to the trivial bound 1/sigma on
#: the margin (so relative to lam, like SOLVER_TOL on Clarabel's scaled rows); what
#: does not reach it goes to Clarabel.
FAST_GAP = SOLVER_TOL

#: A fast solve that broke down before FAST_GAP is used all the same where its dual
#: objective and certified witness depth are this close (relative to 1/sigma). Near
#: mu* the kernel breaks down on some solves at gaps of up to ~1e-7; their certificates
#: are checked like any other, the search only steps from a slightly rougher margin, and
#: a solve that then improves neither bound is redone by Clarabel alone. Far fewer solves
#: go to Clarabel than with a tighter value, for the same solves per grasp (tuned:
#: docs/performance.md#minimum-friction).
FAST_ACCEPT = 1e-6

#: Bisection steps for the largest L a wrench certifies: 2^-32 (~2e-10) of the bracket,
#: far below REL_TOL.
LOWER_BISECTIONS = 32


@dataclass(frozen=True)
class MinimumFriction:
    """Certified bounds on mu* for N grasps, (N,) arrays (numpy scalars for one grasp).

    Attributes
    ----------
    value : ndarray of float
        mu*: the certified upper bound, 0 if that is <= ABS_TOL, inf if no friction up
        to MU_CAP (or none at all) makes the grasp force closure, NaN if not certified
        to the tolerance.
    lower, upper : ndarray of float
        Certified bounds: at ``lower`` and below, no equilibrium force is more than
        max(margin, CERT_MARGIN) deep in every cone (the exact test's margin; clipped
        to ``upper``); above ``upper`` some equilibrium force is more than ``margin``
        deep in every cone (force closure).
    solves : ndarray of int
        SOCP solves the grasp took (each the size of one exact test).
    """

    value: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    solves: np.ndarray


def minimum_friction(positions: npt.ArrayLike, normals: npt.ArrayLike,
                     ratios: npt.ArrayLike = 1.0, margin: float = 0.0,
                     torsional_friction: npt.ArrayLike | None = 0.0) -> np.ndarray:
    """The least friction coefficient at which a grasp is force closure.

    Parameters
    ----------
    positions : array_like, shape (n, 3) or (N, n, 3)
        Contact positions (any length unit).
    normals : array_like, same shape
        Inward contact normals, any non-zero length.
    ratios : float or array_like broadcastable to (N, n)
        Contact i has friction mu * ratios_i (> 0); 1 for equal friction everywhere.
    margin : float
        0 (default): the force-closure boundary itself. ``MARGIN_TOL``: the boundary of
        :func:`check_force_closure`'s verdict, the least mu whose exact-test margin
        t*(mu) reaches it (always > 0). Any margin in [0, 1) may be asked for.
    torsional_friction : float or array_like broadcastable to (N, n)
        gamma of soft contacts (>= 0, a length in the positions' unit; fixed while mu
        varies); 0 (default): hard contacts.

    Returns
    -------
    ndarray of float, shape () for one grasp or (N,)
        mu* (dimensionless), certified to REL_TOL relative or ABS_TOL absolute:
        force closure (margin above ``margin``) for every mu > mu*, and for no
        mu < mu* (margin at most max(margin, CERT_MARGIN)). 0: force closure for every
        positive friction; inf: for none up to MU_CAP; NaN: not certified to the
        tolerance (given up after MAX_STALLS fruitless solves, or MAX_SOLVES; rare,
        none in the tests; :func:`minimum_friction_bounds` still gives valid bounds).

    Raises
    ------
    ValueError
        On bad input, naming the grasp and contact.
    """
    return minimum_friction_bounds(positions, normals, ratios, margin,
                                   torsional_friction).value


def minimum_friction_bounds(positions: npt.ArrayLike, normals: npt.ArrayLike,
                            ratios: npt.ArrayLike = 1.0, margin: float = 0.0,
                            torsional_friction: npt.ArrayLike | None = 0.0) -> MinimumFriction:
    """:func:`minimum_friction` with its certified bounds and solve counts."""
    if not 0.0 <= margin < 1.0:
        raise ValueError(f"margin must be in [0, 1), got {margin}")
    try:
        grasps = prepare_grasps(positions, normals, ratios, torsional_friction)
    except ValueError as error:
        raise ValueError(str(error).replace("friction coefficient", "friction ratio")) from None
    lower, upper, solves = solve_minimum_friction(grasps, float(margin))
    value = np.where(upper <= ABS_TOL, 0.0, upper)
    value = np.where(lower >= MU_CAP, np.inf, value)
    value = np.where(_resolved(lower, upper), value, np.nan)
    # L certifies a margin of at most CERT_MARGIN, so for margin = 0 it may pass the
    # exact boundary by ~CERT_MARGIN / slope; U is a witness of force closure.
    lower = np.minimum(lower, upper)
    return MinimumFriction(*(grasps.unbatch(a) for a in (value, lower, upper, solves)))


def solve_minimum_friction(grasps: GraspBatch, margin: float = 0.0
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Certified bounds on mu* for every grasp of a validated batch (``mu`` = ratios).

    ``margin``: see :func:`minimum_friction`.

    Returns
    -------
    lower, upper : ndarray, shape (N,)
    solves : ndarray of int, shape (N,)
    """
    n_grasps = grasps.mu.shape[0]
    if n_grasps == 0:  # (an empty batch's (0, 0) reshapes below cannot infer their width)
        return np.empty(0), np.empty(0), np.zeros(0, dtype=np.int64)
    model = model_of(grasps.torsional)
    unit, _, size = normalise_positions(grasps.positions)
    torsional_unit = None if grasps.torsional is None else grasps.torsional / size[:, None]
    gmap = wrench_columns(grasp_maps(unit), grasps.normals, torsional_unit)   # (N, 6, d n)
    weight = None if torsional_unit is None else torsion_scales(torsional_unit)[1]
    singular = np.linalg.svd(gmap, compute_uv=False)
    full_rank = singular[:, -1] > RANK_TOL * singular[:, 0]
    state = _RootState.start(n_grasps, full_rank)
    lifted = _lifts_off(gmap, grasps.normals, grasps.mu, full_rank, weight)
    state.lower[lifted] = np.inf
    active = np.flatnonzero(full_rank & ~lifted)
    # Forces towards the centroid, f_i = c - p_i, are always in equilibrium (they pair
    # up along chords): where every one pushes into its contact, a free first bound.
    centroid_bound = upper_certificate(_generalised(-unit, model).reshape(n_grasps, -1), gmap,
                                       grasps.normals, grasps.mu, margin, weight)
    state.upper = np.where(full_rank, centroid_bound, np.inf)
    state.lam = np.where(np.isfinite(state.upper), state.upper, MU_START)
    for _ in range(MAX_SOLVES):
        if active.size == 0:
            break
        # The fast stage (hard contacts only) solves every grasp; what it cannot converge
        # goes to Clarabel in stacked solves. A grasp whose last solve improved neither
        # bound is solved by Clarabel alone: a stacked solve stops on the batch's
        # residuals, and near mu* one grasp may need more accuracy than its batch gave it.
        stalled = state.stalled[active]
        slow = (_step_fast(active[~stalled], state, unit, gmap, grasps, margin)
                if model is HARD else active[~stalled])
        chunks = [slow[start:start + SOLVE_BATCH] for start in range(0, slow.size, SOLVE_BATCH)]
        for chunk in chunks + [active[k:k + 1] for k in np.flatnonzero(stalled)]:
            _step(chunk, state, gmap, grasps, margin, weight)
        done = _resolved(state.lower[active], state.upper[active])
        active = active[~done & (state.stalls[active] < MAX_STALLS)]
    return state.lower, state.upper, state.solves


def _step(chunk: np.ndarray, state: _RootState, gmap: np.ndarray, grasps: GraspBatch,
          margin: float, weight: np.ndarray | None = None) -> None:
    """One stacked solve for the grasps ``chunk``: certificates, then the next lam.

    ``weight`` (N, n): soft batches' cone weights of rho (:mod:`.contact_model`)."""
    lam = state.lam[chunk]
    normals, ratios = grasps.normals[chunk], grasps.mu[chunk]
    weight = None if weight is None else weight[chunk]
    forces, wrench, depth, slope = _solve_chunk(gmap[chunk], normals, ratios, lam, weight)
    upper = upper_certificate(forces, gmap[chunk], normals, ratios, margin, weight)
    ceiling = np.where(np.isfinite(state.upper[chunk]), state.upper[chunk], MU_CAP)
    lower = lower_certificate(wrench, gmap[chunk], normals, ratios, ceiling, margin, weight)
    state.update(chunk, lam, depth - margin, slope, lower, upper)


def _generalised(vectors: np.ndarray, model: ContactModel) -> np.ndarray:
    """Per-contact 3-vectors (K, n, 3) as generalised forces (K, n, d): rho = 0."""
    if model is HARD:
        return vectors
    return np.concatenate([vectors, np.zeros(vectors.shape[:2] + (1,))], axis=2)


def _components(gmap: np.ndarray, normals: np.ndarray) -> int:
    """Generalised components per contact of a (generalised) grasp map: 3 or 4."""
    return gmap.shape[2] // normals.shape[1]


def _step_fast(chunk: np.ndarray, state: _RootState, unit: np.ndarray, gmap: np.ndarray,
               grasps: GraspBatch, margin: float) -> np.ndarray:
    """One fast-stage solve for the grasps ``chunk`` (as :func:`_step`); returns those
    (a subset of ``chunk``) it did not solve accurately enough, for Clarabel, their
    state untouched."""
    if chunk.size == 0:
        return chunk
    lam = state.lam[chunk]
    normals, ratios = grasps.normals[chunk], grasps.mu[chunk]
    friction = lam[:, None] * ratios
    codes, depth, _, _, forces, wrench = solve_fast(unit[chunk], normals, friction,
                                                    signed_gap=FAST_GAP, signed_level=margin)
    forces = forces.reshape(chunk.size, 3 * normals.shape[1])
    slope, gap = _fast_slope_and_gap(forces, wrench, gmap[chunk], normals, friction, ratios,
                                     depth)
    with np.errstate(invalid="ignore"):
        done = (codes == CONVERGED) | (gap <= FAST_ACCEPT)
    slow = chunk[~done]
    if not done.any():  # the certificates below need at least one grasp
        return slow
    chunk, lam, normals, ratios = chunk[done], lam[done], normals[done], ratios[done]
    forces, wrench, depth, slope = forces[done], wrench[done], depth[done], slope[done]
    upper = upper_certificate(forces, gmap[chunk], normals, ratios, margin)
    ceiling = np.where(np.isfinite(state.upper[chunk]), state.upper[chunk], MU_CAP)
    lower = lower_certificate(wrench, gmap[chunk], normals, ratios, ceiling, margin)
    state.update(chunk, lam, depth - margin, slope, lower, upper)
    return slow


def _fast_slope_and_gap(forces: np.ndarray, wrench: np.ndarray, gmap: np.ndarray,
                        normals: np.ndarray, friction: np.ndarray, ratios: np.ndarray,
                        depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """dt/dlam (K,) at the fast stage's optimum, by the envelope theorem, and the gap
    (K,) between the wrench's dual objective and the witness depth, times sigma.

    The kernel's wrench w gives the cone multipliers' first components
    y_i = (1 + d.w - a_n,i) / (sigma mu_i), a_n,i = Bn_i . w (they sum to one), and
    dt/dlam = sum_i y_i r_i c_n,i for the witness' normal forces c_n,i; its dual
    objective is (1 + d.w) / sigma.
    """
    work = np.einsum("gkv,gk->gv", gmap, wrench).reshape(normals.shape)
    work_normal = (work * normals).sum(axis=2)
    sigma = (1.0 / friction).sum(axis=1, keepdims=True)
    d_w = (work_normal / friction).sum(axis=1, keepdims=True) / sigma
    multiplier = (1.0 + d_w - work_normal) / (sigma * friction)
    normal_force = (forces.reshape(normals.shape) * normals).sum(axis=2)
    slope = (multiplier * ratios * normal_force).sum(axis=1)
    return slope, 1.0 + d_w[:, 0] - sigma[:, 0] * depth


def _lifts_off(gmap: np.ndarray, normals: np.ndarray, ratios: np.ndarray,
               full_rank: np.ndarray, weight: np.ndarray | None = None) -> np.ndarray:
    """Grasps (N,) certified not force closure up to MU_CAP without a solve.

    Where the normals' work is a combination of the rows of G (G^T w = the normals: the
    twist w lifts every contact straight off), every equilibrium has zero total normal
    force, and the SOCP (sum f_n = 1) is infeasible, which would fail its whole stacked
    batch. The least-squares w is checked like any other certificate.
    """
    gram = np.einsum("gkv,gjv->gkj", gmap, gmap)
    gram[~full_rank] = np.eye(6)
    model = SOFT if _components(gmap, normals) == 4 else HARD
    normal_work = np.einsum("gkv,gv->gk", gmap,
                            _generalised(normals, model).reshape(len(gmap), -1))
    lift_wrench = np.linalg.solve(gram, normal_work[..., None])[..., 0]
    ceiling = np.full(len(gmap), MU_CAP)
    return full_rank & (lower_certificate(lift_wrench, gmap, normals, ratios, ceiling,
                                          weight=weight)
                        >= MU_CAP)


def _resolved(lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Where the bounds (same shape) are tight enough, or certify no friction up to MU_CAP."""
    with np.errstate(invalid="ignore"):
        close = upper - lower <= np.maximum(REL_TOL * upper, ABS_TOL)
    return (np.isfinite(upper) & close) | (lower >= MU_CAP)


@dataclass
class _RootState:
    """Per-grasp state of the safeguarded search for the sign change of t(lam).

    t(lam) is the signed margin solved at lam, less the margin asked for: positive above
    mu*, not positive below. The search runs on q = t / t' (t' from the multipliers):
    where t behaves like (lam - mu*)^m, q is (lam - mu*) / m, a simple root, also where
    the margin vanishes quadratically (a contact's normal force vanishing at mu* too).
    Each step is the secant on q through the last two solves (a Newton step after the
    first, or when the secant leaves the certified interval (L, U)); a step a little
    outside is clamped to the end, one far outside is replaced by bisecting (L, U)
    (geometrically while it spans orders of magnitude). A step within a quarter of the
    target width of L or U is moved to half that width from it: one solve on the far
    side of mu* then finishes.
    """

    lower: np.ndarray
    upper: np.ndarray
    lam: np.ndarray
    solves: np.ndarray
    latest: np.ndarray        # (N, 2): lam, q of the latest solve (NaN: none)
    previous: np.ndarray      # (N, 2): the solve before
    stalled: np.ndarray       # (N,) bool: the latest solve improved neither bound
    stalls: np.ndarray        # (N,) int: solves in a row that improved neither

    @classmethod
    def start(cls, n_grasps: int, full_rank: np.ndarray) -> _RootState:
        """The state before any solve: L = 0 (inf where G has rank < 6), U = inf."""
        none = np.full((n_grasps, 2), np.nan)
        return cls(lower=np.where(full_rank, 0.0, np.inf), upper=np.full(n_grasps, np.inf),
                   lam=np.full(n_grasps, MU_START), solves=np.zeros(n_grasps, dtype=np.int64),
                   latest=none.copy(), previous=none.copy(),
                   stalled=np.zeros(n_grasps, dtype=bool),
                   stalls=np.zeros(n_grasps, dtype=np.int64))

    def update(self, chunk: np.ndarray, lam: np.ndarray, margin: np.ndarray,
               slope: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> None:
        """Take one solve's certificates and margins; choose the next lam of each grasp."""
        self.solves[chunk] += 1
        stalled = (lower <= self.lower[chunk]) & (upper >= self.upper[chunk])
        self.stalled[chunk] = stalled
        self.stalls[chunk] = np.where(stalled, self.stalls[chunk] + 1, 0)
        self.lower[chunk] = np.maximum(self.lower[chunk], lower)
        self.upper[chunk] = np.minimum(self.upper[chunk], upper)
        self.previous[chunk] = self.latest[chunk]
        # The secant runs on q = t / t', which is (lam - mu*) / m wherever t behaves like
        # (lam - mu*)^m: a simple root even where the margin vanishes quadratically.
        with np.errstate(divide="ignore", invalid="ignore"):
            quotient = np.where(slope > 0, margin / slope, np.nan)
        self.latest[chunk] = np.stack([lam, quotient], axis=1)
        self.lam[chunk] = self._next(chunk)

    def _next(self, chunk: np.ndarray) -> np.ndarray:
        """The next lam (len(chunk),) of each grasp, by the rules of the class docstring."""
        lower, upper = self.lower[chunk], self.upper[chunk]
        (lam1, q1), (lam0, q0) = self.latest[chunk].T, self.previous[chunk].T
        span = upper - lower
        with np.errstate(divide="ignore", invalid="ignore"):
            secant = lam1 - q1 * (lam1 - lam0) / (q1 - q0)
            newton = lam1 - q1
            # A step may land a little outside (L, U) when one end is already close to
            # mu*: it is clamped to that end (and nudged below). Far outside: discarded.
            secant_near = (secant > lower - 0.01 * span) & (secant < upper + 0.01 * span)
            newton_near = (newton > lower - 0.01 * span) & (newton < upper + 0.01 * span)
        middle = np.where(upper > 4.0 * lower, np.sqrt(np.maximum(lower, ABS_TOL) * upper),
                          0.5 * (lower + upper))
        guess = np.where(secant_near, secant, np.where(newton_near, newton, middle))
        guess = np.clip(guess, lower, upper)
        # Within a quarter of the target width of an end: step to half the width from
        # it, so that one solve on the far side of mu* finishes.
        from_lower = np.maximum(REL_TOL * lower, ABS_TOL)
        from_upper = np.maximum(REL_TOL * upper, ABS_TOL)
        with np.errstate(invalid="ignore"):         # inf - inf where no witness yet
            guess = np.where(guess - lower < 0.25 * from_lower, lower + 0.5 * from_lower, guess)
            guess = np.where(upper - guess < 0.25 * from_upper, upper - 0.5 * from_upper, guess)
        # After a solve that improved neither bound, step as far again from the nearer end.
        away = np.where(lam1 - lower < upper - lam1, 2 * lam1 - lower, 2 * lam1 - upper)
        guess = np.where(self.stalled[chunk], np.clip(away, lower, upper), guess)
        # No witness yet: try ESCALATE times more friction (at least the lower bound).
        escalated = np.minimum(np.maximum(self.lam[chunk] * ESCALATE, lower), MU_CAP)
        return np.where(np.isfinite(upper), guess, escalated)


def _block_shape(n_contacts: int, d: int = 3) -> BlockShape:
    """Rows: G f = 0 (6), sum f_n = 1 (1), one Q^d per contact. Columns: f (d n), t."""
    n_vars = d * n_contacts + 1
    pattern = np.zeros((7 + d * n_contacts, n_vars), dtype=bool)
    pattern[:7, :d * n_contacts] = True
    for i in range(n_contacts):
        rows = slice(7 + d * i, 7 + d * (i + 1))
        pattern[rows, d * i:d * (i + 1)] = True
        pattern[7 + d * i, -1] = True
    return BlockShape(pattern, zero_rows=7, nonneg_rows=0, soc_sizes=(d,) * n_contacts)


def _solve_chunk(gmap: np.ndarray, normals: np.ndarray, ratios: np.ndarray, lam: np.ndarray,
                 weight: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The signed-margin SOCP at friction lam * ratios for each grasp of a chunk (K).

        maximise t  s.t.  G f = 0,  sum_i f_n,i = 1,  (lam r_i f_n,i - t, f_t,i) in Q^3

    Each cone's rows are divided by s = max(lam, MARGIN_SCALE_FLOOR) (a cone is closed
    under scaling) and the variable is t / s: its optimum is then relative to lam, so the
    solver's absolute accuracy resolves lam relatively, for small and large lam alike.

    Soft batches (a generalised ``gmap`` of 4 columns per contact, cone weights
    ``weight`` (K, n)) add the cone row lam r_i w_i rho_i / s.

    Returns
    -------
    forces : ndarray, shape (K, d n)
    wrench : ndarray, shape (K, 6)
        Multipliers of the equilibrium rows.
    depth : ndarray, shape (K,)
        The solver's optimum t (the signed margin of the exact test).
    """
    n_grasps, n_contacts = ratios.shape
    d = _components(gmap, normals)
    shape = _block_shape(n_contacts, d)
    tangent, bitangent = tangent_bases(normals)
    scale = np.maximum(lam, MARGIN_SCALE_FLOOR)
    a = np.zeros((n_grasps,) + shape.pattern.shape)
    a[:, :6, :-1] = gmap
    a[:, 6, :-1] = _generalised(normals, SOFT if d == 4 else HARD).reshape(n_grasps, -1)
    # Clarabel's form A x + s = b, s in the cone: each cone row of A holds -s(x).
    cone = -np.stack([((lam / scale)[:, None] * ratios)[..., None] * normals,
                      tangent / scale[:, None, None], bitangent / scale[:, None, None]],
                     axis=2)                                           # (K, n, 3, 3)
    for i in range(n_contacts):
        a[:, 7 + d * i:10 + d * i, d * i:d * i + 3] = cone[:, i]
        if weight is not None:                           # soft: d = 4
            a[:, 10 + d * i, d * i + 3] = -(lam / scale) * ratios[:, i] * weight[:, i]
        a[:, 7 + d * i, -1] = 1.0
    b = np.zeros((n_grasps, shape.pattern.shape[0]))
    b[:, 6] = 1.0
    q = np.zeros((n_grasps, shape.pattern.shape[1]))
    q[:, -1] = -1.0
    solution = solve_stacked(shape, a, b, q, SOLVER_TOL)
    if not solution.converged and n_grasps > 1:
        parts = [solve_stacked(shape, a[k:k + 1], b[k:k + 1], q[k:k + 1], SOLVER_TOL)
                 for k in range(n_grasps)]
        x = np.concatenate([p.x for p in parts])
        z = np.concatenate([p.z for p in parts])
    else:
        x, z = solution.x, solution.z
    # dt/dlam by the envelope theorem: sum_i (cone i's multiplier on its first row)
    # * r_i f_n,i; the rows' scaling by s cancels against t = s t'.
    cone_first = z[:, 7::d][:, :n_contacts]
    per_contact = x[:, :-1].reshape(n_grasps, n_contacts, d)
    normal_force = (per_contact[..., :3] * normals).sum(axis=2)
    slope = (cone_first * ratios * normal_force).sum(axis=1)
    if d == 4:  # the rho row scales with lam too: its multiplier times r_i w_i rho_i
        slope += (z[:, 10::d][:, :n_contacts] * ratios * weight
                  * per_contact[..., 3]).sum(axis=1)
    return x[:, :-1], z[:, :6], x[:, -1] * scale, slope


def upper_certificate(forces: np.ndarray, gmap: np.ndarray, normals: np.ndarray,
                      ratios: np.ndarray, margin: float = 0.0,
                      cone_weight: np.ndarray | None = None) -> np.ndarray:
    """The friction above which the given forces prove force closure with ``margin``.

    The forces are moved onto null(G) by a weighted least-norm correction that loads it
    onto the contacts carrying the most normal force (weights f_n,i), so that contacts
    carrying almost nothing near mu* keep their cone depth; the distance from the result
    to an exact equilibrium is bounded per contact and taken off every depth. (Weights
    f_n,i^2 would make G W G^T nearly singular where a weak contact is needed for rank 6,
    and the bound on the strong contacts' distance useless.)

    Parameters
    ----------
    forces : ndarray, shape (K, d n)
        Candidate (generalised) contact forces, world frame, of grasps normalised to
        unit size.
    gmap : ndarray, shape (K, 6, d n)
    normals : ndarray, shape (K, n, 3)
    ratios : ndarray, shape (K, n)
    margin : float
        Depth t >= 0 the forces must have in every cone (normal forces summing to one).
        Soft contacts: the least mu with mu c - margin S >= |(A, mu B)|, c = f_n - d,
        A = |f_t| + d, B = w (|rho| + d), the larger root of its quadratic (inf unless
        c > B).
    cone_weight : ndarray, shape (K, n), optional
        Soft: the cone weight w of rho (:func:`.contact_model.torsion_scales`).

    Returns
    -------
    ndarray, shape (K,)
        max_i (|f_t,i| + d_i + margin S) / (r_i (f_n,i - d_i)) of the corrected forces,
        d_i the bound on contact i's distance to exact equilibrium and S an upper bound
        on the total normal force; inf where some f_n,i - d_i is not positive. Above it
        some equilibrium force is more than ``margin`` deep in every cone (relative to
        its total normal force), so the exact test's margin t*(mu) exceeds ``margin``.
    """
    n_grasps, n_contacts = ratios.shape
    d = _components(gmap, normals)
    per_contact = forces.reshape(n_grasps, n_contacts, d)[..., :3]
    normal_part = (per_contact * normals).sum(axis=2)
    weight = np.maximum(normal_part, 0.0)
    weight = np.maximum(weight, WEIGHT_FLOOR * weight.max(axis=1, keepdims=True) + 1e-300)
    column_weight = np.repeat(weight, d, axis=1)                       # (K, d n)
    weighted_map = gmap * column_weight[:, None, :]
    normal_matrix = np.einsum("gkv,gjv->gkj", weighted_map, gmap)      # G W G^T (K, 6, 6)
    smallest = np.linalg.eigvalsh(normal_matrix)[:, 0]
    smallest -= ROUNDING * np.abs(normal_matrix).sum(axis=(1, 2))
    solvable = smallest > 0                     # False for a rank-deficient G
    normal_matrix[~solvable] = np.eye(6)
    corrected = forces - np.einsum("gkv,gk->gv", weighted_map, np.linalg.solve(
        normal_matrix, np.einsum("gkv,gv->gk", gmap, forces)[..., None])[..., 0])
    # An exact equilibrium is h - W G^T y, y = M^-1 r, r = G h the corrected forces'
    # residual (bounded with its rounding). Its contact i moves by w_i |G_i^T y|, and
    # w_i |G_i^T y|^2 <= y^T M y = r^T M^-1 r <= |r|^2 / lambda_min(M), so by at most
    # sqrt(w_i / lambda_min) |r|: small at weak contacts, and not inflated at strong ones
    # by a weak contact that M's smallest eigenvalue depends on.
    residual = np.linalg.norm(np.einsum("gkv,gv->gk", gmap, corrected), axis=1)
    residual += ROUNDING * np.einsum("gkv,gv->g", np.abs(gmap), np.abs(corrected))
    with np.errstate(divide="ignore", invalid="ignore"):
        distance = np.where(solvable[:, None],
                            np.sqrt(weight / smallest[:, None]) * residual[:, None], np.inf)
    generalised = corrected.reshape(n_grasps, n_contacts, d)
    normal_part, tangential = split_normal(generalised[..., :3], normals)
    valid = (normal_part > distance).all(axis=1)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        total = (normal_part + distance).sum(axis=1, keepdims=True)
        if d == 3:
            ratio = (tangential + distance + margin * total) / (ratios * (normal_part - distance))
            return np.where(valid, ratio.max(axis=1), np.inf)
        c, need = normal_part - distance, margin * total
        along = tangential + distance
        twist = cone_weight * (np.abs(generalised[..., 3]) + distance)
        room = c * c - twist * twist
        root = (c * need + np.sqrt(np.maximum(c * c * need * need
                                              - room * (need * need - along * along), 0.0)))
        ratio = np.where(room > 0, root / room, np.inf) / ratios
        return np.where(valid, ratio.max(axis=1), np.inf)


def margin_bound(mu: np.ndarray, work_normal: np.ndarray, work_tangential: np.ndarray,
                 ratios: np.ndarray, work_twist: np.ndarray | None = None) -> np.ndarray:
    """Upper bound on the exact test's margin t*(mu) proved by one wrench.

    If a wrench w does work a_i = B_i w on unit forces at contact i, with
    a_n,i <= work_normal_i and |a_t,i| <= work_tangential_i, then any equilibrium with
    normal forces summing to one and every force t deep in its cone has
    t <= max(l0, 0) / S, where l0 = max_i (a_n,i + mu_i |a_t,i|) and
    S = sum_i (l0 - a_n,i) / mu_i (mu_i = mu r_i): the equilibrium's total work against
    w is zero, each cone bounds its contact's work, and each normal force is >= t / mu_i.

    Parameters
    ----------
    mu : ndarray, shape (K,)
    work_normal, work_tangential : ndarray, shape (K, n)
    ratios : ndarray, shape (K, n)
    work_twist : ndarray, shape (K, n), optional
        Soft contacts: a bound on |gamma_i n_i . w_torque|, the work of unit torsion;
        l0 = max_i (a_n,i + |(mu_i |a_t,i|, twist_i)|), the rest as above.

    Returns
    -------
    ndarray, shape (K,)
        The bound (0 where w separates: every contact wrench does work <= 0); inf where
        S is not positive (w does no work at any contact, e.g. w = 0: no information).
    """
    friction = mu[:, None] * ratios
    if work_twist is None:
        l0 = (work_normal + friction * work_tangential).max(axis=1)
    else:
        l0 = (work_normal + np.hypot(friction * work_tangential, work_twist)).max(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        total = ((np.maximum(l0, 0.0)[:, None] - work_normal) / friction).sum(axis=1)
        bound = np.where(l0 > 0, np.maximum(l0, 0.0) / total, 0.0)
    return np.where(total > 0, bound, np.inf)


def lower_certificate(wrench: np.ndarray, gmap: np.ndarray, normals: np.ndarray,
                      ratios: np.ndarray, ceiling: np.ndarray, margin: float = 0.0,
                      weight: np.ndarray | None = None) -> np.ndarray:
    """The largest friction at which a wrench proves the margin at most ``margin``.

    Parameters
    ----------
    wrench : ndarray, shape (K, 6)
        Candidate separating wrench (either sign is tried), of grasps of unit size.
    gmap : ndarray, shape (K, 6, d n)
        d = 4 (soft): the rho columns' work b_i = c_i n_i . w_torque counts too, as
        |b_i| / w_i = gamma_i |n_i . w_torque| per unit normal force (``weight``: the
        cone weights w of :func:`.contact_model.torsion_scales`).
    normals : ndarray, shape (K, n, 3)
    ratios : ndarray, shape (K, n)
    ceiling : ndarray, shape (K,)
        Search no higher than this (a finite upper bound on mu*, or MU_CAP).
    margin : float
        The margin to certify against; CERT_MARGIN is used where it is larger.

    Returns
    -------
    ndarray, shape (K,)
        L in [0, ceiling] with :func:`margin_bound` (L) <= max(margin, CERT_MARGIN) for
        the better sign of w, the work inflated by its rounding slack; 0 if none. t*(mu)
        only grows with mu, so the bound holds at every mu <= L too.
    """
    work = np.einsum("gkv,gk->gv", gmap, wrench).reshape(normals.shape[:2] + (-1,))
    normal_part, tangential = split_normal(work[..., :3], normals)
    slack = (CERT_SLACK * np.abs(wrench).max(axis=1))[:, None]
    threshold = max(margin, CERT_MARGIN)
    # Both signs of w at once: rows [w; -w], shape (2K, n).
    work_normal = np.concatenate([normal_part, -normal_part]) + np.tile(slack, (2, 1))
    work_tangential = np.tile(tangential + slack, (2, 1))
    both_ratios, ceiling = np.tile(ratios, (2, 1)), np.tile(ceiling, 2)
    twist = None if work.shape[-1] == 3 else np.tile(np.abs(work[..., 3]) / weight + slack,
                                                     (2, 1))
    # Where w strictly separates (no work > 0 anywhere), the closed form: the largest mu
    # with a_n,i + mu r_i |a_t,i| <= 0 for all i (soft: a_n,i + |(mu r_i |a_t,i|, b_i)|
    # <= 0, i.e. a_n,i <= -|b_i| and mu r_i |a_t,i| <= sqrt(a_n,i^2 - b_i^2)); the
    # bisection starts from there.
    reach = -work_normal if twist is None else np.sqrt(np.maximum(
        work_normal * work_normal - twist * twist, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        separating = (reach / (both_ratios * work_tangential)).min(axis=1)
    strict = ((work_normal <= 0).all(axis=1) if twist is None
              else (work_normal + twist <= 0).all(axis=1))
    strict &= np.tile(slack[:, 0], 2) > 0                              # w = 0: nothing
    low = np.minimum(np.where(strict, separating, 0.0), ceiling)
    high = ceiling.copy()
    holds = margin_bound(high, work_normal, work_tangential, both_ratios, twist) <= threshold
    low[holds] = high[holds]
    for _ in range(LOWER_BISECTIONS):
        middle = 0.5 * (low + high)
        ok = margin_bound(middle, work_normal, work_tangential, both_ratios, twist) <= threshold
        low, high = np.where(ok, middle, low), np.where(ok, high, middle)
    best = np.maximum(low[:len(wrench)], low[len(wrench):])
    return best
