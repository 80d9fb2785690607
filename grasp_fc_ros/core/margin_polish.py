"""Active-set Newton polish of the exact stage's margin (numba).

Near the optimum of the margin problem of :mod:`.interior_point` (primal z_i, dual
s_i = e0 - A_i^T w, both in Q^3, z_i o s_i = 0), each contact is in one of three states:

* S: z_i = 0, s_i interior (a bottleneck contact pushing along its normal only);
* B: both on the cone boundary, z_i = lambda_i J s_i with lambda_i > 0;
* Z: s_i = 0, z_i interior (the wrench does no tangential work there).

Once the interior-point iterates show which contact is in which state, the optimum
solves the square system

    sum_{B} lambda_i A_i J s_i(w) + sum_{Z} A_i z_i + d = 0     (6 rows)
    s_i(w)^T J s_i(w) / 2 = 0                               (one row per B contact)
    s_i(w) = 0                                              (three rows per Z contact)

in (w, lambda_B, z_Z), on which Newton's method converges quadratically, where the
interior-point method gains a roughly constant factor per iteration. Nothing here is
trusted: the caller checks the polished point with the same certificates as every
iterate (a witness from z, a bound from w), and where they do not close the interval
it carries on with its own iterates, which the polish leaves untouched.
"""

from __future__ import annotations

import numpy as np

from ._kernels.jit import jit
from ._kernels.linear_algebra import cholesky, cholesky_solve

#: Contact states (see the module docstring).
STATE_S, STATE_B, STATE_Z = 0, 1, 2

#: Rows of the polish system beyond the six of the wrench: a nondegenerate optimum has
#: at most six (one per B contact, three per Z contact); more means the states were
#: misread, and the polish is not tried.
MAX_STATE_ROWS = 6

#: rho of the Newton step's regularised first block K + rho C C^T, relative to the
#: larger of the largest diagonal entry of K and of C C^T's scale: large enough that
#: the block is positive definite where K is so on the null space of C^T, small enough
#: to lose few digits (tuned: docs/performance.md#exact-stage).
POLISH_PENALTY = 1e5


@jit
def read_states(z: np.ndarray, s: np.ndarray, complementarity: float,
                states: np.ndarray) -> int:
    """Each contact's state from an interior-point iterate; the number of state rows.

    The larger eigenvalue of z_i (z0 + |z_t|) shrinks like the iterate's mean
    complementarity at an S contact and stays of order one at a B or Z contact (and
    likewise that of s_i): a contact is read as S when the ratio of the two is below the
    square root of the mean complementarity, Z when above its reciprocal, B otherwise.

    Parameters
    ----------
    z, s : ndarray, shape (n, 3)
        Primal and dual iterates (interior).
    complementarity : float
        sum_i z_i . s_i / n.
    states : ndarray of int64, shape (n,)
        Output: STATE_S, STATE_B or STATE_Z per contact.

    Returns
    -------
    int
        The number of state rows, or -1 where it exceeds MAX_STATE_ROWS.
    """
    split = np.sqrt(complementarity)
    rows = 0
    for i in range(z.shape[0]):
        z_big = z[i, 0] + np.sqrt(z[i, 1] * z[i, 1] + z[i, 2] * z[i, 2])
        s_big = s[i, 0] + np.sqrt(s[i, 1] * s[i, 1] + s[i, 2] * s[i, 2])
        if z_big < split * s_big:
            states[i] = STATE_S
        elif s_big < split * z_big:
            states[i] = STATE_Z
            rows += 3
        else:
            states[i] = STATE_B
            rows += 1
    return rows if rows <= MAX_STATE_ROWS else -1


@jit
def start_polish(z: np.ndarray, s: np.ndarray, w: np.ndarray, states: np.ndarray,
                 w_polish: np.ndarray, lam: np.ndarray, z_polish: np.ndarray) -> None:
    """Newton's starting point from the iterate: w, lambda_i = z_big / s_big at B
    contacts, z_i at Z contacts (into ``w_polish`` (6,), ``lam`` (n,), ``z_polish``
    (n, 3))."""
    w_polish[:] = w
    for i in range(z.shape[0]):
        if states[i] == STATE_B:
            z_big = z[i, 0] + np.sqrt(z[i, 1] * z[i, 1] + z[i, 2] * z[i, 2])
            s_big = s[i, 0] + np.sqrt(s[i, 1] * s[i, 1] + s[i, 2] * s[i, 2])
            lam[i] = z_big / s_big
        elif states[i] == STATE_Z:
            z_polish[i, 0], z_polish[i, 1], z_polish[i, 2] = z[i, 0], z[i, 1], z[i, 2]


@jit
def _dual_slack(a_mat: np.ndarray, w: np.ndarray, i: int) -> tuple[float, float, float]:
    """s_i(w) = e0 - A_i^T w."""
    s0, s1, s2 = 1.0, 0.0, 0.0
    for r in range(6):
        s0 -= a_mat[i, r, 0] * w[r]
        s1 -= a_mat[i, r, 1] * w[r]
        s2 -= a_mat[i, r, 2] * w[r]
    return s0, s1, s2


@jit
def newton_step(a_mat: np.ndarray, a_gram: np.ndarray, d: np.ndarray, states: np.ndarray,
                w_polish: np.ndarray, lam: np.ndarray, z_polish: np.ndarray,
                system: np.ndarray) -> float:
    """One Newton step on the polish system, in place on (w_polish, lam, z_polish).

    The step solves [[K, C], [C^T, 0]] (dw, dy) = (r1, r2), K = sum_B lambda_i A_i (-J)
    A_i^T (symmetric, positive definite on the null space of C^T at a nondegenerate
    optimum), C the state rows' gradients, as [[K + rho C C^T, C], [C^T, 0]] (dw, dy) =
    (r1 + rho C r2, r2), which has the same solution and, for rho large enough, a
    positive definite first block: a 6 x 6 Cholesky factor and the m x m Schur
    complement C^T (K + rho C C^T)^-1 C, no pivoting.

    Parameters
    ----------
    a_mat : ndarray, shape (n, 6, 3)
        The A_i of :mod:`.interior_point`.
    a_gram : ndarray, shape (n, 6, 6)
        A_i (-J) A_i^T, lower triangles.
    d : ndarray, shape (6,)
    states : ndarray of int64, shape (n,)
        From :func:`read_states` (at most MAX_STATE_ROWS state rows).
    w_polish, lam, z_polish : ndarrays, shapes (6,), (n,), (n, 3)
    system : ndarray, shape (6, 6, 6)
        Scratch.

    Returns
    -------
    float
        The step's largest change of a variable; inf where a factorisation failed or
        the step is not finite.
    """
    k_mat, factor, c_rows, x_rows, schur, vectors = (system[0], system[1], system[2],
                                                     system[3], system[4], system[5])
    r1, x0, r2, rhs_y, dy, scratch = (vectors[0], vectors[1], vectors[2], vectors[3],
                                      vectors[4], vectors[5])
    k_mat[:] = 0.0
    for r in range(6):
        r1[r] = -d[r]
    m = 0
    for i in range(a_mat.shape[0]):
        if states[i] == STATE_S:
            continue
        s0, s1, s2 = _dual_slack(a_mat, w_polish, i)
        if states[i] == STATE_B:
            weight = lam[i]
            for r in range(6):
                for c in range(r + 1):
                    k_mat[r, c] += weight * a_gram[i, r, c]
                g = a_mat[i, r, 0] * s0 - a_mat[i, r, 1] * s1 - a_mat[i, r, 2] * s2
                c_rows[m, r] = g
                r1[r] -= weight * g
            r2[m] = 0.5 * (s0 * s0 - s1 * s1 - s2 * s2)
            m += 1
        else:
            slack = (s0, s1, s2)
            for j in range(3):
                for r in range(6):
                    c_rows[m, r] = a_mat[i, r, j]
                    r1[r] -= a_mat[i, r, j] * z_polish[i, j]
                r2[m] = slack[j]
                m += 1
    k_scale = 0.0
    c_scale = 0.0
    for r in range(6):
        k_scale = max(k_scale, abs(k_mat[r, r]))
    for j in range(m):
        for r in range(6):
            c_scale = max(c_scale, c_rows[j, r] * c_rows[j, r])
    if not c_scale > 0.0:
        return np.inf
    rho = POLISH_PENALTY * max(k_scale, c_scale) / c_scale
    for j in range(m):
        for r in range(6):
            scaled = rho * c_rows[j, r]
            r1[r] += scaled * r2[j]
            for c in range(r + 1):
                k_mat[r, c] += scaled * c_rows[j, c]
    if not cholesky(k_mat, factor):
        return np.inf
    cholesky_solve(factor, r1, x0, scratch)
    for j in range(m):
        cholesky_solve(factor, c_rows[j], x_rows[j], scratch)
    for j in range(m):
        acc = -r2[j]
        for r in range(6):
            acc += c_rows[j, r] * x0[r]
        rhs_y[j] = acc
        for k in range(j + 1):
            acc = 0.0
            for r in range(6):
                acc += c_rows[j, r] * x_rows[k, r]
            schur[j, k] = acc
    if not _small_cholesky_solve(schur, rhs_y, dy, m):
        return np.inf
    change = 0.0
    for r in range(6):
        acc = x0[r]
        for j in range(m):
            acc -= x_rows[j, r] * dy[j]
        w_polish[r] += acc
        change = max(change, abs(acc))
    k = 0
    for i in range(a_mat.shape[0]):
        if states[i] == STATE_B:
            lam[i] += dy[k]
            change = max(change, abs(dy[k]))
            k += 1
        elif states[i] == STATE_Z:
            for j in range(3):
                z_polish[i, j] += dy[k + j]
                change = max(change, abs(dy[k + j]))
            k += 3
    return change if np.isfinite(change) else np.inf


@jit
def _small_cholesky_solve(matrix: np.ndarray, rhs: np.ndarray, x: np.ndarray,
                          m: int) -> bool:
    """Solve matrix x = rhs for a symmetric positive definite m x m matrix (its lower
    triangle, overwritten by the factor); False on a pivot that is not positive."""
    for r in range(m):
        for c in range(r + 1):
            acc = matrix[r, c]
            for k in range(c):
                acc -= matrix[r, k] * matrix[c, k]
            if r == c:
                if not acc > 0.0:
                    return False
                matrix[r, r] = np.sqrt(acc)
            else:
                matrix[r, c] = acc / matrix[c, c]
    for r in range(m):
        acc = rhs[r]
        for c in range(r):
            acc -= matrix[r, c] * x[c]
        x[r] = acc / matrix[r, r]
    for r in range(m - 1, -1, -1):
        acc = x[r]
        for c in range(r + 1, m):
            acc -= matrix[c, r] * x[c]
        x[r] = acc / matrix[r, r]
    return True


@jit
def polished_forces(a_mat: np.ndarray, states: np.ndarray, w_polish: np.ndarray,
                    lam: np.ndarray, z_polish: np.ndarray, z_out: np.ndarray) -> None:
    """The primal point of the polish, z_i = 0 (S), lambda_i J s_i(w) (B), z_i (Z),
    into ``z_out`` (n, 3) for the witness."""
    for i in range(a_mat.shape[0]):
        if states[i] == STATE_S:
            z_out[i, 0] = z_out[i, 1] = z_out[i, 2] = 0.0
        elif states[i] == STATE_B:
            s0, s1, s2 = _dual_slack(a_mat, w_polish, i)
            z_out[i, 0], z_out[i, 1], z_out[i, 2] = lam[i] * s0, -lam[i] * s1, -lam[i] * s2
        else:
            z_out[i, 0], z_out[i, 1], z_out[i, 2] = z_polish[i, 0], z_polish[i, 1], z_polish[i, 2]
