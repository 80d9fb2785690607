"""The fast s* stage: a compiled interior-point method for the grasp-force problem (numba).

Hard contacts. For the unit wrench W of a unit-size grasp (:mod:`.grasp_forces`), with
B_i the 3 x 6 map from a wrench w to the local work vector (normal row Bn_i, tangential
rows Bt_i) of contact i, the homogenised problem and its dual are

    forces  max beta  s.t.  sum_i B_i^T c_i + beta W = 0,  c_n,i <= 1,  c_n,i <= beta L_i,
                            |c_t,i| <= mu_i c_n,i
    wrench  min sum_i u_i  s.t.  W . w + sum_i L_i v_i = -1,  u_i >= 0,  v_i >= 0,
                            s_i = (u_i + v_i - Bn_i w, mu_i Bt_i w) in Q^3

(v_i and L_i only at limited contacts). The forces are the cone multipliers z_i of the
wrench side: c_n,i = z0_i, c_t,i = -mu_i z_t,i, and beta = -y for the multiplier y of
its equality. The wrench side starts strictly feasible (w = -W scaled) and stays so;
the force side may have no interior point (a load that can only just be held, or not
at all), so it starts infeasible and its residual shrinks with the steps. Nesterov-Todd
scaling and Mehrotra's predictor-corrector, as in :mod:`.interior_point` (both are built
from :mod:`._kernels`). Each Newton step eliminates (u_i, v_i) contact by contact (a 2 x 2
block), leaving the 6 x 6 system in w bordered by the one equality: one 6 x 6 Cholesky
factor per iteration, used by both the predictor and the corrector. The 6 x 6 matrix is
summed from semidefinite per-contact terms (subtracting the eliminated blocks instead
lost its definiteness to rounding near the optimum).

After every iteration (iteration 0 included) it checks what :mod:`.grasp_forces` will
check in numpy, at tighter tolerances so that rounding differences do not fail that
check: the iterate's forces divided by beta and projected onto equilibrium (closed form
from the Cholesky factor of G G^T) lie in their cones and limits and their largest
normal force is within the optimality tolerance of the dual bound of the iterate's
wrench; or that bound alone proves s* = inf. The numpy check decides; the kernel's own
test only says when to stop. A contact limited to 0 carries no force and would leave the
force side no interior point: it is dropped (force 0). It returns a grasp as undecided
(for the Clarabel path) when the grasp map's rank (of the other contacts) is not clearly
6, when every contact is limited to 0, on a numerical breakdown, and at the iteration
limit (iteration counts: docs/performance.md#contact-forces).
"""

from __future__ import annotations

from typing import TypeAlias

import numpy as np

from .._kernels.cones import (
    MIN_STEP,
    NO_LIMIT,
    STEP_FRACTION,
    inverse_apply,
    inverse_square_apply,
    jordan_divide,
    jordan_product,
    max_step,
    nt_scaling,
    positive_step,
    scaled_apply,
    scaling_of,
)
from .._kernels.frames import normal_split, tangent_frames, work_at
from .._kernels.grasp_map import add_congruence, add_wrench, apply_grasp_map, certified_rank
from .._kernels.jit import jit, kernel_array, row
from .._kernels.linear_algebra import cholesky, cholesky_solve

#: Index into a :data:`._kernels.cones.Scaling` of the entry (r, c) of the symmetric W.
_SYMMETRIC = ((0, 1, 2), (1, 3, 4), (2, 4, 5))

#: Result codes of the kernel: forces and a wrench that meet the stop rule; a wrench
#: proving s* = inf; neither (for the Clarabel path).
SOLVED, INFEASIBLE, UNDECIDED = 0, 1, 2

#: What :func:`solve_fast_forces` returns: codes, beta, iterations, forces, wrench.
ForcesResult: TypeAlias = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]

#: Iterations before a grasp is handed to the Clarabel path.
MAX_ITERATIONS = 50

#: The kernel stops at this fraction of the numpy checks' tolerances (FORCE_TOL,
#: OPTIMALITY_TOL): its projection and bound differ from numpy's only by rounding
#: (~1e-15 relative), so an answer it accepts passes those checks.
STOP_FRACTION = 0.5

#: Diagonal shift, relative to the trace, of a Newton system that lost definiteness to
#: rounding: a few hundred eps, enough to restore a positive factor.
REGULARISATION = 1e-13

#: Scale of the start's complementarity s_i o z_i = START_GAP e (unit grasp, unit wrench:
#: forces and work are O(1)).
START_GAP = 1.0


@jit
def _lower_bound(unit: np.ndarray, normals: np.ndarray, mu: np.ndarray, limits: np.ndarray,
                 direction: np.ndarray, w: np.ndarray, excess: np.ndarray) -> float:
    """The dual bound of :func:`.grasp_forces.lower_bound` for wrench w (6,) (this sign,
    without rounding slack): 0 where w proves nothing, inf where no forces hold W.
    ``excess`` (n,) is scratch."""
    n = unit.shape[0]
    along = 0.0
    for r in range(6):
        along -= w[r] * direction[r]
    if not along > 0.0:
        return 0.0
    for i in range(n):
        a_n, a_t = normal_split(work_at(w, row(unit, i)), row(normals, i))
        excess[i] = max(a_n + mu[i] * a_t, 0.0)
    # g(beta) = sum_i excess_i min(1, beta L_i) - beta along is concave, linear between
    # the breakpoints 1 / L_i: the root lies past the last breakpoint where g >= 0.
    start = 0.0
    for k in range(n):
        if not (0.0 < limits[k] < np.inf) or 1.0 / limits[k] <= start:
            continue
        point = 1.0 / limits[k]
        room = -point * along
        for i in range(n):
            room += excess[i] * min(1.0, point * limits[i])
        if room >= 0.0:
            start = point
    saturated = slope = 0.0
    for i in range(n):
        # 1 / L_i <= start, not start L_i >= 1: the same rounding as the breakpoints.
        if limits[i] == np.inf or 1.0 / limits[i] <= start:
            saturated += excess[i]
        else:
            slope += excess[i] * limits[i]
    if not along > slope:
        return 0.0
    root = saturated / (along - slope)
    return 1.0 / root if root > 0.0 else np.inf


@jit
def _upper_bound(unit: np.ndarray, normals: np.ndarray, tangent: np.ndarray,
                 bitangent: np.ndarray, mu: np.ndarray, limits: np.ndarray,
                 direction: np.ndarray, z: np.ndarray, beta: float, gram_factor: np.ndarray,
                 forces: np.ndarray, check: np.ndarray, y: np.ndarray,
                 scratch: np.ndarray) -> tuple[float, float]:
    """(s, violation) of the force iterate z (n, 3): forces c_i / beta into ``forces``
    (n, 3, world frame), then their projection onto G f + W = 0; s its largest normal
    force, violation the largest excess over a cone or a limit."""
    n = unit.shape[0]
    for i in range(n):
        for k in range(3):
            forces[i, k] = (z[i, 0] * normals[i, k] - mu[i] * (z[i, 1] * tangent[i, k]
                                                               + z[i, 2] * bitangent[i, k])) / beta
    apply_grasp_map(unit, forces, check)
    for r in range(6):
        check[r] += direction[r]
    cholesky_solve(gram_factor, check, y, scratch)
    largest = -np.inf
    violation = 0.0
    for i in range(n):
        g0, g1, g2 = work_at(y, row(unit, i))                          # G_i^T y
        f_n, f_t = normal_split((forces[i, 0] - g0, forces[i, 1] - g1, forces[i, 2] - g2),
                                row(normals, i))
        largest = max(largest, f_n)
        violation = max(violation, f_t - mu[i] * f_n, f_n - limits[i])
    return largest, violation


@jit
def _slacks(unit: np.ndarray, edges: np.ndarray, w: np.ndarray, u: np.ndarray, v: np.ndarray,
            s: np.ndarray, work: np.ndarray) -> None:
    """The wrench side's cone slacks s_i = (u_i + v_i, 0, 0) + R_i^T G_i^T w into s
    (n, 3), R_i's columns ``edges[:, i]`` (-n_i, mu_i t1_i, mu_i t2_i); ``work`` (3,)
    is scratch."""
    for i in range(unit.shape[0]):
        work[0], work[1], work[2] = work_at(w, row(unit, i))
        for k in range(3):
            s[i, k] = edges[k, i, 0] * work[0] + edges[k, i, 1] * work[1] + edges[k, i, 2] * work[2]
        s[i, 0] += u[i] + v[i]


@jit
def _solve_grasp(unit: np.ndarray, normals: np.ndarray, mu: np.ndarray, limits: np.ndarray,
                 direction: np.ndarray, force_tol: float, optimality_tol: float,
                 infeasible_bound: float, forces_out: np.ndarray, wrench_out: np.ndarray,
                 work3: np.ndarray, work6: np.ndarray, mats: np.ndarray, scalings: np.ndarray,
                 edges: np.ndarray, work_n: np.ndarray) -> tuple[int, float, int]:
    """Solve one unit-size grasp. Returns (code, beta, iterations).

    ``forces_out`` (n, 3) gets the forces c_i / beta (world frame, before the
    projection), ``wrench_out`` (6,) the wrench w. The other arguments are scratch of
    the batch: work3 (12, n, 3), work6 (9, 6), mats (6, 6, 6), scalings (n, 6),
    edges (3, n, 3), work_n (20, n).
    """
    n = unit.shape[0]
    tangent, bitangent, z, s, jv, lam, dz, ds, rhs_c, winv_q, forces, h3 = (
        work3[0], work3[1], work3[2], work3[3], work3[4], work3[5], work3[6], work3[7],
        work3[8], work3[9], work3[10], work3[11])
    w, dw, r_w, rhs, b, sb, check, y6, scratch = (
        work6[0], work6[1], work6[2], work6[3], work6[4], work6[5], work6[6], work6[7],
        work6[8])
    gram, gram_factor, schur, factor = mats[0], mats[1], mats[2], mats[3]
    winv, vy, q_mat, t_mat = mats[4, :3, :3], mats[4, 3:, :3], mats[4, :3, 3:], mats[4, 3:, 3:]
    a, gvec, p_row, vec, pe = (mats[5, 0, :3], mats[5, 0, 3:], mats[5, 1, :3],
                               mats[5, 3, :3], mats[5, 3, 3:])
    (u, v, zu, zv, du, dv, dzu, dzv, rc_u, rc_v, inv_eta2, e_sum, e_cross, e_vv, r_u, r_v,
     t_u, t_v, excess, rhs_uv) = (
        work_n[0], work_n[1], work_n[2], work_n[3], work_n[4], work_n[5], work_n[6],
        work_n[7], work_n[8], work_n[9], work_n[10], work_n[11], work_n[12], work_n[13],
        work_n[14], work_n[15], work_n[16], work_n[17], work_n[18], work_n[19])

    sigma_min, _ = certified_rank(unit, gram, gram_factor, scratch)
    if not sigma_min > 0.0:
        return UNDECIDED, np.nan, 0
    n_cones = 2 * n
    for i in range(n):
        if not limits[i] > 0.0:
            return UNDECIDED, np.nan, 0
        if limits[i] < np.inf:
            n_cones += 1
    tangent_frames(normals, tangent, bitangent)
    for i in range(n):
        for k in range(3):
            edges[0, i, k] = -normals[i, k]
            edges[1, i, k] = mu[i] * tangent[i, k]
            edges[2, i, k] = mu[i] * bitangent[i, k]

    # Start: v_i L_i <= 1/n, w = -W (1 + sum_i L_i v_i), u_i one past the cone's need;
    # z centred on s (s o z = START_GAP e), beta = 0.
    total = 1.0
    for i in range(n):
        v[i] = 1.0 / (n * max(limits[i], 1.0)) if limits[i] < np.inf else 0.0
        total += limits[i] * v[i] if limits[i] < np.inf else 0.0
    for r in range(6):
        w[r] = -direction[r] * total
    u[:] = 0.0
    _slacks(unit, edges, w, u, v, s, a)
    for i in range(n):
        tangential = np.sqrt(s[i, 1] ** 2 + s[i, 2] ** 2)
        u[i] = max(tangential - s[i, 0], 0.0) + 1.0
        s[i, 0] += u[i]
        det = s[i, 0] ** 2 - s[i, 1] ** 2 - s[i, 2] ** 2
        z[i, 0], z[i, 1], z[i, 2] = (START_GAP * s[i, 0] / det, -START_GAP * s[i, 1] / det,
                                     -START_GAP * s[i, 2] / det)
        zu[i] = START_GAP / u[i]
        zv[i] = START_GAP / v[i] if limits[i] < np.inf else 0.0
    y = 0.0

    for iteration in range(MAX_ITERATIONS + 1):
        _slacks(unit, edges, w, u, v, s, a)
        bound = _lower_bound(unit, normals, mu, limits, direction, w, excess)
        if bound >= infeasible_bound:
            wrench_out[:] = w
            return INFEASIBLE, -y, iteration
        beta = -y
        if beta > 0.0:
            largest, violation = _upper_bound(unit, normals, tangent, bitangent, mu, limits,
                                              direction, z, beta, gram_factor, forces,
                                              check, y6, scratch)
            if (violation <= force_tol * largest
                    and largest <= bound * (1.0 + optimality_tol)):
                forces_out[:] = forces
                wrench_out[:] = w
                return SOLVED, beta, iteration
        if iteration == MAX_ITERATIONS:
            break

        # Residuals: force side (dual) r_w, r_u, r_v; the wrench side's equality r_p.
        r_p = -1.0
        for r in range(6):
            r_w[r] = -direction[r] * y
            r_p -= direction[r] * w[r]
        for i in range(n):
            for k in range(3):   # the force of z_i: -R_i z_i
                vec[k] = -(edges[0, i, k] * z[i, 0] + edges[1, i, k] * z[i, 1]
                           + edges[2, i, k] * z[i, 2])
            add_wrench(vec, unit[i], 1.0, r_w)
            r_u[i] = 1.0 - z[i, 0] - zu[i]
            if limits[i] < np.inf:
                r_v[i] = -z[i, 0] - zv[i] - limits[i] * y
                r_p -= limits[i] * v[i]

        # The reduced system: Schur complement S of the (u_i, v_i) blocks in the w block,
        # bordered by the equality (b, c).
        schur[:] = 0.0
        b[:] = direction
        c = 0.0
        gap = 0.0
        finite = True
        for i in range(n):
            inv_eta2[i], scaling, inverse_vector = nt_scaling(row(z, i), row(s, i))
            if not np.isfinite(inv_eta2[i]):
                finite = False
                break
            for k in range(6):
                scalings[i, k] = scaling[k]
            jv[i, 0], jv[i, 1], jv[i, 2] = inverse_vector
            lam[i, 0], lam[i, 1], lam[i, 2] = scaled_apply(scaling, row(z, i))
            # h_i = G_i R_i W^-2 e0, W^-2 = (2 Jv Jv^T - J) / eta^2.
            pe[0] = inv_eta2[i] * (2.0 * jv[i, 0] * jv[i, 0] - 1.0)
            pe[1] = inv_eta2[i] * 2.0 * jv[i, 0] * jv[i, 1]
            pe[2] = inv_eta2[i] * 2.0 * jv[i, 0] * jv[i, 2]
            for k in range(3):
                h3[i, k] = pe[0] * edges[0, i, k] + pe[1] * edges[1, i, k] + pe[2] * edges[2, i, k]
            d_u = zu[i] / u[i]
            gap += z[i, 0] * s[i, 0] + z[i, 1] * s[i, 1] + z[i, 2] * s[i, 2] + zu[i] * u[i]
            # Contact i adds G_i R_i W^-1 (I + c g g^T)^-1 W^-1 R_i^T G_i^T to S (c: the
            # compliance of its eliminated u_i, v_i; g = W^-1 e0), with the 3 x 3 middle
            # Y^T Y + kappa p p^T, X = W^-1 R_i^T, p = X^T g/|g|, Y = X - (g/|g|) p^T,
            # kappa = 1 / (1 + c |g|^2): semidefinite terms only. Subtracting the
            # elimination from the cone's term instead cancels to rounding near the
            # optimum, and so does forming W^2.
            compliance = u[i] / zu[i] + (v[i] / zv[i] if limits[i] < np.inf else 0.0)
            for r in range(3):      # W^-1 = J W J / eta^2
                for col in range(3):
                    sign = 1.0 if (r == 0) == (col == 0) else -1.0
                    winv[r, col] = sign * inv_eta2[i] * scaling[_SYMMETRIC[r][col]]
            g_norm = np.sqrt(winv[0, 0] ** 2 + winv[1, 0] ** 2 + winv[2, 0] ** 2)
            kappa = 1.0 / (1.0 + compliance * g_norm * g_norm)
            for k in range(3):
                gvec[k] = winv[k, 0] / g_norm
            for m in range(3):
                along_g = 0.0
                for k in range(3):
                    vy[k, m] = (winv[k, 0] * edges[0, i, m] + winv[k, 1] * edges[1, i, m]
                                + winv[k, 2] * edges[2, i, m])
                    along_g += gvec[k] * vy[k, m]
                p_row[m] = along_g
                for k in range(3):
                    vy[k, m] -= gvec[k] * along_g
            for m in range(3):
                for col in range(3):
                    q_mat[m, col] = (vy[0, m] * vy[0, col] + vy[1, m] * vy[1, col]
                                     + vy[2, m] * vy[2, col] + kappa * p_row[m] * p_row[col])
            add_congruence(q_mat, unit[i], schur, t_mat)
            p00 = pe[0]
            if limits[i] < np.inf:
                d_v = zv[i] / v[i]
                gap += zv[i] * v[i]
                det = p00 * (d_u + d_v) + d_u * d_v
                # E = D^-1 of D = [[p00 + d_u, p00], [p00, p00 + d_v]]: 1'E1, 1'E e_v, E_vv.
                e_sum[i] = (d_u + d_v) / det
                e_cross[i] = d_u / det
                e_vv[i] = (p00 + d_u) / det
                add_wrench(h3[i], unit[i], -limits[i] * e_cross[i], b)
                c += limits[i] * limits[i] * e_vv[i]
            else:
                e_sum[i] = 1.0 / (p00 + d_u)
        if not finite:
            break
        if not cholesky(schur, factor):
            # S lost definiteness to rounding (its condition nears 1/eps as beta -> 0 on
            # a load that can just not be held): a shift of REGULARISATION of its
            # trace keeps the step a descent direction; the checks judge the iterate.
            shift = REGULARISATION * np.trace(schur)
            for r in range(6):
                schur[r, r] += shift
            if not cholesky(schur, factor):
                break
        cholesky_solve(factor, b, sb, scratch)
        border = np.dot(b, sb) + c
        if not border > 0.0:
            break
        mean_gap = gap / n_cones
        for i in range(n):
            square = jordan_product(row(lam, i), row(lam, i))
            for k in range(3):
                rhs_c[i, k] = -square[k]
            rc_u[i] = -u[i] * zu[i]
            rc_v[i] = -v[i] * zv[i]
        alpha = NO_LIMIT
        dy = 0.0
        for corrector in range(2):
            # Right-hand side M W^-1 q - r_d; then (u_i, v_i) eliminated.
            for r in range(6):
                rhs[r] = -r_w[r]
            r2 = r_p
            for i in range(n):
                winv_q[i, 0], winv_q[i, 1], winv_q[i, 2] = inverse_apply(
                    scaling_of(scalings, i), jordan_divide(row(lam, i), row(rhs_c, i)))
                t_u[i] = rc_u[i] / u[i]
                ru = winv_q[i, 0] + t_u[i] - r_u[i]
                if limits[i] < np.inf:
                    t_v[i] = rc_v[i] / v[i]
                    rv = winv_q[i, 0] + t_v[i] - r_v[i]
                    # 1'E r' and e_v'E r' from E's entries 1'E1, 1'E e_v, E_vv.
                    rhs_uv[i] = (e_sum[i] - e_cross[i]) * ru + e_cross[i] * rv
                    r2 -= limits[i] * ((e_cross[i] - e_vv[i]) * ru + e_vv[i] * rv)
                    dv[i] = rv                      # kept for the back-substitution
                else:
                    rhs_uv[i] = e_sum[i] * ru
                du[i] = ru
                for k in range(3):   # R_i W^-1 q_i - h_i (1'E r'_i), mapped by G_i
                    vec[k] = (winv_q[i, 0] * edges[0, i, k] + winv_q[i, 1] * edges[1, i, k]
                              + winv_q[i, 2] * edges[2, i, k] - rhs_uv[i] * h3[i, k])
                add_wrench(vec, unit[i], 1.0, rhs)
            cholesky_solve(factor, rhs, dw, scratch)
            dy = (r2 - np.dot(b, dw)) / border
            for r in range(6):
                dw[r] += sb[r] * dy
            alpha = NO_LIMIT
            for i in range(n):
                a[0], a[1], a[2] = work_at(dw, row(unit, i))
                along_h = h3[i, 0] * a[0] + h3[i, 1] * a[1] + h3[i, 2] * a[2]
                ru = du[i] - along_h
                if limits[i] < np.inf:
                    rv = dv[i] + limits[i] * dy - along_h
                    # [du; dv] = E [ru; rv], E from its three entries.
                    e_uv = e_cross[i] - e_vv[i]
                    du[i] = (e_sum[i] - 2.0 * e_cross[i] + e_vv[i]) * ru + e_uv * rv
                    dv[i] = e_uv * ru + e_vv[i] * rv
                else:
                    du[i] = e_sum[i] * ru
                    dv[i] = 0.0
                for k in range(3):
                    ds[i, k] = edges[k, i, 0] * a[0] + edges[k, i, 1] * a[1] + edges[k, i, 2] * a[2]
                ds[i, 0] += du[i] + dv[i]
                # dz = W^-1 q - W^-2 ds
                w2_ds = inverse_square_apply(row(jv, i), inv_eta2[i], row(ds, i))
                for k in range(3):
                    dz[i, k] = winv_q[i, k] - w2_ds[k]
                dzu[i] = t_u[i] - zu[i] / u[i] * du[i]
                alpha = min(alpha, max_step(row(z, i), row(dz, i)),
                            max_step(row(s, i), row(ds, i)),
                            positive_step(u[i], du[i]), positive_step(zu[i], dzu[i]))
                if limits[i] < np.inf:
                    dzv[i] = t_v[i] - zv[i] / v[i] * dv[i]
                    alpha = min(alpha, positive_step(v[i], dv[i]),
                                positive_step(zv[i], dzv[i]))
            if corrector == 0:
                alpha = min(1.0, alpha)
                predicted = 0.0
                for i in range(n):
                    for k in range(3):
                        predicted += (z[i, k] + alpha * dz[i, k]) * (s[i, k] + alpha * ds[i, k])
                    predicted += (zu[i] + alpha * dzu[i]) * (u[i] + alpha * du[i])
                    if limits[i] < np.inf:
                        predicted += (zv[i] + alpha * dzv[i]) * (v[i] + alpha * dv[i])
                centring = (predicted / gap) ** 3 * mean_gap
                for i in range(n):
                    scaling = scaling_of(scalings, i)
                    second_order = jordan_product(inverse_apply(scaling, row(ds, i)),
                                                  scaled_apply(scaling, row(dz, i)))
                    square = jordan_product(row(lam, i), row(lam, i))
                    for k in range(3):
                        rhs_c[i, k] = -square[k] - second_order[k]
                    rhs_c[i, 0] += centring
                    rc_u[i] = -u[i] * zu[i] - du[i] * dzu[i] + centring
                    if limits[i] < np.inf:
                        rc_v[i] = -v[i] * zv[i] - dv[i] * dzv[i] + centring
        alpha = min(1.0, STEP_FRACTION * alpha)
        if not alpha > MIN_STEP:
            break
        for r in range(6):
            w[r] += alpha * dw[r]
        for i in range(n):
            for k in range(3):
                z[i, k] += alpha * dz[i, k]
            u[i] += alpha * du[i]
            zu[i] += alpha * dzu[i]
            if limits[i] < np.inf:
                v[i] += alpha * dv[i]
                zv[i] += alpha * dzv[i]
        y += alpha * dy
    return UNDECIDED, -y, iteration


@jit
def _workspace(n_contacts: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                         np.ndarray, np.ndarray]:
    """Scratch of :func:`_solve_grasp` for grasps of ``n_contacts`` contacts, reused from
    grasp to grasp: work3, work6, mats, scalings, edges, work_n."""
    return (np.empty((12, n_contacts, 3)), np.empty((9, 6)), np.empty((6, 6, 6)),
            np.empty((n_contacts, 6)), np.empty((3, n_contacts, 3)),
            np.zeros((20, n_contacts)))


@jit
def _solve_without_idle(unit: np.ndarray, normals: np.ndarray, mu: np.ndarray,
                        limits: np.ndarray, direction: np.ndarray, force_tol: float,
                        optimality_tol: float, infeasible_bound: float,
                        forces_out: np.ndarray, wrench_out: np.ndarray,
                        active: int) -> tuple[int, float, int]:
    """:func:`_solve_grasp` on the ``active`` contacts with a limit > 0 only: a contact
    limited to 0 carries no force (and leaves the force side no interior point), so it
    is dropped and gets force 0. Rare: the copies and scratch are allocated here."""
    keep = np.flatnonzero(limits > 0.0)
    work3, work6, mats, scalings, edges, work_n = _workspace(active)
    forces = np.full((active, 3), np.nan)
    code, beta, iterations = _solve_grasp(
        np.ascontiguousarray(unit[keep]), np.ascontiguousarray(normals[keep]),
        np.ascontiguousarray(mu[keep]), np.ascontiguousarray(limits[keep]), direction,
        force_tol, optimality_tol, infeasible_bound, forces, wrench_out, work3, work6, mats,
        scalings, edges, work_n)
    forces_out[:] = 0.0
    for j in range(active):
        forces_out[keep[j]] = forces[j]
    return code, beta, iterations


@jit
def _solve_all(unit: np.ndarray, normals: np.ndarray, mu: np.ndarray, limits: np.ndarray,
               direction: np.ndarray, force_tol: float, optimality_tol: float,
               infeasible_bound: float) -> ForcesResult:
    """:func:`solve_fast_forces` on kernel arrays, with the stop tolerances applied."""
    n_grasps, n_contacts = mu.shape
    codes = np.full(n_grasps, UNDECIDED, dtype=np.int8)
    beta = np.full(n_grasps, np.nan)
    iterations = np.zeros(n_grasps, dtype=np.int32)
    forces = np.full((n_grasps, n_contacts, 3), np.nan)
    wrench = np.full((n_grasps, 6), np.nan)
    work3, work6, mats, scalings, edges, work_n = _workspace(n_contacts)
    for k in range(n_grasps):
        active = 0
        for i in range(n_contacts):
            if limits[k, i] > 0.0:
                active += 1
        if active == n_contacts:
            codes[k], beta[k], iterations[k] = _solve_grasp(
                unit[k], normals[k], mu[k], limits[k], direction[k], force_tol,
                optimality_tol, infeasible_bound, forces[k], wrench[k], work3, work6, mats,
                scalings, edges, work_n)
        elif active > 0:
            codes[k], beta[k], iterations[k] = _solve_without_idle(
                unit[k], normals[k], mu[k], limits[k], direction[k], force_tol,
                optimality_tol, infeasible_bound, forces[k], wrench[k], active)
    return codes, beta, iterations, forces, wrench



def solve_fast_forces(unit: np.ndarray, normals: np.ndarray, mu: np.ndarray,
                      limits: np.ndarray, direction: np.ndarray, force_tol: float,
                      optimality_tol: float, infeasible_bound: float) -> ForcesResult:
    """Run the fast s* stage on unit-size hard grasps and unit wrenches.

    Parameters
    ----------
    unit : ndarray, shape (N, n, 3)
        Positions centred at the centroid and scaled to unit size.
    normals : ndarray, shape (N, n, 3)
        Unit inward normals.
    mu : ndarray, shape (N, n)
    limits : ndarray, shape (N, n)
        Normal-force limits for the unit wrench, inf where none.
    direction : ndarray, shape (N, 6)
        Unit external wrenches (torque about the centroid, in the unit grasp).
    force_tol, optimality_tol : float
        The numpy checks' tolerances (relative to s*) on cone and limit excess and on
        the distance from the dual bound; the kernel stops at STOP_FRACTION of them.
    infeasible_bound : float
        A dual bound at least this proves s* = inf; the kernel stops at twice it.

    Returns
    -------
    codes : ndarray of int8, shape (N,)
        SOLVED, INFEASIBLE or UNDECIDED.
    beta : ndarray, shape (N,)
        The last beta of the force side (1 / s* at the optimum).
    iterations : ndarray of int32, shape (N,)
    forces : ndarray, shape (N, n, 3)
        SOLVED: the forces (world frame of the unit grasp, for the unit wrench) before
        their projection onto equilibrium; NaN elsewhere.
    wrench : ndarray, shape (N, 6)
        The dual wrench w (SOLVED and INFEASIBLE), NaN elsewhere.
    """
    return _solve_all(kernel_array(unit), kernel_array(normals),
                      kernel_array(mu), kernel_array(limits),
                      kernel_array(direction), STOP_FRACTION * float(force_tol),
                      STOP_FRACTION * float(optimality_tol), 2.0 * float(infeasible_bound))


def warm_up() -> None:
    """Compile (or load from the cache) the kernel, with and without limits."""
    unit = np.array([[[1.0, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]]]) / np.sqrt(3.0)
    direction = np.array([[0.0, 0, -1, 0, 0, 0]])
    for limit in (np.inf, 10.0):
        solve_fast_forces(unit, -unit, np.full((1, 4), 0.5), np.full((1, 4), limit),
                          direction, 1e-6, 1e-6, 1e9)
