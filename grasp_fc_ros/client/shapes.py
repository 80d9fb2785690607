"""Shape checks of the client's arrays, before anything is registered or sent.

A mis-shaped input raises ValueError naming the arrays and their shapes ("positions has
shape (3, 4, 3) but normals (3, 5, 3)"): unchecked, it stopped a ``zip`` short, failed
a numpy broadcast, or went out as a batch the node refused whole with a message about
the wire format. Only shapes are checked here; values (a zero normal, a negative
friction coefficient) are the node's to judge, grasp by grasp, in its verdicts.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike


def one_grasp(positions: ArrayLike, normals: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """``positions`` and ``normals`` of one grasp, (n, 3) float64 each.

    Raises
    ------
    ValueError
        If they are not both (n, 3), naming their shapes.
    """
    p, n = _floats(positions, "positions"), _floats(normals, "normals")
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"positions has shape {p.shape}, but one grasp is (n, 3): n "
                         "contacts, x y z each")
    _same_shape(p, n)
    return p, n


def grasp_batch(positions: ArrayLike, normals: ArrayLike, counts: ArrayLike | None = None,
                stacked: bool = True) -> tuple[np.ndarray, np.ndarray, int]:
    """``positions`` and ``normals`` of a batch as float64 arrays, and its number of
    grasps: (N, n, 3) each, or (where the method takes ``counts``: ``stacked``) stacked
    (K, 3) with ``counts`` (N,) contacts per grasp summing to K.

    Raises
    ------
    ValueError
        If the shapes do not describe such a batch, naming them.
    """
    p, n = _floats(positions, "positions"), _floats(normals, "normals")
    if counts is None:
        if p.ndim != 3 or p.shape[2] != 3:
            hint = " (or stacked (K, 3) with counts)" if stacked and p.ndim == 2 else ""
            raise ValueError(f"positions has shape {p.shape}, but a batch is (N, n, 3): N "
                             f"grasps of n contacts{hint}; positions[None] is a batch of "
                             "one grasp")
        _same_shape(p, n)
        return p, n, p.shape[0]
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"positions has shape {p.shape}, but with counts the contacts are "
                         "stacked (K, 3)")
    _same_shape(p, n)
    c = np.asarray(counts)
    if c.ndim != 1 or not (np.issubdtype(c.dtype, np.integer) or c.size == 0):
        raise ValueError(f"counts must be (N,) integers (contacts per grasp), got shape "
                         f"{c.shape} of {c.dtype}")
    if c.size and c.min() < 0:
        raise ValueError(f"counts must not be negative, got {int(c.min())} for grasp "
                         f"{int(np.argmin(c))}")
    if int(c.sum()) != p.shape[0]:
        raise ValueError(f"counts sum to {int(c.sum())} contacts, but positions has "
                         f"{p.shape[0]} (shape {p.shape})")
    return p, n, c.size


def per_grasp(values: ArrayLike | None, name: str, n_grasps: int) -> None:
    """Check that ``values`` (e.g. ``ids``) is None or has one value per grasp."""
    if values is None:
        return
    shape = np.shape(values)
    if len(shape) != 1 or shape[0] != n_grasps:
        raise ValueError(f"{name} has shape {shape}, but there are {n_grasps} grasps: give "
                         f"one value per grasp ({n_grasps},), or none")


def per_contact(values: ArrayLike | None, name: str, positions: np.ndarray,
                flat: bool = False) -> None:
    """Check that ``values`` (``mu``, ``torsional_friction``) is None, or broadcasts to
    the contacts of ``positions`` ((n, 3), (N, n, 3) or stacked (K, 3)): one value, one
    per contact, or (N, 1) one per grasp; with ``flat``, also (K,) contact after contact
    (a batch message's layout) or empty (the node's default)."""
    if values is None or (flat and np.size(values) == 0):
        return
    shape, contacts = np.shape(values), positions.shape[:-1]
    if shape == () or shape == contacts or (flat and shape == (int(np.prod(contacts)),)):
        return
    if len(shape) <= len(contacts):
        try:
            if np.broadcast_shapes(shape, contacts) == contacts:
                return
        except ValueError:
            pass
    per_grasp_hint = f", one per grasp {contacts[:1] + (1,)}" if len(contacts) == 2 else ""
    raise ValueError(f"{name} has shape {shape}, but positions {positions.shape} have "
                     f"{contacts} contacts: give one value, one per contact "
                     f"{contacts}{per_grasp_hint}, or None")


def wrench(values: ArrayLike) -> np.ndarray:
    """A wrench (force, torque) as (6,) float64."""
    w = _floats(values, "wrench")
    if w.size != 6:
        raise ValueError(f"wrench has shape {w.shape}, but a wrench is (6,): force (N) "
                         "then torque (N m)")
    return w.reshape(6)


def _same_shape(positions: np.ndarray, normals: np.ndarray) -> None:
    if normals.shape != positions.shape:
        raise ValueError(f"positions has shape {positions.shape} but normals "
                         f"{normals.shape}: give one normal per contact")


def _floats(values: ArrayLike, name: str) -> np.ndarray:
    """``values`` as a float64 array (no copy where it is one), or ValueError naming it."""
    try:
        return np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be an array of numbers: {error}") from None
