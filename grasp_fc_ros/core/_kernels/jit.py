"""The JIT decorator of the core's kernels, the array form they take, and row access."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TypeAlias, TypeVar

import numba
import numpy as np

if TYPE_CHECKING:
    from numba.core.dispatcher import Dispatcher

Function = TypeVar("Function", bound=Callable[..., Any])

#: A 3-vector (x0, x1, x2) passed by value between kernels.
Vector3: TypeAlias = tuple[float, float, float]


def jit(function: Function) -> Dispatcher[Function]:
    """``numba.njit(cache=True, error_model="numpy")``; without a usable cache
    directory, uncached.

    The compiled function takes the arguments of ``function`` and returns what it does
    (the annotations serve mypy; numba compiles one specialisation per argument type).
    ``error_model="numpy"``: a division by zero gives inf or NaN, as in numpy, instead
    of raising.

    No fastmath flag, not even ``contract`` (fused multiply-adds): without one, LLVM must
    round every operation as written, so every compiled copy of a kernel gives the same
    bits. With ``contract`` it may fuse or not in each copy, and does so differently
    where a kernel is inlined into another caller or linked from the cache (numba links
    a callee's code into each caller and keeps one definition of it per process): the
    one-grasp and batch paths of the exact stage then returned margins one ulp apart,
    and the same call different margins in a process that compiled it and one that
    loaded it from the cache (docs/performance.md#exact-stage).

    numba stores the machine code next to the defining file (or in the user's cache
    directory when the install is read-only) and keys it on that function's bytecode
    and the CPU alone: a kernel that calls kernels of other files, or whose options
    here change, keeps its cached code until its own file changes or the
    ``__pycache__/*.nbi`` files are removed.
    """
    try:
        return numba.njit(cache=True, error_model="numpy")(function)
    except RuntimeError:  # no writable cache location at all: compile per process
        return numba.njit(cache=False, error_model="numpy")(function)


def kernel_array(values: Any) -> np.ndarray:
    """``values`` as a C-contiguous, writable float64 array, to pass to a compiled kernel.

    Parameters
    ----------
    values : array_like, any shape

    Returns
    -------
    ndarray of float64, the same shape
        ``values`` itself where it already has that form, else a copy.

    numba compiles a kernel once per argument type, and a read-only array (from
    ``np.frombuffer``, ``np.broadcast_to`` or an unpickled buffer) is a type of its own:
    passed as it is, it made the node's first queries compile the exact stage again
    after ``warm_up`` (a full compile in a fresh install, a cache load in every later
    process). Only such arrays are copied.
    """
    return np.require(values, np.float64, ("C", "W"))


@jit
def row(array: np.ndarray, i: int) -> Vector3:
    """Row ``i`` of an (n, 3) array as a tuple, without the array view ``array[i]``
    (a view costs an atomic reference count each way, which numba cannot always remove
    inside a kernel's loops).

    Parameters
    ----------
    array : ndarray, shape (n, 3)
    i : int

    Returns
    -------
    Vector3
    """
    return array[i, 0], array[i, 1], array[i, 2]
