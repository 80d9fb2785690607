"""The fast exact stage: a small interior-point method for this SOCP family (numba).

The margin problem of :mod:`.exact_test`, with the normalisation row eliminated
(sigma = sum_i 1/mu_i, d = sum_i Bn_i / (mu_i sigma), B_i the 3 x 6 map from the wrench w
to the local work vector of contact i, Bn_i its normal row, Bt_i its tangential rows):

    primal  min sum_i z0_i   s.t.  sum_i A_i z_i = -d,  z_i in Q^3,
            A_i = [Bn_i - d, -mu_i Bt_i^T]
            (forces: t = (1 - sum z0) / sigma, c_n,i = z0_i + t/mu_i, c_t,i = -mu_i z_t,i)
    dual    max -d . w       s.t.  s_i = (1 + d.w - Bn_i.w, mu_i Bt_i w) in Q^3.

Six dual variables whatever the number of contacts, so each iteration solves one 6 x 6
system. Both sides start strictly feasible (w = 0; z from the normal forces 1/(mu_i sigma)
projected onto equilibrium), and a primal-dual method with Nesterov-Todd scaling and
Mehrotra's predictor-corrector keeps them so.

The method decides from certificates, never from convergence: after every iteration
(iteration 0 included; with the optimum asked for, only once the iterates' objectives
are within ``CHECK_GAP``, since before that no certificate can close the interval; for
verdicts, the witness only where the iterate's forces before projection are deep enough
to matter, ``WITNESS_SKIP_SLACK``) it checks

* force closure: the iterate's forces, projected onto equilibrium, lie ``MARGIN_TOL``
  deep in every cone after allowing for rounding (the same bound as
  :func:`.certificates.certified_internal_force`, with the closed-form projection of a
  centred grasp);
* not force closure: the iterate's wrench bounds t* below ``MARGIN_TOL``, with rounding
  (the bound of :func:`.certificates.wrench_bound`).

With the optimum asked for, the same certificates are also taken at the affine
(predictor) point where it is likely to close the interval (``AFFINE_CHECK_GAP``): each
side's Newton step to its cone boundary, which near the optimum is far closer to it than
the damped, centred iterate that follows.

It returns a grasp as undecided (for the Clarabel path) when the grasp map's rank is not
clearly 6, when equilibrium forces with a positive total normal force are nearly absent
(contacts that nearly share one normal), on any numerical breakdown, and at the
iteration limit. Compiled with ``cache=True``: numba stores the machine code next to this
file, or in the user's cache directory when the install is read-only; call
:func:`warm_up` before serving queries to pay the compile (or cache load) up front.
"""

from __future__ import annotations

from typing import TypeAlias

import numpy as np

from .._kernels.cones import (
    MIN_STEP,
    STEP_FRACTION,
    inverse_square_apply,
    jordan_divide,
    jordan_product,
    nt_unit_scaling,
    scaled_apply,
    scaled_inverse_apply,
    scaling_of,
    step_within,
)
from .._kernels.frames import normal_split, tangent_frames, work_at, wrench_rows
from .._kernels.grasp_map import apply_grasp_map, certified_rank, normalise_grasp
from .._kernels.jit import Vector3, jit, jit_fused, kernel_array, row
from .._kernels.linear_algebra import (
    Diagonal6,
    diagonal_reciprocals,
    ldl,
    ldl_substitute,
    substitute,
)
from ..tolerances import (
    MARGIN_ACCURACY,
    MARGIN_TOL,
    ROUNDING_SLACK,
    SEPARATION_TARGET,
    SHARED_NORMAL_TOL,
)

#: Result codes of the kernel. CONVERGED: the signed mode's gap closed (no verdict).
FORCE_CLOSURE, NOT_FORCE_CLOSURE, UNDECIDED, CONVERGED = 0, 1, 2, 3

#: What :func:`solve_fast` returns: codes, t_lo, t_hi, iterations, forces, wrench.
FastResult: TypeAlias = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                              np.ndarray]

#: Iterations before a grasp is handed to the Clarabel path. Verdicts and margins take a
#: few on average (docs/performance.md#exact-stage); 40 only bounds a stuck or marginal
#: grasp.
MAX_ITERATIONS = 40

#: Centring with the optimum asked for: sigma = min(CAP, (1 - alpha_aff)^1.5) instead
#: of Mehrotra's (1 - alpha_aff)^3, which is kept for verdicts. Iterating to the optimum,
#: the cube centres too little in the late iterations (short affine steps, slowly
#: shrinking gaps); this rule takes fewer iterations to the margin, while on verdicts the
#: cube is the faster (tuned: docs/performance.md#exact-stage).
OPTIMUM_CENTRING_CAP = 0.1

_EPS = float(np.finfo(np.float64).eps)

#: The step to the cone boundary whose STEP_FRACTION is a full step: the corrector's
#: search for the boundary stops there.
FULL_REACH = 1.0 / STEP_FRACTION

#: For verdicts, the witness is computed only where it could raise max(t_lo, 0): where
#: :func:`_unprojected_depth` exceeds it less this allowance, which covers the
#: projection's rounding (~1e-15) many times over. A speed heuristic only (it pays on
#: verdicts; with the optimum asked for, where ``CHECK_GAP`` already gates the witness,
#: it does not and is not used; tuned: docs/performance.md#exact-stage): a skipped
#: witness could have changed neither the verdict nor the reported interval (t_lo enters
#: both only through max(t_lo, 0); a certifying witness is MARGIN_TOL deep), and a
#: mistaken skip only costs an iteration.
WITNESS_SKIP_SLACK = 1e-9

#: With ``want_optimum``, the certificate checks are skipped while the iterates' primal
#: and dual objectives are more than this apart (10 MARGIN_ACCURACY): they cannot close
#: the interval yet (the certified width is a sizeable part of the objectives' gap). A
#: speed heuristic only: every return is still from a checked iterate (tuned:
#: docs/performance.md#exact-stage).
CHECK_GAP = 1e-7

#: With the optimum asked for, the affine point's certificates are checked where the
#: gap it would leave, (1 - alpha_aff) times the iterate's (relative to 1/sigma), is below
#: this (5 MARGIN_ACCURACY): about where they can close the interval, which is about half
#: the gap wide. A speed heuristic only (tuned: docs/performance.md#exact-stage).
AFFINE_CHECK_GAP = 5e-8

#: The signed mode also stops where its gap is this fraction of the margin's distance
#: from the level searched for: far from mu*, the search's next step and the
#: certificates need no more.
SIGNED_RELATIVE_GAP = 1e-3

#: Relative rounding allowance of the trivial bound t* <= 1 / sum_i (1/mu_i): the sum
#: of n <= ~1e3 positive terms errs by far less than n eps.
TRIVIAL_BOUND_SLACK = 1e-12


@jit
def _witness(unit: np.ndarray, normals: np.ndarray, tangent: np.ndarray,
             bitangent: np.ndarray, mu: np.ndarray, z: np.ndarray, sigma: float,
             gram_factor: np.ndarray, gram_inverse: Diagonal6, sigma_min: float,
             grasp_norm: float, forces: np.ndarray, y: np.ndarray, check: np.ndarray,
             scratch: np.ndarray) -> tuple[float, float]:
    """Certified depth of the forces of primal iterate z (n, 3), and their total normal
    force; the projected forces go to ``forces`` (n, 3), to be scaled by the total (only
    where the depth is kept). Depth -inf when the total is not positive. ``gram_inverse``
    is :func:`._kernels.linear_algebra.diagonal_reciprocals` of ``gram_factor``."""
    n = unit.shape[0]
    total_z0 = 0.0
    for i in range(n):
        total_z0 += z[i, 0]
    t = (1.0 - total_z0) / sigma
    for i in range(n):
        c_n = z[i, 0] + t / mu[i]
        for k in range(3):
            forces[i, k] = c_n * normals[i, k] - mu[i] * (z[i, 1] * tangent[i, k]
                                                          + z[i, 2] * bitangent[i, k])
    apply_grasp_map(unit, forces, check)
    substitute(gram_factor, gram_inverse, check, y, scratch)
    size = 0.0
    for i in range(n):
        g0, g1, g2 = work_at(y, row(unit, i))                         # G_i^T y
        forces[i, 0] -= g0
        forces[i, 1] -= g1
        forces[i, 2] -= g2
        size += forces[i, 0] ** 2 + forces[i, 1] ** 2 + forces[i, 2] ** 2
    apply_grasp_map(unit, forces, check)
    residual = 0.0
    for r in range(6):
        residual += check[r] * check[r]
    residual = np.sqrt(residual)
    reach = (residual + ROUNDING_SLACK * _EPS * 3 * n * grasp_norm * np.sqrt(size)) / sigma_min
    total = 0.0
    worst = np.inf
    for i in range(n):
        f_n, tangential = normal_split(row(forces, i), row(normals, i))
        worst = min(worst, mu[i] * f_n - tangential - (mu[i] + 1.0) * reach)
        total += f_n
    slack = np.sqrt(n) * reach
    if not total - slack > 0.0:
        return -np.inf, total
    return worst / (total + slack), total


@jit
def _verdict(t_lo: float, t_hi: float, separated: bool, want_optimum: bool,
             want_wrench: bool) -> int:
    """FORCE_CLOSURE or NOT_FORCE_CLOSURE where the certified interval [t_lo, t_hi] on
    t* settles the verdict (and, with ``want_optimum``, is MARGIN_ACCURACY wide, and with
    ``want_wrench`` a not-force-closure grasp has a separating wrench); else UNDECIDED."""
    close = t_hi - max(t_lo, 0.0) <= MARGIN_ACCURACY
    if t_lo >= MARGIN_TOL and (close or not want_optimum):
        return FORCE_CLOSURE
    if t_hi < MARGIN_TOL and (separated or not want_wrench) and (close or not want_optimum):
        return NOT_FORCE_CLOSURE
    return UNDECIDED


@jit
def _unprojected_depth(z: np.ndarray, mu: np.ndarray, t_p: float) -> float:
    """Depth t_p + min_i mu_i (z0_i - |z_t,i|) of the forces of primal iterate z before
    the projection onto equilibrium (mu_i c_n,i - |c_t,i| = t_p + mu_i (z0_i - |z_t,i|),
    normal forces summing to one): the iterates are in equilibrium up to rounding, so
    :func:`_witness` certifies at most this plus rounding, at a fraction of its cost."""
    lowest = np.inf
    for i in range(z.shape[0]):
        lowest = min(lowest, mu[i] * (z[i, 0] - np.sqrt(z[i, 1] * z[i, 1] + z[i, 2] * z[i, 2])))
    return t_p + lowest


@jit
def _bound(unit: np.ndarray, normals: np.ndarray, mu: np.ndarray, w: np.ndarray,
           normal_work: np.ndarray) -> tuple[float, bool]:
    """Certified upper bound on t* from wrench w (6,), and whether w meets the
    separation target (L <= SEPARATION_TARGET max_j |a_j|)."""
    n = unit.shape[0]
    force_norm = np.sqrt(w[0] ** 2 + w[1] ** 2 + w[2] ** 2)
    torque_norm = np.sqrt(w[3] ** 2 + w[4] ** 2 + w[5] ** 2)
    error = ROUNDING_SLACK * _EPS * (force_norm + 2.0 * torque_norm)
    level = -np.inf
    largest_square = 0.0
    mu_max = 0.0
    for i in range(n):
        a0, a1, a2 = work_at(w, row(unit, i))
        a_n, a_t = normal_split((a0, a1, a2), row(normals, i))
        normal_work[i] = a_n
        level = max(level, a_n + mu[i] * a_t)
        largest_square = max(largest_square, a0 * a0 + a1 * a1 + a2 * a2)
        mu_max = max(mu_max, mu[i])
    # One root for max_j |a_j|: a correctly rounded root is monotone, so this is the
    # largest of the n roots exactly.
    largest = np.sqrt(largest_square)
    raw_level = level
    level += (1.0 + mu_max) * error
    spread = 0.0
    for i in range(n):
        spread += (level - normal_work[i] - error) / mu[i]
    spread *= 1.0 - 1e-12
    bound = max(level, 0.0) / spread if spread > 0.0 else np.inf
    return bound, raw_level <= SEPARATION_TARGET * largest


#: A 6-vector (a wrench) passed by value between kernels.
Vector6: TypeAlias = tuple[float, float, float, float, float, float]


@jit_fused
def _block_times(a_mat: np.ndarray, i: int, x: Vector3) -> Vector6:
    """A_i x for contact i's 6 x 3 block ``a_mat[i]`` and a 3-vector x.

    As a tuple, and with x passed by value: the callers' loops store into arrays that
    the compiler cannot tell apart from their operands, and would reload those after
    every store (tuned: docs/performance.md#exact-stage).
    """
    x0, x1, x2 = x
    return (a_mat[i, 0, 0] * x0 + a_mat[i, 0, 1] * x1 + a_mat[i, 0, 2] * x2,
            a_mat[i, 1, 0] * x0 + a_mat[i, 1, 1] * x1 + a_mat[i, 1, 2] * x2,
            a_mat[i, 2, 0] * x0 + a_mat[i, 2, 1] * x1 + a_mat[i, 2, 2] * x2,
            a_mat[i, 3, 0] * x0 + a_mat[i, 3, 1] * x1 + a_mat[i, 3, 2] * x2,
            a_mat[i, 4, 0] * x0 + a_mat[i, 4, 1] * x1 + a_mat[i, 4, 2] * x2,
            a_mat[i, 5, 0] * x0 + a_mat[i, 5, 1] * x1 + a_mat[i, 5, 2] * x2)


@jit_fused
def _block_transposed_times(a_mat: np.ndarray, i: int, v: Vector6) -> Vector3:
    """A_i^T v for contact i's 6 x 3 block ``a_mat[i]`` and a 6-vector v (see
    :func:`_block_times`)."""
    v0, v1, v2, v3, v4, v5 = v
    return (a_mat[i, 0, 0] * v0 + a_mat[i, 1, 0] * v1 + a_mat[i, 2, 0] * v2
            + a_mat[i, 3, 0] * v3 + a_mat[i, 4, 0] * v4 + a_mat[i, 5, 0] * v5,
            a_mat[i, 0, 1] * v0 + a_mat[i, 1, 1] * v1 + a_mat[i, 2, 1] * v2
            + a_mat[i, 3, 1] * v3 + a_mat[i, 4, 1] * v4 + a_mat[i, 5, 1] * v5,
            a_mat[i, 0, 2] * v0 + a_mat[i, 1, 2] * v1 + a_mat[i, 2, 2] * v2
            + a_mat[i, 3, 2] * v3 + a_mat[i, 4, 2] * v4 + a_mat[i, 5, 2] * v5)


@jit_fused
def _vector6(values: np.ndarray) -> Vector6:
    """A (6,) array as a tuple (see :func:`_block_times`)."""
    return values[0], values[1], values[2], values[3], values[4], values[5]


@jit_fused
def _solve_grasp(unit: np.ndarray, normals: np.ndarray, mu: np.ndarray, want_optimum: bool,
                 want_wrench: bool, signed_gap: float, signed_level: float,
                 forces_out: np.ndarray, wrench_out: np.ndarray, work3: np.ndarray,
                 work6: np.ndarray, rows: np.ndarray, a_mat: np.ndarray, scalings: np.ndarray,
                 mats: np.ndarray, work_n: np.ndarray,
                 a_gram: np.ndarray) -> tuple[int, float, float, int]:
    """Decide one unit-size grasp. Returns (code, t_lo, t_hi, iterations).

    ``signed_gap`` > 0 selects the signed mode (for :mod:`.minimum_friction`): no verdict;
    iterate until the primal-dual gap of the signed margin, (1 + d.w)/sigma - (1 - sum_i
    z0_i)/sigma, is at most ``signed_gap / sigma`` (relative to the trivial bound 1/sigma,
    so relative to the friction scale) or at most SIGNED_RELATIVE_GAP of |t - signed_level|
    (times sigma; the search's distance from its root), and return CONVERGED with the
    best witness in ``forces_out`` and the last iterate's wrench in ``wrench_out`` (the
    optimum's multipliers).

    The remaining arguments are scratch space of the batch, reused from grasp to grasp
    (allocating it per grasp would cost a large share of the run time): work3 (12, n, 3),
    work6 (13, 6), rows (3, n, 6), a_mat (n, 6, 3), scalings (n, 6), mats (4, 6, 6),
    work_n (2, n), a_gram (n, 6, 6).
    """
    n = unit.shape[0]
    (tangent, bitangent, z, s, z_affine, jv, lam, dz, ds, u_aff, winv_q,
     projected) = (work3[0], work3[1], work3[2], work3[3], work3[4], work3[5], work3[6],
                   work3[7], work3[8], work3[9], work3[10], work3[11])
    d, trial, g_sum, solved, gg_d, y6, w, rhs, dw, scratch, check, y, w_affine = (
        work6[0], work6[1], work6[2], work6[3], work6[4], work6[5], work6[6], work6[7],
        work6[8], work6[9], work6[10], work6[11], work6[12])
    b_n, b_t1, b_t2 = rows[0], rows[1], rows[2]
    gram, gram_factor, hessian, factor = mats[0], mats[1], mats[2], mats[3]
    inv_eta2, normal_work = work_n[0], work_n[1]

    sigma_min, grasp_norm = certified_rank(unit, gram, gram_factor, scratch)
    if not sigma_min > 0.0:
        return UNDECIDED, -np.inf, np.inf, 0
    gram_inverse = diagonal_reciprocals(gram_factor)
    # A first trial wrench: pull against the mean inward normal. It separates every
    # grasp whose normals all lie in one open half-space around it, e.g. contacts
    # sharing a face, which the interior-point start below cannot handle.
    trial[:] = 0.0
    for i in range(n):
        for k in range(3):
            trial[k] -= normals[i, k]
    bound, separating = _bound(unit, normals, mu, trial, normal_work)
    signed = signed_gap > 0.0
    if bound < MARGIN_TOL and (separating or not want_wrench) and not signed:
        wrench_out[:] = trial
        return NOT_FORCE_CLOSURE, -np.inf, bound, 0
    tangent_frames(normals, tangent, bitangent)
    wrench_rows(unit, normals, b_n)
    wrench_rows(unit, tangent, b_t1)
    wrench_rows(unit, bitangent, b_t2)
    sigma = 0.0
    d[:] = 0.0
    for i in range(n):
        sigma += 1.0 / mu[i]
        for r in range(6):
            d[r] += b_n[i, r] / mu[i]
    for r in range(6):
        d[r] /= sigma

    # Feasible start: forces n_i / (mu_i sigma) projected onto {G f = 0, sum n.f = 1}.
    # Schur complement of the normalisation row: ~0 when every equilibrium force has
    # (nearly) zero total normal force, e.g. contacts sharing one normal.
    g_sum[:] = 0.0
    for i in range(n):
        for r in range(6):
            g_sum[r] += b_n[i, r]
    substitute(gram_factor, gram_inverse, g_sum, solved, scratch)
    schur = n - np.dot(g_sum, solved)
    if not schur > SHARED_NORMAL_TOL * n:
        return UNDECIDED, -np.inf, np.inf, 0
    # y = (y6, y7) of (M M^T) y = (d, 0): y7 = -g.GG^-1 d / schur, y6 = GG^-1 (d - g y7).
    substitute(gram_factor, gram_inverse, d, gg_d, scratch)
    y7 = -np.dot(g_sum, gg_d) / schur
    for r in range(6):
        solved[r] = d[r] - g_sum[r] * y7
    substitute(gram_factor, gram_inverse, solved, y6, scratch)
    start_t = np.inf
    for i in range(n):
        u = unit[i]
        scale = 1.0 / (mu[i] * sigma) - y7
        f0 = scale * normals[i, 0] - (y6[0] + y6[4] * u[2] - y6[5] * u[1])
        f1 = scale * normals[i, 1] - (y6[1] + y6[5] * u[0] - y6[3] * u[2])
        f2 = scale * normals[i, 2] - (y6[2] + y6[3] * u[1] - y6[4] * u[0])
        c_n = f0 * normals[i, 0] + f1 * normals[i, 1] + f2 * normals[i, 2]
        c_t1 = f0 * tangent[i, 0] + f1 * tangent[i, 1] + f2 * tangent[i, 2]
        c_t2 = f0 * bitangent[i, 0] + f1 * bitangent[i, 1] + f2 * bitangent[i, 2]
        z[i, 0], z[i, 1], z[i, 2] = c_n, c_t1, c_t2
        start_t = min(start_t, mu[i] * c_n - np.sqrt(c_t1 * c_t1 + c_t2 * c_t2))
    start_t -= 1.0 / sigma
    for i in range(n):
        c_n, c_t1, c_t2 = z[i, 0], z[i, 1], z[i, 2]
        z[i, 0] = (mu[i] * c_n - start_t) / mu[i]
        z[i, 1], z[i, 2] = -c_t1 / mu[i], -c_t2 / mu[i]

    for i in range(n):
        for r in range(6):
            a_mat[i, r, 0] = b_n[i, r] - d[r]
            a_mat[i, r, 1] = -mu[i] * b_t1[i, r]
            a_mat[i, r, 2] = -mu[i] * b_t2[i, r]
    w[:] = 0.0
    # mu_i c_n,i >= t at every contact and sum_i c_n,i = 1 give t* <= 1 / sigma.
    t_lo, t_hi = -np.inf, (1.0 + TRIVIAL_BOUND_SLACK) / sigma
    separated = False
    iteration = 0
    last = False     # a breakdown: check the current iterate in full, then stop
    # The dual slacks s_i = e - A_i^T w, here at w = 0; each step updates them along
    # with w (s moves by -A_i^T dw, the ds of the step), which saves recomputing them
    # from w (tuned: docs/performance.md#exact-stage). Rounding of the update only: no
    # certificate reads s.
    for i in range(n):
        s[i, 0], s[i, 1], s[i, 2] = 1.0, 0.0, 0.0
    while True:
        d_w = 0.0
        for r in range(6):
            d_w += d[r] * w[r]
        total_z0 = 0.0
        for i in range(n):
            total_z0 += z[i, 0]
        # The iterates' primal and dual objectives (uncertified). With the optimum asked
        # for, a certificate can end the run only once the interval is MARGIN_ACCURACY
        # wide, so while they are CHECK_GAP apart the checks are skipped (the witness
        # while t_p is also that far below t_hi; the bound while t_p > 0 shows the grasp
        # is not to be rejected).
        t_p = (1.0 - total_z0) / sigma
        wide = (want_optimum and not signed and not last and iteration < MAX_ITERATIONS
                and (1.0 + d_w) / sigma - t_p > CHECK_GAP)
        if not (wide and t_p < t_hi - CHECK_GAP) and (
                want_optimum or signed
                or _unprojected_depth(z, mu, t_p) > max(t_lo, 0.0) - WITNESS_SKIP_SLACK):
            depth, total = _witness(unit, normals, tangent, bitangent, mu, z, sigma,
                                    gram_factor, gram_inverse, sigma_min, grasp_norm,
                                    projected, y, check, scratch)
            if depth > t_lo:
                t_lo = depth
                for i in range(n):
                    for k in range(3):
                        forces_out[i, k] = projected[i, k] / total
        if iteration > 0 and not (wide and t_p > 0.0):
            bound, separating = _bound(unit, normals, mu, w, normal_work)
            if (separating and not separated) or (bound < t_hi and not separated):
                wrench_out[:] = w
                separated = separating
            t_hi = min(t_hi, bound)
        if signed:
            wrench_out[:] = w
            # Dual minus primal objective of the iterates, times sigma: small against
            # signed_gap, or against the margin's distance from signed_level (a search
            # step needs no more).
            distance = abs(1.0 - total_z0 - sigma * signed_level)
            if d_w + total_z0 <= max(signed_gap, SIGNED_RELATIVE_GAP * distance):
                return CONVERGED, t_lo, t_hi, iteration
        else:
            code = _verdict(t_lo, t_hi, separated, want_optimum, want_wrench)
            if code != UNDECIDED:
                return code, t_lo, t_hi, iteration
        if last or iteration == MAX_ITERATIONS:
            break

        # Newton system: H dw = rhs, H = sum A_i W_i^-2 A_i^T, with W_i^-2 = (2 (Jv)(Jv)^T
        # - J) / eta^2: A_i W_i^-2 A_i^T = (2 g g^T - A_i J A_i^T) / eta^2, g = A_i J v;
        # A_i J A_i^T does not change, so it is kept from the first iteration (a_gram)
        # and each later one costs a rank-one update.
        # The scalings first, in a loop of their own: each is a chain of roots and
        # divisions, and only a short loop body lets those of several contacts overlap
        # (tuned: docs/performance.md#exact-stage).
        finite = True
        for i in range(n):
            inv_eta2[i], scaling, inverse_vector = nt_unit_scaling(row(z, i), row(s, i))
            if not np.isfinite(inv_eta2[i]):
                finite = False
                break
            scalings[i, 0], scalings[i, 1], scalings[i, 2] = scaling[0], scaling[1], scaling[2]
            scalings[i, 3], scalings[i, 4], scalings[i, 5] = scaling[3], scaling[4], scaling[5]
            jv[i, 0], jv[i, 1], jv[i, 2] = inverse_vector
            lam[i, 0], lam[i, 1], lam[i, 2] = scaled_apply(scaling, row(z, i))
        if not finite:
            last = True
            continue
        hessian[:] = 0.0
        gap = 0.0
        for i in range(n):
            g_i = _block_times(a_mat, i, row(jv, i))
            weight = inv_eta2[i]
            if iteration == 0:
                for r in range(6):
                    for c in range(r + 1):
                        a_gram[i, r, c] = (a_mat[i, r, 1] * a_mat[i, c, 1]
                                           + a_mat[i, r, 2] * a_mat[i, c, 2]
                                           - a_mat[i, r, 0] * a_mat[i, c, 0])
            for r in range(6):
                for c in range(r + 1):
                    hessian[r, c] += weight * (2.0 * g_i[r] * g_i[c] + a_gram[i, r, c])
            gap += z[i, 0] * s[i, 0] + z[i, 1] * s[i, 1] + z[i, 2] * s[i, 2]
        if not ldl(hessian, factor):               # (it reads the lower triangle only)
            last = True
            continue
        # Predictor (affine) direction: lam o (W dz + W^-1 ds) = -lam o lam gives
        # W dz + W^-1 ds = -lam, W^-1 (-lam) = -z, and the right-hand side -r_p + sum_i
        # A_i z_i is -d exactly (r_p = sum_i A_i z_i + d): no residual, no Jordan division.
        # In scaled form, u = W^-1 ds and W dz = -lam - u; W maps the cone onto itself,
        # so the step to its boundary is that of lam along u and along -lam - u. With
        # W = eta Wbar, the arrays hold lam / eta = Wbar z and u / eta = J Wbar J ds /
        # eta^2, which give the same steps without the root eta (nt_unit_scaling).
        for r in range(6):
            rhs[r] = -d[r]
        ldl_substitute(factor, rhs, dw)
        # (Only steps up to 1 are used below: the search stops there.)
        alpha_dual = alpha_primal = 1.0
        step = _vector6(dw)
        for i in range(n):
            ds_i = _block_transposed_times(a_mat, i, step)
            ds[i, 0], ds[i, 1], ds[i, 2] = -ds_i[0], -ds_i[1], -ds_i[2]
            u = scaled_inverse_apply(scaling_of(scalings, i), inv_eta2[i], row(ds, i))
            u_aff[i, 0], u_aff[i, 1], u_aff[i, 2] = u
            lam_i = row(lam, i)
            alpha_dual = step_within(lam_i, u, alpha_dual)
            alpha_primal = step_within(
                lam_i, (-lam_i[0] - u[0], -lam_i[1] - u[1], -lam_i[2] - u[2]), alpha_primal)
        alpha = min(alpha_dual, alpha_primal)
        # With the optimum asked for, the affine point (each side's step to its cone
        # boundary, at most 1) is often near enough to close the interval one corrector
        # and one iteration earlier: its certificates are checked where the gap it would
        # leave, (1 - alpha) gap, is small enough for that to be likely.
        if want_optimum and not signed and (1.0 - alpha) * gap / sigma < AFFINE_CHECK_GAP:
            for i in range(n):
                w2_ds = inverse_square_apply(row(jv, i), inv_eta2[i], row(ds, i))
                for k in range(3):     # dz of the affine step: -z - W^-2 ds
                    z_affine[i, k] = z[i, k] + alpha_primal * (-z[i, k] - w2_ds[k])
            for r in range(6):
                w_affine[r] = w[r] + alpha_dual * dw[r]
            depth, total = _witness(unit, normals, tangent, bitangent, mu, z_affine, sigma,
                                    gram_factor, gram_inverse, sigma_min, grasp_norm,
                                    projected, y, check, scratch)
            if depth > t_lo:
                t_lo = depth
                for i in range(n):
                    for k in range(3):
                        forces_out[i, k] = projected[i, k] / total
            bound, separating = _bound(unit, normals, mu, w_affine, normal_work)
            if (separating and not separated) or (bound < t_hi and not separated):
                wrench_out[:] = w_affine
                separated = separating
            t_hi = min(t_hi, bound)
            code = _verdict(t_lo, t_hi, separated, want_optimum, want_wrench)
            if code != UNDECIDED:
                return code, t_lo, t_hi, iteration + 1
        # Mehrotra's centring from the affine step: for feasible iterates dz . ds = 0,
        # so that step would leave the gap (1 - alpha) gap.
        shrink = 1.0 - alpha
        if want_optimum:
            # (the power 1.5 as a root: a call of pow costs several times more)
            centring = min(OPTIMUM_CENTRING_CAP, shrink * np.sqrt(shrink))
        else:
            centring = shrink ** 3
        target = centring * (gap / n)
        # Corrector: lam o (W dz + W^-1 ds) = -lam o lam - u o (-lam - u) + target e, so
        # W dz + W^-1 ds = -lam + p with p = lam \ (u o (lam + u) + target e); as above
        # the right-hand side becomes -d - sum_i A_i W^-1 p_i and dz = -z + W^-1 p - W^-2 ds.
        # In the arrays' lam / eta and u / eta: W^-1 p = J Wbar J (lam/eta) \ ((u/eta) o
        # (lam/eta + u/eta) + target / eta^2 e).
        for r in range(6):
            rhs[r] = -d[r]
        for i in range(n):
            lam_i, u = row(lam, i), row(u_aff, i)
            # -W dz of the predictor is lam + u.
            second_order = jordan_product(u, (lam_i[0] + u[0], lam_i[1] + u[1],
                                              lam_i[2] + u[2]))
            q = jordan_divide(lam_i, (second_order[0] + target * inv_eta2[i],
                                      second_order[1], second_order[2]))
            winv_q[i, 0], winv_q[i, 1], winv_q[i, 2] = scaled_inverse_apply(
                scaling_of(scalings, i), 1.0, q)
            pushed = _block_times(a_mat, i, row(winv_q, i))
            for r in range(6):
                rhs[r] -= pushed[r]
        ldl_substitute(factor, rhs, dw)
        # The step to the nearest cone boundary, searched only up to where STEP_FRACTION
        # of it is a full step.
        alpha = FULL_REACH
        step = _vector6(dw)
        for i in range(n):
            ds_i = _block_transposed_times(a_mat, i, step)
            ds[i, 0], ds[i, 1], ds[i, 2] = -ds_i[0], -ds_i[1], -ds_i[2]
            w2_ds = inverse_square_apply(row(jv, i), inv_eta2[i], row(ds, i))
            for k in range(3):
                dz[i, k] = winv_q[i, k] - z[i, k] - w2_ds[k]
            alpha = step_within(row(z, i), row(dz, i), alpha)
            alpha = step_within(row(s, i), row(ds, i), alpha)
        alpha = 1.0 if alpha == FULL_REACH else STEP_FRACTION * alpha
        if not alpha > MIN_STEP:
            last = True
            continue
        for i in range(n):
            for k in range(3):
                z[i, k] += alpha * dz[i, k]
                s[i, k] += alpha * ds[i, k]
        for r in range(6):
            w[r] += alpha * dw[r]
        iteration += 1
    if t_lo >= MARGIN_TOL and not signed:
        return FORCE_CLOSURE, t_lo, t_hi, iteration
    if t_hi < MARGIN_TOL and not signed:
        return NOT_FORCE_CLOSURE, t_lo, t_hi, iteration
    return UNDECIDED, t_lo, t_hi, iteration


@jit
def _solve_all(positions: np.ndarray, normals: np.ndarray, mu: np.ndarray, normalise: bool,
               want_optimum: bool, want_wrench: bool, signed_gap: float,
               signed_level: float) -> FastResult:
    """:func:`solve_fast` on kernel arrays (:func:`._kernels.jit.kernel_array`)."""
    n_grasps, n_contacts = mu.shape
    unit = np.empty((n_contacts, 3))
    codes = np.empty(n_grasps, dtype=np.int8)
    t_lo = np.empty(n_grasps)
    t_hi = np.empty(n_grasps)
    iterations = np.empty(n_grasps, dtype=np.int32)
    forces = np.full((n_grasps, n_contacts, 3), np.nan)
    wrench = np.full((n_grasps, 6), np.nan)
    work3, work6, rows, a_mat, scalings, mats, work_n, a_gram = _workspace(n_contacts)
    for g in range(n_grasps):
        grasp = positions[g]
        if normalise:
            peak = 0.0
            for i in range(n_contacts):
                for k in range(3):
                    peak = max(peak, abs(grasp[i, k]))
            normalise_grasp(grasp, peak, unit)
            grasp = unit
        codes[g], t_lo[g], t_hi[g], iterations[g] = _solve_grasp(
            grasp, normals[g], mu[g], want_optimum, want_wrench, signed_gap, signed_level,
            forces[g], wrench[g], work3, work6, rows, a_mat, scalings, mats, work_n, a_gram)
    return codes, t_lo, t_hi, iterations, forces, wrench


@jit
def _workspace(n_contacts: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                         np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Scratch of :func:`_solve_grasp` for grasps of ``n_contacts`` contacts: work3,
    work6, rows, a_mat, scalings, mats, work_n, a_gram."""
    return (np.empty((12, n_contacts, 3)), np.empty((13, 6)), np.empty((3, n_contacts, 6)),
            np.empty((n_contacts, 6, 3)), np.empty((n_contacts, 6)), np.empty((4, 6, 6)),
            np.empty((2, n_contacts)), np.empty((n_contacts, 6, 6)))


@jit
def solve_one(unit: np.ndarray, normals: np.ndarray, mu: np.ndarray,
              want_optimum: bool) -> tuple[int, float, float]:
    """The verdict of one unit-size grasp, compiled for callers that are compiled too.

    Parameters
    ----------
    unit, normals : ndarray, shape (n, 3)
        As for :func:`solve_fast`, one grasp.
    mu : ndarray, shape (n,)
    want_optimum : bool

    Returns
    -------
    (int, float, float)
        code (FORCE_CLOSURE, NOT_FORCE_CLOSURE or UNDECIDED), t_lo, t_hi.
    """
    work3, work6, rows, a_mat, scalings, mats, work_n, a_gram = _workspace(unit.shape[0])
    forces, wrench = np.empty((unit.shape[0], 3)), np.empty(6)
    code, t_lo, t_hi, _ = _solve_grasp(unit, normals, mu, want_optimum, False, 0.0, 0.0,
                                       forces, wrench, work3, work6, rows, a_mat, scalings,
                                       mats, work_n, a_gram)
    return code, t_lo, t_hi



def solve_fast(unit: np.ndarray, normals: np.ndarray, mu: np.ndarray,
               want_optimum: bool = False, want_wrench: bool = False,
               signed_gap: float = 0.0, signed_level: float = 0.0,
               normalise: bool = False) -> FastResult:
    """Run the fast exact stage on unit-size grasps.

    Parameters
    ----------
    unit : ndarray, shape (N, n, 3)
        Positions centred at the centroid and scaled to unit size; with ``normalise``,
        positions in any length unit, normalised in the kernel as
        :func:`.certificates.normalise_positions` does (no numpy pass over the batch).
    normals : ndarray, shape (N, n, 3)
        Unit inward normals.
    mu : ndarray, shape (N, n)
    want_optimum : bool
        Iterate until the certified interval on t* is at most MARGIN_ACCURACY wide.
    want_wrench : bool
        For not-force-closure grasps, iterate until the wrench meets the separation
        target (or the iteration limit).
    signed_gap : float
        > 0: the signed mode of :func:`_solve_grasp` (codes CONVERGED or UNDECIDED, t_lo
        the signed depth of the witness, ``wrench`` the last iterate's); 0: verdicts.
    signed_level : float
        The signed mode's target margin: the gap may stay larger far from it.
    normalise : bool
        ``unit`` holds positions still to be normalised.

    Returns
    -------
    codes : ndarray of int8, shape (N,)
        FORCE_CLOSURE, NOT_FORCE_CLOSURE or UNDECIDED.
    t_lo, t_hi : ndarray, shape (N,)
        Certified bounds on t* (-inf / inf where none was found).
    iterations : ndarray of int32, shape (N,)
    forces : ndarray, shape (N, n, 3)
        Best certified internal force (normal parts summing to one), NaN where none.
    wrench : ndarray, shape (N, 6)
        Wrench about the centroid of the unit-size grasp giving t_hi, NaN where none.
    """
    return _solve_all(kernel_array(unit), kernel_array(normals), kernel_array(mu),
                      bool(normalise), bool(want_optimum), bool(want_wrench),
                      float(signed_gap), float(signed_level))


def warm_up() -> None:
    """Compile (or load from the cache) the kernel for every mode: a ROS node calls
    this before it reports ready, so no query pays the compile."""
    unit = np.array([[[1.0, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]]])
    for optimum in (False, True):
        for wrench in (False, True):
            solve_fast(unit, -unit / np.sqrt(3.0), np.full((1, 4), 0.5), optimum, wrench)
    solve_fast(unit, -unit / np.sqrt(3.0), np.full((1, 4), 0.5), signed_gap=1e-11)
