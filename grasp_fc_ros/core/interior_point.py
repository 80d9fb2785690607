"""The fast exact stage: a small interior-point method for this SOCP family (numba).

The margin problem of :mod:`.exact_test`, with the normalisation row eliminated
(sigma = sum_i 1/mu_i, d = sum_i Bn_i / (mu_i sigma), B_i the 3 x 6 map from the wrench w
to the local work vector of contact i, Bn_i its normal row, Bt_i its tangential rows):

    primal  min sum_i z0_i   s.t.  sum_i A_i z_i = -d,  z_i in Q^3,
            A_i = [Bn_i - d, -mu_i Bt_i^T]              (forces: t = (1 - sum z0) / sigma,
                                                          c_n,i = z0_i + t/mu_i, c_t,i = -mu_i z_t,i)
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

It returns a grasp as undecided (for the Clarabel path) when the grasp map's rank is not
clearly 6, when equilibrium forces with a positive total normal force are nearly absent
(contacts that nearly share one normal), on any numerical breakdown, and at the
iteration limit. Compiled with ``cache=True``: numba stores the machine code next to this
file, or in the user's cache directory when the install is read-only; call
:func:`warm_up` before serving queries to pay the compile (or cache load) up front.
"""

from __future__ import annotations

import numpy as np

from .tolerances import (FAST_RANK_TOL, MARGIN_ACCURACY, MARGIN_TOL, ROUNDING_SLACK,
                         SEPARATION_TARGET, SHARED_NORMAL_TOL)

try:
    import numba
except ImportError:  # pragma: no cover - numba is a pinned runtime dependency
    numba = None

#: Result codes of the kernel. CONVERGED: the signed mode's gap closed (no verdict).
FORCE_CLOSURE, NOT_FORCE_CLOSURE, UNDECIDED, CONVERGED = 0, 1, 2, 3

#: Iterations before a grasp is handed to the Clarabel path. On the box benchmark a
#: verdict takes 0.8-1.7 iterations on average (at most 7), the margin to
#: MARGIN_ACCURACY 1.5-7 on average; 40 only bounds a stuck or marginal grasp.
MAX_ITERATIONS = 40

#: Fraction of the step to the cone boundary taken (the usual 0.99 of interior-point
#: methods: close enough to converge fast, far enough to keep the scaling well-defined).
STEP_FRACTION = 0.99

#: Centring with the optimum asked for: sigma = min(CAP, (1 - alpha_aff)^POWER) instead
#: of Mehrotra's (1 - alpha_aff)^3, which is kept for verdicts. Iterating to the optimum,
#: the cube's too little centring in the late iterations left affine steps of 0.6-0.9
#: (gaps shrinking ~10x per iteration); this rule cut the mean iterations to the margin
#: by 4-7% on the box, ellipsoid and mug (n = 4, 6, 8; mu = tan 10 deg, 0.5; 1,500-2,000
#: grasps per cell), while on verdicts it cost up to 3% and the cube stays there.
OPTIMUM_CENTRING_POWER = 1.5
OPTIMUM_CENTRING_CAP = 0.1

#: A step shorter than this means the iteration has stalled: hand the grasp over.
MIN_STEP = 1e-10

_EPS = float(np.finfo(np.float64).eps)

#: For verdicts, the witness is computed only where it could raise max(t_lo, 0): where
#: :func:`_unprojected_depth` exceeds it less this allowance, which covers the
#: projection's rounding (~1e-15) many times over. A speed heuristic only (1.1-1.2x on
#: verdicts, measured; with the optimum asked for, where ``CHECK_GAP`` already gates the
#: witness, it cost 1-3% and is not used): a skipped witness could have changed neither
#: the verdict nor the reported interval (t_lo enters both only through max(t_lo, 0); a
#: certifying witness is MARGIN_TOL deep), and a mistaken skip only costs an iteration.
WITNESS_SKIP_SLACK = 1e-9

#: With ``want_optimum``, the certificate checks are skipped while the iterates' primal
#: and dual objectives are more than this apart (10 MARGIN_ACCURACY): they cannot close
#: the interval yet (at the iterate before the one that closes it, the certified width
#: was 0.4-0.9 of the objectives' gap, 10th-90th percentile). A speed heuristic only
#: (every return is still from a checked iterate). 100 MARGIN_ACCURACY changed no stop
#: on the benchmark's 24,000 box grasps and saved ~10-15% of the optimum's time; 10
#: MARGIN_ACCURACY changed none of 12,000 more (n = 4, 6, 8; two mu) and saved 0-4%.
CHECK_GAP = 1e-7

#: The signed mode also stops where its gap is this fraction of the margin's distance
#: from the level searched for: far from mu*, the search's next step and the
#: certificates need no more.
SIGNED_RELATIVE_GAP = 1e-3

#: Relative rounding allowance of the trivial bound t* <= 1 / sum_i (1/mu_i): the sum
#: of n <= ~1e3 positive terms errs by far less than n eps.
TRIVIAL_BOUND_SLACK = 1e-12


def _jit(function):
    """``numba.njit(cache=True)``; without a usable cache directory, uncached."""
    try:
        return numba.njit(cache=True, error_model="numpy")(function)
    except RuntimeError:  # no writable cache location at all: compile per process
        return numba.njit(cache=False, error_model="numpy")(function)


def kernel_array(values) -> np.ndarray:
    """``values`` as a C-contiguous, writable float64 array, to pass to a compiled kernel.

    numba compiles a kernel once per argument type, and a read-only array (from
    ``np.frombuffer``, ``np.broadcast_to`` or an unpickled buffer) is a type of its own:
    passed as it is, it made the node's first queries compile the exact stage again
    after :func:`warm_up` (~15 s of CPU in a fresh install, a cache load in every later
    process). Only such arrays are copied.
    """
    return np.require(values, np.float64, ("C", "W"))


def _frames(normals, first, second):
    """Duff et al.'s branch-free tangents (n, 3) into ``first`` and ``second``, for unit
    normals (n, 3)."""
    n = normals.shape[0]
    for i in range(n):
        x, y, z = normals[i, 0], normals[i, 1], normals[i, 2]
        sign = 1.0 if z >= 0.0 else -1.0
        a = -1.0 / (sign + z)
        b = x * y * a
        first[i, 0], first[i, 1], first[i, 2] = 1.0 + sign * x * x * a, sign * b, -sign * x
        second[i, 0], second[i, 1], second[i, 2] = b, sign + y * y * a, -y


def _wrench_rows(unit, direction, rows):
    """Wrenches (n, 6) into ``rows`` of unit forces along ``direction`` (n, 3) at ``unit``."""
    for i in range(unit.shape[0]):
        u, e = unit[i], direction[i]
        rows[i, 0], rows[i, 1], rows[i, 2] = e[0], e[1], e[2]
        rows[i, 3] = u[1] * e[2] - u[2] * e[1]
        rows[i, 4] = u[2] * e[0] - u[0] * e[2]
        rows[i, 5] = u[0] * e[1] - u[1] * e[0]


def _work_at(w, point):
    """The work vector (3 floats) w_F + w_T x point of wrench w (6,) at ``point`` (3,):
    G_i^T w for the contact there."""
    return (w[0] + w[4] * point[2] - w[5] * point[1],
            w[1] + w[5] * point[0] - w[3] * point[2],
            w[2] + w[3] * point[1] - w[4] * point[0])


def _normal_split(x0, x1, x2, normal):
    """Normal component and tangential length of the vector (x0, x1, x2) at a unit
    ``normal`` (3,)."""
    x_n = x0 * normal[0] + x1 * normal[1] + x2 * normal[2]
    x_t = np.sqrt((x0 - x_n * normal[0]) ** 2 + (x1 - x_n * normal[1]) ** 2
                  + (x2 - x_n * normal[2]) ** 2)
    return x_n, x_t


def _gram(unit, gram):
    """G G^T (6 x 6) into ``gram`` for global force components at ``unit`` (n, 3):
    [[n I, -sum [u]x], [sum [u]x, sum (|u|^2 I - u u^T)]]."""
    gram[:] = 0.0
    sx = sy = sz = 0.0
    for i in range(unit.shape[0]):
        x, y, z = unit[i, 0], unit[i, 1], unit[i, 2]
        sx += x
        sy += y
        sz += z
        square = x * x + y * y + z * z
        for r in range(3):
            for c in range(3):
                gram[3 + r, 3 + c] -= unit[i, r] * unit[i, c]
            gram[3 + r, 3 + r] += square
    for r in range(3):
        gram[r, r] = unit.shape[0]
    # sum [u]x = [[0, -sz, sy], [sz, 0, -sx], [-sy, sx, 0]] in the lower-left block.
    cross = ((0.0, -sz, sy), (sz, 0.0, -sx), (-sy, sx, 0.0))
    for r in range(3):
        for c in range(3):
            gram[3 + r, c] = cross[r][c]
            gram[c, 3 + r] = cross[r][c]


def _apply_grasp_map(unit, forces, out):
    """G f (6,) into ``out`` for global forces (n, 3) at ``unit``."""
    out[:] = 0.0
    for i in range(unit.shape[0]):
        u, f = unit[i], forces[i]
        out[0] += f[0]
        out[1] += f[1]
        out[2] += f[2]
        out[3] += u[1] * f[2] - u[2] * f[1]
        out[4] += u[2] * f[0] - u[0] * f[2]
        out[5] += u[0] * f[1] - u[1] * f[0]


def _cholesky_solve(factor, rhs, x, y):
    """Solve (L L^T) x = rhs for a lower-triangular 6 x 6 L; ``y`` is scratch (x may be
    rhs). The literal size lets the compiler unroll both substitutions (3x faster than
    loops over ``rhs.shape[0]``, measured)."""
    for r in range(6):
        acc = rhs[r]
        for c in range(r):
            acc -= factor[r, c] * y[c]
        y[r] = acc / factor[r, r]
    for r in range(5, -1, -1):
        acc = y[r]
        for c in range(r + 1, 6):
            acc -= factor[c, r] * x[c]
        x[r] = acc / factor[r, r]


def _triangular_inverse_norm2(factor, column):
    """|L^-1|_F^2 of a lower-triangular 6 x 6 L, by forward substitution column by
    column (literal size, as in :func:`_cholesky_solve`)."""
    total = 0.0
    for k in range(6):
        for r in range(6):
            if r < k:
                column[r] = 0.0
                continue
            acc = 1.0 if r == k else 0.0
            for c in range(k, r):
                acc -= factor[r, c] * column[c]
            column[r] = acc / factor[r, r]
            total += column[r] * column[r]
    return total


def _cholesky(matrix, factor):
    """Lower Cholesky factor of a 6 x 6 ``matrix`` into ``factor`` (literal size, as in
    :func:`_cholesky_solve`); False on a non-positive pivot."""
    factor[:] = 0.0
    for r in range(6):
        for c in range(r + 1):
            acc = matrix[r, c]
            for k in range(c):
                acc -= factor[r, k] * factor[c, k]
            if r == c:
                if not acc > 0.0:
                    return False
                factor[r, r] = np.sqrt(acc)
            else:
                factor[r, c] = acc / factor[c, c]
    return True


def _certified_rank(unit, gram, gram_factor, scratch):
    """(sigma_min, |G|_F) of the grasp map at ``unit`` (n, 3), with G G^T into ``gram``
    and its Cholesky factor into ``gram_factor``; sigma_min is 0 where rank 6 is not
    certain (sigma_min^2 <= FAST_RANK_TOL^2 trace(G G^T))."""
    _gram(unit, gram)
    trace = np.trace(gram)
    if not _cholesky(gram, gram_factor):
        return 0.0, np.sqrt(trace)
    # lambda_min(G G^T) = 1 / |L^-T L^-1|_2 >= 1 / |L^-1|_F^2: a lower bound on sigma_min,
    # so the witness slack errs on the safe side; lambda_max <= trace likewise.
    lambda_min = 1.0 / _triangular_inverse_norm2(gram_factor, scratch)
    if not lambda_min > FAST_RANK_TOL * FAST_RANK_TOL * trace:
        return 0.0, np.sqrt(trace)
    return np.sqrt(lambda_min), np.sqrt(trace)


def _witness(unit, normals, tangent, bitangent, mu, z, sigma, gram_factor, sigma_min,
             grasp_norm, out, forces, y, check, scratch):
    """Certified depth of the forces of primal iterate z (n, 3); the projected forces,
    scaled to total one, go to ``out`` (n, 3). -inf when the total is not positive."""
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
    _apply_grasp_map(unit, forces, check)
    _cholesky_solve(gram_factor, check, y, scratch)
    size = 0.0
    for i in range(n):
        g0, g1, g2 = _work_at(y, unit[i])                              # G_i^T y
        forces[i, 0] -= g0
        forces[i, 1] -= g1
        forces[i, 2] -= g2
        size += forces[i, 0] ** 2 + forces[i, 1] ** 2 + forces[i, 2] ** 2
    _apply_grasp_map(unit, forces, check)
    residual = 0.0
    for r in range(6):
        residual += check[r] * check[r]
    residual = np.sqrt(residual)
    reach = (residual + ROUNDING_SLACK * _EPS * 3 * n * grasp_norm * np.sqrt(size)) / sigma_min
    total = 0.0
    worst = np.inf
    for i in range(n):
        f_n, tangential = _normal_split(forces[i, 0], forces[i, 1], forces[i, 2], normals[i])
        worst = min(worst, mu[i] * f_n - tangential - (mu[i] + 1.0) * reach)
        total += f_n
    slack = np.sqrt(n) * reach
    if not total - slack > 0.0:
        return -np.inf
    for i in range(n):
        for k in range(3):
            out[i, k] = forces[i, k] / total
    return worst / (total + slack)


def _unprojected_depth(z, mu, t_p):
    """Depth t_p + min_i mu_i (z0_i - |z_t,i|) of the forces of primal iterate z before
    the projection onto equilibrium (mu_i c_n,i - |c_t,i| = t_p + mu_i (z0_i - |z_t,i|),
    normal forces summing to one): the iterates are in equilibrium up to rounding, so
    :func:`_witness` certifies at most this plus rounding, at a fraction of its cost."""
    lowest = np.inf
    for i in range(z.shape[0]):
        lowest = min(lowest, mu[i] * (z[i, 0] - np.sqrt(z[i, 1] * z[i, 1] + z[i, 2] * z[i, 2])))
    return t_p + lowest


def _bound(unit, normals, mu, w, normal_work):
    """Certified upper bound on t* from wrench w (6,), and whether w meets the
    separation target (L <= SEPARATION_TARGET max_j |a_j|)."""
    n = unit.shape[0]
    force_norm = np.sqrt(w[0] ** 2 + w[1] ** 2 + w[2] ** 2)
    torque_norm = np.sqrt(w[3] ** 2 + w[4] ** 2 + w[5] ** 2)
    error = ROUNDING_SLACK * _EPS * (force_norm + 2.0 * torque_norm)
    level = -np.inf
    largest = 0.0
    mu_max = 0.0
    for i in range(n):
        a0, a1, a2 = _work_at(w, unit[i])
        a_n, a_t = _normal_split(a0, a1, a2, normals[i])
        normal_work[i] = a_n
        level = max(level, a_n + mu[i] * a_t)
        largest = max(largest, np.sqrt(a0 * a0 + a1 * a1 + a2 * a2))
        mu_max = max(mu_max, mu[i])
    raw_level = level
    level += (1.0 + mu_max) * error
    spread = 0.0
    for i in range(n):
        spread += (level - normal_work[i] - error) / mu[i]
    spread *= 1.0 - 1e-12
    bound = max(level, 0.0) / spread if spread > 0.0 else np.inf
    return bound, raw_level <= SEPARATION_TARGET * largest


def _nt_scaling(z, s, scaling, inverse_vector):
    """Nesterov-Todd scaling of one 3-cone pair, for z, s interior.

    Fills ``scaling`` (3, 3) with W (W z = W^-1 s) and ``inverse_vector`` (3,) with
    J v, where W = eta Wbar, Wbar^2 = 2 v v^T - J; so W^-1 = (1/eta) J Wbar J and
    W^-2 = (1/eta^2) (2 (Jv)(Jv)^T - J). Returns 1/eta^2, or NaN if z or s has left
    the cone interior.
    """
    z_det = z[0] * z[0] - z[1] * z[1] - z[2] * z[2]
    s_det = s[0] * s[0] - s[1] * s[1] - s[2] * s[2]
    if not (z_det > 0.0 and s_det > 0.0 and z[0] > 0.0 and s[0] > 0.0):
        return np.nan
    # Four reciprocals instead of fifteen divisions (the divider bounds this function;
    # 2x faster, measured); rounding of the scaling only, which no certificate uses.
    z_root, s_root = np.sqrt(z_det), np.sqrt(s_det)
    z_inv, s_inv = 1.0 / z_root, 1.0 / s_root
    gamma = np.sqrt(0.5 * (1.0 + (z[0] * s[0] + z[1] * s[1] + z[2] * s[2]) * (z_inv * s_inv)))
    half_inv_gamma = 0.5 / gamma
    v0 = (s[0] * s_inv + z[0] * z_inv) * half_inv_gamma
    v1 = (s[1] * s_inv - z[1] * z_inv) * half_inv_gamma
    v2 = (s[2] * s_inv - z[2] * z_inv) * half_inv_gamma
    eta = np.sqrt(s_root * z_inv)
    off = eta / (1.0 + v0)
    scaling[0, 0] = eta * v0
    scaling[0, 1] = scaling[1, 0] = eta * v1
    scaling[0, 2] = scaling[2, 0] = eta * v2
    scaling[1, 1] = eta + off * v1 * v1
    scaling[2, 2] = eta + off * v2 * v2
    scaling[1, 2] = scaling[2, 1] = off * v1 * v2
    inverse_vector[0], inverse_vector[1], inverse_vector[2] = v0, -v1, -v2
    return z_root * s_inv


def _scaled_inverse_apply(scaling, inv_eta2, x, out):
    """out = W^-1 x = J W J x / eta^2 for W = eta Wbar (``scaling``) and its 1/eta^2."""
    jx0, jx1, jx2 = x[0], -x[1], -x[2]
    for r in range(3):
        sign = 1.0 if r == 0 else -1.0
        out[r] = sign * inv_eta2 * (scaling[r, 0] * jx0 + scaling[r, 1] * jx1 + scaling[r, 2] * jx2)


def _inverse_apply(scaling, x, out):
    """out = W^-1 x from W = eta Wbar alone (1/eta^2 = 1 / det W)."""
    inv_eta2 = 1.0 / (scaling[0, 0] ** 2 - scaling[0, 1] ** 2 - scaling[0, 2] ** 2)
    _scaled_inverse_apply(scaling, inv_eta2, x, out)


def _jordan_product_into(x, y, out):
    """out = x o y (out may not alias x or y)."""
    out0 = x[0] * y[0] + x[1] * y[1] + x[2] * y[2]
    out1 = x[0] * y[1] + y[0] * x[1]
    out2 = x[0] * y[2] + y[0] * x[2]
    out[0], out[1], out[2] = out0, out1, out2


def _jordan_divide_into(lam, r, out):
    """out with lam o out = r."""
    det = lam[0] * lam[0] - lam[1] * lam[1] - lam[2] * lam[2]
    out[0] = (lam[0] * r[0] - lam[1] * r[1] - lam[2] * r[2]) / det
    out[1] = (r[1] - out[0] * lam[1]) / lam[0]
    out[2] = (r[2] - out[0] * lam[2]) / lam[0]


def _max_step(x, dx):
    """Largest alpha (capped at 1e30) with x + alpha dx in the 3-cone, x interior."""
    a = dx[0] * dx[0] - dx[1] * dx[1] - dx[2] * dx[2]
    b = 2.0 * (x[0] * dx[0] - x[1] * dx[1] - x[2] * dx[2])
    c = x[0] * x[0] - x[1] * x[1] - x[2] * x[2]
    # The smallest positive root of a alpha^2 + b alpha + c (c > 0), one division:
    # 2c / (sqrt(D) - b) for b < 0 (both terms positive, no cancellation); for b >= 0 a
    # positive root needs a < 0, and is (-b - sqrt(D)) / (2a), again without cancellation.
    if b < 0.0:
        disc = b * b - 4.0 * a * c
        if disc < 0.0:
            return 1e30      # a > 0 and no real root: dx points into the cone
        return 2.0 * c / (np.sqrt(disc) - b)
    if a < 0.0:
        return (-b - np.sqrt(b * b - 4.0 * a * c)) / (2.0 * a)
    return 1e30          # both roots negative (or none): dx lies in the cone


def _solve_grasp(unit, normals, mu, want_optimum, want_wrench, signed_gap, signed_level,
                 forces_out, wrench_out, work3, work6, rows, a_mat, scalings, mats, work_n,
                 a_gram):
    """Decide one unit-size grasp. Returns (code, t_lo, t_hi, iterations).

    ``signed_gap`` > 0 selects the signed mode (for :mod:`.minimum_friction`): no verdict;
    iterate until the primal-dual gap of the signed margin, (1 + d.w)/sigma - (1 - sum_i
    z0_i)/sigma, is at most ``signed_gap / sigma`` (relative to the trivial bound 1/sigma,
    so relative to the friction scale) or at most SIGNED_RELATIVE_GAP of |t - signed_level|
    (times sigma; the search's distance from its root), and return CONVERGED with the
    best witness in ``forces_out`` and the last iterate's wrench in ``wrench_out`` (the
    optimum's multipliers).

    The remaining arguments are scratch space of the batch, reused from grasp to grasp
    (allocating it per grasp cost ~25% of the run time): work3 (12, n, 3), work6 (13, 6),
    rows (3, n, 6), a_mat (n, 6, 3), scalings (n, 3, 3), mats (4, 6, 6), work_n (2, n),
    a_gram (n, 6, 6).
    """
    n = unit.shape[0]
    (tangent, bitangent, z, s, candidate, jv, lam, dz, ds, u_aff, winv_q,
     projected) = (work3[0], work3[1], work3[2], work3[3], work3[4], work3[5], work3[6],
                   work3[7], work3[8], work3[9], work3[10], work3[11])
    d, trial, g_sum, solved, gg_d, y6, w, g, rhs, dw, scratch, check, y = (
        work6[0], work6[1], work6[2], work6[3], work6[4], work6[5], work6[6], work6[7],
        work6[8], work6[9], work6[10], work6[11], work6[12])
    b_n, b_t1, b_t2 = rows[0], rows[1], rows[2]
    gram, gram_factor, hessian, factor = mats[0], mats[1], mats[2], mats[3]
    inv_eta2, normal_work = work_n[0], work_n[1]
    q, w_dz, second_order = y[:3], y[3:], scratch[:3]

    sigma_min, grasp_norm = _certified_rank(unit, gram, gram_factor, scratch)
    if not sigma_min > 0.0:
        return UNDECIDED, -np.inf, np.inf, 0
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
    _frames(normals, tangent, bitangent)
    _wrench_rows(unit, normals, b_n)
    _wrench_rows(unit, tangent, b_t1)
    _wrench_rows(unit, bitangent, b_t2)
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
    _cholesky_solve(gram_factor, g_sum, solved, scratch)
    schur = n - np.dot(g_sum, solved)
    if not schur > SHARED_NORMAL_TOL * n:
        return UNDECIDED, -np.inf, np.inf, 0
    # y = (y6, y7) of (M M^T) y = (d, 0): y7 = -g.GG^-1 d / schur, y6 = GG^-1 (d - g y7).
    _cholesky_solve(gram_factor, d, gg_d, scratch)
    y7 = -np.dot(g_sum, gg_d) / schur
    for r in range(6):
        solved[r] = d[r] - g_sum[r] * y7
    _cholesky_solve(gram_factor, solved, y6, scratch)
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
    while True:
        d_w = 0.0
        for r in range(6):
            d_w += d[r] * w[r]
        for i in range(n):
            n_w = t1_w = t2_w = 0.0
            for r in range(6):
                n_w += b_n[i, r] * w[r]
                t1_w += b_t1[i, r] * w[r]
                t2_w += b_t2[i, r] * w[r]
            s[i, 0] = 1.0 + d_w - n_w
            s[i, 1] = mu[i] * t1_w
            s[i, 2] = mu[i] * t2_w
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
            depth = _witness(unit, normals, tangent, bitangent, mu, z, sigma, gram_factor,
                             sigma_min, grasp_norm, candidate, projected, y, check, scratch)
            if depth > t_lo:
                t_lo = depth
                forces_out[:] = candidate
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
            close = t_hi - max(t_lo, 0.0) <= MARGIN_ACCURACY
            if t_lo >= MARGIN_TOL and (close or not want_optimum):
                return FORCE_CLOSURE, t_lo, t_hi, iteration
            if (t_hi < MARGIN_TOL and (separated or not want_wrench)
                    and (close or not want_optimum)):
                return NOT_FORCE_CLOSURE, t_lo, t_hi, iteration
        if last or iteration == MAX_ITERATIONS:
            break

        # Newton system: H dw = rhs, H = sum A_i W_i^-2 A_i^T, with W_i^-2 = (2 (Jv)(Jv)^T
        # - J) / eta^2: A_i W_i^-2 A_i^T = (2 g g^T - A_i J A_i^T) / eta^2, g = A_i J v;
        # A_i J A_i^T does not change, so it is kept from the first iteration (a_gram)
        # and each later one costs a rank-one update.
        hessian[:] = 0.0
        gap = 0.0
        finite = True
        for i in range(n):
            inv_eta2[i] = _nt_scaling(z[i], s[i], scalings[i], jv[i])
            if not np.isfinite(inv_eta2[i]):
                finite = False
                break
            for r in range(3):
                lam[i, r] = scalings[i, r, 0] * z[i, 0] + scalings[i, r, 1] * z[i, 1] + scalings[i, r, 2] * z[i, 2]
            for r in range(6):
                g[r] = a_mat[i, r, 0] * jv[i, 0] + a_mat[i, r, 1] * jv[i, 1] + a_mat[i, r, 2] * jv[i, 2]
            if iteration == 0:
                for r in range(6):
                    for c in range(r + 1):
                        a_gram[i, r, c] = (a_mat[i, r, 1] * a_mat[i, c, 1] + a_mat[i, r, 2] * a_mat[i, c, 2]
                                           - a_mat[i, r, 0] * a_mat[i, c, 0])
            for r in range(6):
                for c in range(r + 1):
                    hessian[r, c] += inv_eta2[i] * (2.0 * g[r] * g[c] + a_gram[i, r, c])
            gap += z[i, 0] * s[i, 0] + z[i, 1] * s[i, 1] + z[i, 2] * s[i, 2]
        if not finite:
            last = True
            continue
        for r in range(6):
            for c in range(r):
                hessian[c, r] = hessian[r, c]
        if not _cholesky(hessian, factor):
            last = True
            continue
        # Predictor (affine) direction: lam o (W dz + W^-1 ds) = -lam o lam gives
        # W dz + W^-1 ds = -lam, W^-1 (-lam) = -z, and the right-hand side -r_p + sum_i
        # A_i z_i is -d exactly (r_p = sum_i A_i z_i + d): no residual, no Jordan division.
        # In scaled form, u = W^-1 ds and W dz = -lam - u; W maps the cone onto itself,
        # so the step to its boundary is that of lam along u and along -lam - u.
        for r in range(6):
            rhs[r] = -d[r]
        _cholesky_solve(factor, rhs, dw, scratch)
        alpha = 1e30
        for i in range(n):
            for k in range(3):
                acc = 0.0
                for r in range(6):
                    acc -= a_mat[i, r, k] * dw[r]
                ds[i, k] = acc
            _scaled_inverse_apply(scalings[i], inv_eta2[i], ds[i], u_aff[i])
            for k in range(3):
                w_dz[k] = -lam[i, k] - u_aff[i, k]
            alpha = min(alpha, _max_step(lam[i], u_aff[i]), _max_step(lam[i], w_dz))
        # Mehrotra's centring from the affine step: for feasible iterates dz . ds = 0,
        # so that step would leave the gap (1 - alpha) gap.
        shrink = 1.0 - min(1.0, alpha)
        if want_optimum:
            centring = min(OPTIMUM_CENTRING_CAP, shrink ** OPTIMUM_CENTRING_POWER)
        else:
            centring = shrink ** 3
        target = centring * (gap / n)
        # Corrector: lam o (W dz + W^-1 ds) = -lam o lam - u o (-lam - u) + target e, so
        # W dz + W^-1 ds = -lam + p with p = lam \ (u o (lam + u) + target e); as above
        # the right-hand side becomes -d - sum_i A_i W^-1 p_i and dz = -z + W^-1 p - W^-2 ds.
        for r in range(6):
            rhs[r] = -d[r]
        for i in range(n):
            for k in range(3):
                w_dz[k] = lam[i, k] + u_aff[i, k]     # -W dz of the predictor
            _jordan_product_into(u_aff[i], w_dz, second_order)
            second_order[0] += target
            _jordan_divide_into(lam[i], second_order, q)
            _scaled_inverse_apply(scalings[i], inv_eta2[i], q, winv_q[i])
            for r in range(6):
                rhs[r] -= (a_mat[i, r, 0] * winv_q[i, 0] + a_mat[i, r, 1] * winv_q[i, 1]
                           + a_mat[i, r, 2] * winv_q[i, 2])
        _cholesky_solve(factor, rhs, dw, scratch)
        alpha = 1e30
        for i in range(n):
            for k in range(3):
                acc = 0.0
                for r in range(6):
                    acc -= a_mat[i, r, k] * dw[r]
                ds[i, k] = acc
            # W^-2 ds = (2 Jv (Jv . ds) - J ds) / eta^2
            proj = jv[i, 0] * ds[i, 0] + jv[i, 1] * ds[i, 1] + jv[i, 2] * ds[i, 2]
            for k in range(3):
                j_ds = ds[i, k] if k == 0 else -ds[i, k]
                dz[i, k] = winv_q[i, k] - z[i, k] - inv_eta2[i] * (2.0 * jv[i, k] * proj - j_ds)
            alpha = min(alpha, _max_step(z[i], dz[i]), _max_step(s[i], ds[i]))
        alpha = min(1.0, STEP_FRACTION * alpha)
        if not alpha > MIN_STEP:
            last = True
            continue
        for i in range(n):
            for k in range(3):
                z[i, k] += alpha * dz[i, k]
        for r in range(6):
            w[r] += alpha * dw[r]
        iteration += 1
    if t_lo >= MARGIN_TOL and not signed:
        return FORCE_CLOSURE, t_lo, t_hi, iteration
    if t_hi < MARGIN_TOL and not signed:
        return NOT_FORCE_CLOSURE, t_lo, t_hi, iteration
    return UNDECIDED, t_lo, t_hi, iteration


def _solve_all(unit, normals, mu, want_optimum, want_wrench, signed_gap, signed_level):
    n_grasps, n_contacts = mu.shape
    codes = np.empty(n_grasps, dtype=np.int8)
    t_lo = np.empty(n_grasps)
    t_hi = np.empty(n_grasps)
    iterations = np.empty(n_grasps, dtype=np.int32)
    forces = np.full((n_grasps, n_contacts, 3), np.nan)
    wrench = np.full((n_grasps, 6), np.nan)
    work3 = np.empty((12, n_contacts, 3))
    work6 = np.empty((13, 6))
    rows = np.empty((3, n_contacts, 6))
    a_mat = np.empty((n_contacts, 6, 3))
    scalings = np.empty((n_contacts, 3, 3))
    mats = np.empty((4, 6, 6))
    work_n = np.empty((2, n_contacts))
    a_gram = np.empty((n_contacts, 6, 6))
    for g in range(n_grasps):
        codes[g], t_lo[g], t_hi[g], iterations[g] = _solve_grasp(
            unit[g], normals[g], mu[g], want_optimum, want_wrench, signed_gap, signed_level,
            forces[g], wrench[g], work3, work6, rows, a_mat, scalings, mats, work_n, a_gram)
    return codes, t_lo, t_hi, iterations, forces, wrench


for _name in ("_frames", "_wrench_rows", "_work_at", "_normal_split", "_gram", "_apply_grasp_map", "_cholesky_solve",
              "_cholesky", "_triangular_inverse_norm2", "_certified_rank", "_witness",
              "_unprojected_depth", "_bound", "_nt_scaling", "_scaled_inverse_apply",
              "_inverse_apply", "_jordan_product_into", "_jordan_divide_into", "_max_step",
              "_solve_grasp", "_solve_all"):
    globals()[_name] = _jit(globals()[_name])


def solve_fast(unit: np.ndarray, normals: np.ndarray, mu: np.ndarray,
               want_optimum: bool = False, want_wrench: bool = False,
               signed_gap: float = 0.0, signed_level: float = 0.0):
    """Run the fast exact stage on unit-size grasps.

    Parameters
    ----------
    unit : ndarray, shape (N, n, 3)
        Positions centred at the centroid and scaled to unit size.
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
    return _solve_all(kernel_array(unit), kernel_array(normals),
                      kernel_array(mu), bool(want_optimum), bool(want_wrench),
                      float(signed_gap), float(signed_level))


def warm_up() -> None:
    """Compile (or load from the cache) the kernel for every mode: a ROS node calls
    this before it reports ready, so no query pays the compile."""
    unit = np.array([[[1.0, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]]])
    for optimum in (False, True):
        for wrench in (False, True):
            solve_fast(unit, -unit / np.sqrt(3.0), np.full((1, 4), 0.5), optimum, wrench)
    solve_fast(unit, -unit / np.sqrt(3.0), np.full((1, 4), 0.5), signed_gap=1e-11)
