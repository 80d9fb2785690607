"""Many small conic programs of one shape, solved as one block-diagonal Clarabel problem.

Each grasp contributes the same block: ``A_g x_g + s_g = b_g``, ``s_g`` in the same list
of cones, cost ``q_g . x_g``, with the same sparsity pattern for every grasp. Stacking
them pays Python and set-up costs once per batch (as :mod:`.exact_test` does). The
blocks do not interact, so the stacked optimum is every grasp's own optimum; only the
solver's stopping rule is shared, which callers cover by checking every answer in numpy.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any, TypeAlias

import clarabel
import numpy as np
from scipy import sparse  # clarabel's Python API takes scipy CSC matrices

#: Grasps per Clarabel solve: the exact test's (see exact_test.py).
SOLVE_BATCH = 64

#: Interior-point iterations allowed per solve; an unconverged batch is retried alone.
MAX_ITERATIONS = 200

ACCEPTED = (clarabel.SolverStatus.Solved, clarabel.SolverStatus.AlmostSolved)


#: :meth:`BlockShape.key`: pattern bytes, pattern shape, zero rows, non-negative rows,
#: cone sizes.
StructureKey: TypeAlias = tuple[bytes, tuple[int, ...], int, int, tuple[int, ...]]


@dataclass(frozen=True)
class BlockShape:
    """The shape every grasp's block shares.

    Attributes
    ----------
    pattern : ndarray of bool, shape (m, v)
        Where a block's constraint matrix may be non-zero.
    zero_rows : int
        The first ``zero_rows`` rows are equalities (Clarabel's zero cone).
    nonneg_rows : int
        The next rows are inequalities ``A x <= b`` (non-negative slack).
    soc_sizes : tuple of int
        The remaining rows, in order, form second-order cones of these sizes.
    """

    pattern: np.ndarray
    zero_rows: int
    nonneg_rows: int
    soc_sizes: tuple[int, ...]

    def key(self) -> StructureKey:
        """A hashable summary of the shape (for the cache of stacked structures)."""
        return (self.pattern.tobytes(), self.pattern.shape, self.zero_rows,
                self.nonneg_rows, self.soc_sizes)


@dataclass(frozen=True)
class StackedSolution:
    """The answer of one stacked solve of N blocks.

    Attributes
    ----------
    x : ndarray, shape (N, v)
        Primal variables per grasp.
    z : ndarray, shape (N, m)
        Dual variables (cone multipliers) per grasp, Clarabel's sign convention:
        ``P x + q + A^T z = 0``.
    converged : bool
        Clarabel reported Solved or AlmostSolved.
    """

    x: np.ndarray
    z: np.ndarray
    converged: bool


@lru_cache(maxsize=64)
def _stacked_structure(n_blocks: int, key: StructureKey
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[int, int],
                                  list[Any], sparse.csc_matrix]:
    """CSC structure of N stacked blocks, and the order that maps values into it."""
    pattern_bytes, shape, zero_rows, nonneg_rows, soc_sizes = key
    pattern = np.frombuffer(pattern_bytes, dtype=bool).reshape(shape)
    m, v = shape
    local_rows, local_cols = np.nonzero(pattern)
    block = np.arange(n_blocks)[:, None]
    rows = (block * m + local_rows).ravel()
    cols = (block * v + local_cols).ravel()
    order = sparse.csc_matrix((np.arange(1, rows.size + 1, dtype=np.float64), (rows, cols)),
                              shape=(n_blocks * m, n_blocks * v))
    cones: list[Any] = []   # clarabel's cone objects
    for _ in range(n_blocks):
        if zero_rows:
            cones.append(clarabel.ZeroConeT(zero_rows))
        if nonneg_rows:
            cones.append(clarabel.NonnegativeConeT(nonneg_rows))
        cones.extend(clarabel.SecondOrderConeT(size) for size in soc_sizes)
    no_quadratic_cost = sparse.csc_matrix((n_blocks * v, n_blocks * v))
    return (order.indices, order.indptr, order.data.astype(np.int64) - 1,
            (n_blocks * m, n_blocks * v), cones, no_quadratic_cost)


def settings(tol: float | None) -> clarabel.DefaultSettings:
    """Clarabel settings: the defaults, or gap and feasibility tolerances ``tol``."""
    result = clarabel.DefaultSettings()
    result.verbose = False
    result.max_iter = MAX_ITERATIONS
    # Iterative refinement of each KKT solve costs a good part of the time of these
    # solves (docs/performance.md#minimum-friction), and every answer is checked in
    # numpy anyway (as in the exact test).
    result.iterative_refinement_enable = False
    if tol is not None:
        result.tol_gap_abs = result.tol_gap_rel = tol
        result.tol_feas = tol
    return result


def solve_stacked(shape: BlockShape, a_values: np.ndarray, b: np.ndarray, q: np.ndarray,
                  tol: float | None = None) -> StackedSolution:
    """Solve N blocks of the same shape together.

    Parameters
    ----------
    shape : BlockShape
    a_values : ndarray, shape (N, m, v)
        Each block's constraint matrix (only entries inside ``shape.pattern`` are used).
    b : ndarray, shape (N, m)
    q : ndarray, shape (N, v)
    tol : float, optional
        Clarabel's gap and feasibility tolerances; its defaults (1e-8) if None.

    Returns
    -------
    StackedSolution
    """
    n_blocks, m, v = a_values.shape
    indices, indptr, order, full_shape, cones, p = _stacked_structure(n_blocks, shape.key())
    values = a_values[:, shape.pattern].ravel()
    a = sparse.csc_matrix((values[order], indices, indptr), shape=full_shape)
    solver = clarabel.DefaultSolver(p, q.ravel(), a, b.ravel(), cones, settings(tol))
    solution = solver.solve()
    return StackedSolution(np.asarray(solution.x).reshape(n_blocks, v),
                           np.asarray(solution.z).reshape(n_blocks, m),
                           solution.status in ACCEPTED)


def tangent_bases(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents (..., 3) orthogonal to each unit normal (..., 3) and each other.

    The branch-free orthonormal basis of Duff et al., "Building an Orthonormal Basis,
    Revisited" (JCGT 2017): elementwise only, well-conditioned for every unit normal.
    """
    x, y, z = normals[..., 0], normals[..., 1], normals[..., 2]
    sign = np.where(z >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + z)
    b = x * y * a
    first = np.stack((1.0 + sign * x * x * a, sign * b, -sign * x), axis=-1)
    second = np.stack((b, sign + y * y * a, -y), axis=-1)
    return first, second


def split_normal(vectors: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normal components (..., ) and tangential lengths (...) of vectors (..., 3)."""
    normal_part = (vectors * normals).sum(axis=-1)
    tangential = vectors - normal_part[..., None] * normals
    return normal_part, np.linalg.norm(tangential, axis=-1)
