"""The 6 x 6 Cholesky and L D L^T factors, their solves and the norm of an inverse (numba).

Every loop runs over the literal size 6, which lets the compiler unroll it (faster than
loops over ``shape[0]``), and each divides by a diagonal entry once, multiplying by its
reciprocal after: the substitutions are chains of dependent operations, where a division
costs several multiplications (tuned: docs/performance.md#exact-stage). Results differ
from divisions by at most an ulp per step; every caller checks what it uses (a projection
by its residual, a rank bound with its own margin).
"""

from __future__ import annotations

from typing import TypeAlias

import numpy as np

from .jit import jit

#: The six reciprocals of a 6 x 6 triangular factor's diagonal.
Diagonal6: TypeAlias = tuple[float, float, float, float, float, float]


@jit
def cholesky(matrix: np.ndarray, factor: np.ndarray) -> bool:
    """Lower Cholesky factor L (L L^T = matrix) of a symmetric 6 x 6 matrix.

    Parameters
    ----------
    matrix : ndarray, shape (6, 6)
        Only its lower triangle is read.
    factor : ndarray, shape (6, 6)
        Output: L, zero above the diagonal.

    Returns
    -------
    bool
        False on a pivot that is not positive (``factor`` is then incomplete).
    """
    factor[:] = 0.0
    # Column by column, so that each column's reciprocal is taken once and held in a
    # register (by rows, the compiler took it again for every entry: it cannot tell the
    # factor from the matrix and reloads the pivot after every store).
    for c in range(6):
        acc = matrix[c, c]
        for k in range(c):
            acc -= factor[c, k] * factor[c, k]
        if not acc > 0.0:
            return False
        pivot = np.sqrt(acc)
        factor[c, c] = pivot
        inverse = 1.0 / pivot
        for r in range(c + 1, 6):
            acc = matrix[r, c]
            for k in range(c):
                acc -= factor[r, k] * factor[c, k]
            factor[r, c] = acc * inverse
    return True


@jit
def cholesky_solve(factor: np.ndarray, rhs: np.ndarray, x: np.ndarray,
                   y: np.ndarray) -> None:
    """Solve (L L^T) x = rhs by forward and back substitution.

    Parameters
    ----------
    factor : ndarray, shape (6, 6)
        Lower-triangular L (from :func:`cholesky`).
    rhs : ndarray, shape (6,)
    x : ndarray, shape (6,)
        Output; may be ``rhs`` itself.
    y : ndarray, shape (6,)
        Scratch.
    """
    substitute(factor, diagonal_reciprocals(factor), rhs, x, y)


@jit
def diagonal_reciprocals(factor: np.ndarray) -> Diagonal6:
    """1 / L_rr for r = 0..5: what :func:`substitute` takes, for callers that solve
    with one factor several times.

    Parameters
    ----------
    factor : ndarray, shape (6, 6)
        Lower-triangular L with a nonzero diagonal.

    Returns
    -------
    Diagonal6
    """
    return (1.0 / factor[0, 0], 1.0 / factor[1, 1], 1.0 / factor[2, 2], 1.0 / factor[3, 3],
            1.0 / factor[4, 4], 1.0 / factor[5, 5])


@jit
def substitute(factor: np.ndarray, inverse: Diagonal6, rhs: np.ndarray, x: np.ndarray,
               y: np.ndarray) -> None:
    """:func:`cholesky_solve` with the reciprocals of L's diagonal given.

    Parameters
    ----------
    factor : ndarray, shape (6, 6)
        Lower-triangular L (from :func:`cholesky`).
    inverse : Diagonal6
        :func:`diagonal_reciprocals` of ``factor``.
    rhs : ndarray, shape (6,)
    x : ndarray, shape (6,)
        Output; may be ``rhs`` itself.
    y : ndarray, shape (6,)
        Scratch.
    """
    for r in range(6):
        acc = rhs[r]
        for c in range(r):
            acc -= factor[r, c] * y[c]
        y[r] = acc * inverse[r]
    for r in range(5, -1, -1):
        acc = y[r]
        for c in range(r + 1, 6):
            acc -= factor[c, r] * x[c]
        x[r] = acc * inverse[r]


@jit
def ldl(matrix: np.ndarray, factor: np.ndarray) -> bool:
    """L D L^T of a symmetric positive definite 6 x 6 matrix, for Newton systems.

    Each column costs one division and no root, where :func:`cholesky`'s costs a root
    and then a division: the columns form one chain of dependent operations, which this
    shortens (tuned: docs/performance.md#exact-stage). For the Newton systems only;
    certificates use :func:`cholesky`. Unfused, like every kernel (:func:`.jit.jit`).

    Parameters
    ----------
    matrix : ndarray, shape (6, 6)
        Only its lower triangle is read.
    factor : ndarray, shape (6, 6)
        Output: L's strict lower triangle (unit diagonal implied), 1/D on the diagonal,
        and L D (scratch) above it, transposed.

    Returns
    -------
    bool
        False on a pivot that is not positive (``factor`` is then incomplete).
    """
    for c in range(6):
        acc = matrix[c, c]
        for k in range(c):
            acc -= factor[c, k] * factor[k, c]
        if not acc > 0.0:
            return False
        inverse = 1.0 / acc
        factor[c, c] = inverse
        for r in range(c + 1, 6):
            acc = matrix[r, c]
            for k in range(c):
                acc -= factor[r, k] * factor[k, c]
            factor[c, r] = acc                         # (L D)[r, c]
            factor[r, c] = acc * inverse
    return True


@jit
def ldl_substitute(factor: np.ndarray, rhs: np.ndarray, x: np.ndarray) -> None:
    """Solve (L D L^T) x = rhs with the factor of :func:`ldl`.

    Parameters
    ----------
    factor : ndarray, shape (6, 6)
        From :func:`ldl`.
    rhs : ndarray, shape (6,)
    x : ndarray, shape (6,)
        Output; may be ``rhs`` itself.
    """
    for r in range(6):
        acc = rhs[r]
        for c in range(r):
            acc -= factor[r, c] * x[c]
        x[r] = acc
    for r in range(6):
        x[r] *= factor[r, r]
    for r in range(5, -1, -1):
        acc = x[r]
        for c in range(r + 1, 6):
            acc -= factor[c, r] * x[c]
        x[r] = acc


@jit
def triangular_inverse_norm2(factor: np.ndarray, column: np.ndarray) -> float:
    """|L^-1|_F^2 of a lower-triangular 6 x 6 L, by forward substitution column by column.

    Parameters
    ----------
    factor : ndarray, shape (6, 6)
        Lower-triangular L with a positive diagonal.
    column : ndarray, shape (6,)
        Scratch.

    Returns
    -------
    float
    """
    i0, i1, i2 = 1.0 / factor[0, 0], 1.0 / factor[1, 1], 1.0 / factor[2, 2]
    i3, i4, i5 = 1.0 / factor[3, 3], 1.0 / factor[4, 4], 1.0 / factor[5, 5]
    inverse = (i0, i1, i2, i3, i4, i5)
    total = 0.0
    for k in range(6):
        for r in range(6):
            if r < k:
                column[r] = 0.0
                continue
            acc = 1.0 if r == k else 0.0
            for c in range(k, r):
                acc -= factor[r, c] * column[c]
            column[r] = acc * inverse[r]
            total += column[r] * column[r]
    return total
