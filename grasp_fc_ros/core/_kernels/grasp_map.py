"""The grasp map G of point contacts with global force components (numba).

G maps forces f (n, 3) at the contacts to their net wrench sum_i (f_i, p_i x f_i); its
block for contact i is G_i = [I; [p_i]x] (6 x 3). Positions are those of a unit-size
grasp.
"""

from __future__ import annotations

import numpy as np

from ..tolerances import FAST_RANK_TOL
from .jit import jit
from .linear_algebra import cholesky, triangular_inverse_norm2


@jit
def normalise_grasp(positions: np.ndarray, peak: float, unit: np.ndarray) -> None:
    """:func:`..certificates.normalise_positions` of one grasp, with the same arithmetic:
    scale by the largest |coordinate| ``peak``, centre at the mean, scale to unit size.

    Parameters
    ----------
    positions : ndarray, shape (n, 3)
        Contact positions (any length unit).
    peak : float
        max |positions|; 0 (all contacts at the origin) is taken as 1.
    unit : ndarray, shape (n, 3)
        Output: the unit-size grasp, every coordinate in [-1, 1].
    """
    n = positions.shape[0]
    if not peak > 0.0:
        peak = 1.0
    size = 0.0
    for k in range(3):
        total = 0.0
        for i in range(n):
            total += positions[i, k] / peak
        centre = total / n
        for i in range(n):
            unit[i, k] = positions[i, k] / peak - centre
            size = max(size, abs(unit[i, k]))
    if not size > 0.0:
        size = 1.0
    for i in range(n):
        for k in range(3):
            unit[i, k] = unit[i, k] / size


@jit
def gram(unit: np.ndarray, out: np.ndarray) -> None:
    """G G^T = [[n I, -sum [p]x], [sum [p]x, sum (|p|^2 I - p p^T)]].

    Parameters
    ----------
    unit : ndarray, shape (n, 3)
        Contact positions.
    out : ndarray, shape (6, 6)
        Output.
    """
    out[:] = 0.0
    sx = sy = sz = 0.0
    for i in range(unit.shape[0]):
        x, y, z = unit[i, 0], unit[i, 1], unit[i, 2]
        sx += x
        sy += y
        sz += z
        square = x * x + y * y + z * z
        for r in range(3):
            for c in range(3):
                out[3 + r, 3 + c] -= unit[i, r] * unit[i, c]
            out[3 + r, 3 + r] += square
    for r in range(3):
        out[r, r] = unit.shape[0]
    # sum [u]x = [[0, -sz, sy], [sz, 0, -sx], [-sy, sx, 0]] in the lower-left block.
    cross = ((0.0, -sz, sy), (sz, 0.0, -sx), (-sy, sx, 0.0))
    for r in range(3):
        for c in range(3):
            out[3 + r, c] = cross[r][c]
            out[c, 3 + r] = cross[r][c]


@jit
def apply_grasp_map(unit: np.ndarray, forces: np.ndarray, out: np.ndarray) -> None:
    """The net wrench G f of forces at the contacts.

    Parameters
    ----------
    unit : ndarray, shape (n, 3)
        Contact positions.
    forces : ndarray, shape (n, 3)
        Global force components.
    out : ndarray, shape (6,)
        Output.
    """
    # Summed in locals, stored once: stores into ``out`` inside the loop made the
    # compiler reload the operands after each (the same sums in the same order).
    f0 = f1 = f2 = t0 = t1 = t2 = 0.0
    for i in range(unit.shape[0]):
        u0, u1, u2 = unit[i, 0], unit[i, 1], unit[i, 2]
        g0, g1, g2 = forces[i, 0], forces[i, 1], forces[i, 2]
        f0 += g0
        f1 += g1
        f2 += g2
        t0 += u1 * g2 - u2 * g1
        t1 += u2 * g0 - u0 * g2
        t2 += u0 * g1 - u1 * g0
    out[0], out[1], out[2], out[3], out[4], out[5] = f0, f1, f2, t0, t1, t2


@jit
def add_wrench(force: np.ndarray, point: np.ndarray, scale: float, out: np.ndarray) -> None:
    """out += scale G_i f: the wrench (f, point x f) of one force, scaled.

    Parameters
    ----------
    force : ndarray, shape (3,)
    point : ndarray, shape (3,)
    scale : float
    out : ndarray, shape (6,)
        Accumulated in place.
    """
    out[0] += scale * force[0]
    out[1] += scale * force[1]
    out[2] += scale * force[2]
    out[3] += scale * (point[1] * force[2] - point[2] * force[1])
    out[4] += scale * (point[2] * force[0] - point[0] * force[2])
    out[5] += scale * (point[0] * force[1] - point[1] * force[0])


@jit
def add_congruence(q: np.ndarray, point: np.ndarray, out: np.ndarray, t: np.ndarray) -> None:
    """out += G_i q G_i^T for a symmetric q and G_i = [I; [point]x].

    With t = [point]x q the blocks are q, t^T, t and [point]x t^T.

    Parameters
    ----------
    q : ndarray, shape (3, 3)
        Symmetric.
    point : ndarray, shape (3,)
    out : ndarray, shape (6, 6)
        Accumulated in place.
    t : ndarray, shape (3, 3)
        Scratch.
    """
    for col in range(3):
        t[0, col] = point[1] * q[2, col] - point[2] * q[1, col]
        t[1, col] = point[2] * q[0, col] - point[0] * q[2, col]
        t[2, col] = point[0] * q[1, col] - point[1] * q[0, col]
    for r in range(3):
        for col in range(3):
            out[r, col] += q[r, col]
            out[3 + r, col] += t[r, col]
            out[col, 3 + r] += t[r, col]
    for col in range(3):
        out[3, 3 + col] += point[1] * t[col, 2] - point[2] * t[col, 1]
        out[4, 3 + col] += point[2] * t[col, 0] - point[0] * t[col, 2]
        out[5, 3 + col] += point[0] * t[col, 1] - point[1] * t[col, 0]


@jit
def certified_rank(unit: np.ndarray, gram_out: np.ndarray, gram_factor: np.ndarray,
                   scratch: np.ndarray) -> tuple[float, float]:
    """A certified lower bound on sigma_min(G), and |G|_F, where rank 6 is clear.

    lambda_min(G G^T) = 1 / |L^-T L^-1|_2 >= 1 / |L^-1|_F^2 for the Cholesky factor L:
    a lower bound on sigma_min, so slacks built on it err on the safe side;
    lambda_max <= trace likewise.

    Parameters
    ----------
    unit : ndarray, shape (n, 3)
        Contact positions.
    gram_out : ndarray, shape (6, 6)
        Output: G G^T.
    gram_factor : ndarray, shape (6, 6)
        Output: its lower Cholesky factor (incomplete where the first value is 0).
    scratch : ndarray, shape (6,)

    Returns
    -------
    (float, float)
        (sigma_min bound, |G|_F); the bound is 0 where rank 6 is not certain
        (sigma_min^2 <= FAST_RANK_TOL^2 trace(G G^T)).
    """
    gram(unit, gram_out)
    trace = np.trace(gram_out)
    if not cholesky(gram_out, gram_factor):
        return 0.0, np.sqrt(trace)
    lambda_min = 1.0 / triangular_inverse_norm2(gram_factor, scratch)
    if not lambda_min > FAST_RANK_TOL * FAST_RANK_TOL * trace:
        return 0.0, np.sqrt(trace)
    return np.sqrt(lambda_min), np.sqrt(trace)
