"""Input handling: shapes, broadcasting and per-grasp validation.

A grasp is n contacts, each a position (3,), an inward normal (3,) and a friction
coefficient mu. Public functions accept one grasp (arrays (n, 3)) or a batch (arrays
(N, n, 3)); internally everything is a batch. Accepted values, all real and finite:

* positions with every |coordinate| <= ``MAX_ABS_COORDINATE`` (about 1e301);
* normals of any length whose largest |component| is at least ``MIN_NORMAL_COMPONENT``
  (the smallest normal float, about 2.2e-308): 1e-300 and 1e300 are both fine; only
  the zero vector and subnormal-only vectors are refused;
* 0 < mu <= ``MAX_FRICTION_COEFFICIENT`` (1e3);
* torsional friction 0 <= gamma <= ``MAX_ABS_COORDINATE`` (a length, optional,
  broadcastable like mu; 0 is a hard contact, see :mod:`.contact_model`).

Results of one grasp are those of a batch of one, unbatched (:meth:`GraspBatch.unbatch`):
a per-grasp (N,) array becomes its element, a numpy scalar. Signatures annotate the
batch form (``np.ndarray``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from ..tolerances import MAX_ABS_COORDINATE, MAX_FRICTION_COEFFICIENT, MIN_NORMAL_COMPONENT
from .contact_model import torsional_all_valid, torsional_checks, torsional_or_none

MIN_CONTACTS = 2

#: From this many vectors on, :func:`unit_vectors` and :func:`_largest_component` work
#: component by component into preallocated arrays (fewer and smaller temporaries, no
#: inner loops over three elements); below it their broadcast forms, which make fewer
#: numpy calls, are the faster. The same results either way (tuned:
#: docs/performance.md#exact-stage).
COMPONENTWISE_MIN_VECTORS = 512


@dataclass(frozen=True)
class GraspBatch:
    """Validated, normalised input of a batch of N grasps with n contacts each.

    Attributes
    ----------
    positions : ndarray, shape (N, n, 3)
        Contact positions, in the caller's length unit.
    normals : ndarray, shape (N, n, 3)
        Unit inward normals.
    mu : ndarray, shape (N, n)
        Friction coefficients, all finite and > 0.
    single : bool
        True if the caller passed one grasp; results are then returned 0-d.
    torsional : ndarray, shape (N, n), or None
        Torsional friction coefficients gamma (>= 0, positions' unit) when some contact
        is soft; None when every contact is hard (the hard path).
    """

    positions: np.ndarray
    normals: np.ndarray
    mu: np.ndarray
    single: bool
    torsional: np.ndarray | None = None

    def unbatch(self, values: np.ndarray) -> Any:
        """Per-grasp ``values`` (N, ...) as the caller expects: ``values[0]`` for one
        grasp (a numpy scalar where ``values`` is (N,), an array otherwise), else
        ``values``."""
        return values[0] if self.single else values


@dataclass(frozen=True)
class GraspValidation:
    """Per-grasp validity of a batch.

    Attributes
    ----------
    valid : ndarray of bool, shape (N,)
        True where the grasp can be tested.
    reasons : list of str, length N
        Empty string where valid, otherwise what is wrong, naming grasp and contact.
    """

    valid: np.ndarray
    reasons: list[str]


def _as_batch_arrays(positions: npt.ArrayLike, normals: npt.ArrayLike,
                     mu: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """Coerce inputs to float arrays of shape (N, n, 3), (N, n, 3), (N, n).

    Raises
    ------
    ValueError
        If the shapes do not describe one grasp or a batch of grasps, or an argument
        is not real numbers (complex, strings), naming the argument.
    """
    p = _real_array(positions, "positions")
    nrm = _real_array(normals, "normals")
    if p.ndim not in (2, 3) or p.shape[-1] != 3:
        raise ValueError(
            f"positions must have shape (n, 3) or (N, n, 3), got {p.shape}")
    if nrm.shape != p.shape:
        raise ValueError(
            f"normals must have the same shape as positions {p.shape}, got {nrm.shape}")
    single = p.ndim == 2
    if single:
        p, nrm = p[None], nrm[None]
    n_grasps, n_contacts = p.shape[:2]
    return p, nrm, _per_contact(mu, "mu", single, (n_grasps, n_contacts)), single


def _per_contact(values: npt.ArrayLike, name: str, single: bool,
                 shape: tuple[int, int]) -> np.ndarray:
    """A per-contact coefficient (mu, gamma) broadcast to ``shape`` (N, n).

    Raises
    ------
    ValueError
        If it is not real numbers or does not broadcast, naming ``name``.
    """
    m = _real_array(values, name)
    if single and m.ndim >= 1:
        m = m[None]
    try:
        return np.broadcast_to(m, shape)
    except ValueError:
        hint = f" (for one {name} per grasp pass an (N, 1) array)" if m.ndim == 1 else ""
        raise ValueError(
            f"{name} of shape {np.shape(values)} does not broadcast to (grasps, contacts) = "
            f"{shape}{hint}") from None


def _real_array(values: npt.ArrayLike, name: str) -> np.ndarray:
    """``values`` as a float64 array; refuses complex and non-numeric input by ``name``.

    A plain float conversion would drop imaginary parts silently.
    """
    array = np.asarray(values)
    if np.iscomplexobj(array):
        raise ValueError(f"{name} must be real numbers, got complex values ({array.dtype})")
    try:
        return np.asarray(array, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be real numbers: {error}") from None


def _largest_component(vectors: np.ndarray) -> np.ndarray:
    """max |component| of vectors (..., 3): shape (...); NaN where a component is NaN.

    Two elementwise maxima (exact, and propagating NaN as ``max`` does): numpy's reduction
    over a last axis of length 3 is several times slower, in every validation and
    normalisation of the normals (tuned: docs/performance.md#one-grasp). From
    ``COMPONENTWISE_MIN_VECTORS`` vectors on, into two arrays of shape (...), without a
    temporary |vectors|.
    """
    if vectors.size < 3 * COMPONENTWISE_MIN_VECTORS:
        whole = np.abs(vectors)
        return np.maximum(np.maximum(whole[..., 0], whole[..., 1]), whole[..., 2])
    size = np.abs(vectors[..., 0], out=np.empty(vectors.shape[:-1]))
    other = np.abs(vectors[..., 1], out=np.empty(vectors.shape[:-1]))
    np.maximum(size, other, out=size)
    np.abs(vectors[..., 2], out=other)
    return np.maximum(size, other, out=size)


def unit_vectors(vectors: np.ndarray, largest: np.ndarray | None = None) -> np.ndarray:
    """Directions of vectors (..., 3) whose largest |component| is a normal float.

    Dividing by the largest |component| first brings every vector to a length in
    [1, sqrt(3)], so the norm neither overflows (lengths >= ~1e154) nor underflows
    (lengths <= ~1e-154); the result is a unit vector to a few ulps. ``largest``: that
    component, shape (...), where the caller has it already.
    """
    # From COMPONENTWISE_MIN_VECTORS vectors on, component by component into one output
    # array: a division of (..., 3) by a
    # broadcast (..., 1) runs numpy's inner loop over three elements at a time, the
    # reduction over the last axis likewise, and each fresh temporary of a batch costs
    # page faults; this made the normalisation several times slower on a batch (tuned:
    # docs/performance.md#exact-stage). The same divisions, and the sum in the order of
    # numpy's reduction ((x0^2 + x1^2) + x2^2): results bit for bit those of
    # ``scaled / |scaled|`` with ``scaled = vectors / largest[..., None]``.
    if largest is None:
        largest = _largest_component(vectors)
    if vectors.size < 3 * COMPONENTWISE_MIN_VECTORS:
        scaled = vectors / largest[..., None]
        return scaled / np.sqrt((scaled * scaled).sum(axis=-1))[..., None]
    out = np.empty(vectors.shape)
    for k in range(3):
        np.divide(vectors[..., k], largest, out=out[..., k])
    length = np.multiply(out[..., 0], out[..., 0], out=np.empty(vectors.shape[:-1]))
    square = np.multiply(out[..., 1], out[..., 1], out=np.empty(vectors.shape[:-1]))
    length += square
    np.multiply(out[..., 2], out[..., 2], out=square)
    length += square
    np.sqrt(length, out=length)
    for k in range(3):
        np.divide(out[..., k], length, out=out[..., k])
    return out


def _first_per_grasp(bad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For a mask (N, n): which grasps have a True, and the first such contact."""
    return np.any(bad, axis=1), bad.argmax(axis=1)


def validate_grasps(positions: npt.ArrayLike, normals: npt.ArrayLike, mu: npt.ArrayLike,
                    torsional_friction: npt.ArrayLike = 0.0) -> GraspValidation:
    """Check every grasp of a batch and say what is wrong with the bad ones.

    Parameters
    ----------
    positions, normals : array_like, shape (N, n, 3) or (n, 3)
        Contact positions and inward normals.
    mu : array_like
        Friction coefficients, broadcastable to (N, n).
    torsional_friction : array_like
        Torsional friction coefficients gamma (a length), broadcastable to (N, n).

    Returns
    -------
    GraspValidation
        ``valid`` (N,) and ``reasons``; a single grasp is reported as a batch of one.

    Raises
    ------
    ValueError
        Only if the shapes themselves are wrong or an argument is not real numbers;
        bad values are reported per grasp.
    """
    p, nrm, m, single = _as_batch_arrays(positions, normals, mu)
    gamma = _torsional(torsional_friction, single, m.shape)
    if _all_valid(p, nrm, m, _largest_component(nrm)) and (gamma is None
                                                           or torsional_all_valid(gamma)):
        # the common case, without the per-check bookkeeping
        return GraspValidation(np.ones(p.shape[0], dtype=bool), [""] * p.shape[0])
    return _validate(p, nrm, m, gamma)


def _validate(p: np.ndarray, nrm: np.ndarray, m: np.ndarray,
              torsional: np.ndarray | None = None) -> GraspValidation:
    """:func:`validate_grasps` on arrays already shaped (N, n, 3), (N, n, 3), (N, n),
    and gamma (N, n) or None (all hard)."""
    n_grasps, n_contacts = p.shape[:2]
    reasons = [""] * n_grasps
    if n_contacts < MIN_CONTACTS:
        reasons = [f"grasp {g}: has {n_contacts} contacts, needs at least {MIN_CONTACTS}"
                   for g in range(n_grasps)]
        return GraspValidation(np.zeros(n_grasps, dtype=bool), reasons)

    with np.errstate(invalid="ignore"):
        normal_size = _largest_component(nrm)
        checks = (
            (~np.isfinite(p).all(axis=2), "position is not finite", p),
            (~(_largest_component(p) <= MAX_ABS_COORDINATE),
             f"position has a coordinate beyond +-{MAX_ABS_COORDINATE:.3g} (use a larger "
             "length unit)", p),
            (~np.isfinite(nrm).all(axis=2), "normal is not finite", nrm),
            (normal_size == 0, "normal has zero length", nrm),
            (normal_size < MIN_NORMAL_COMPONENT,
             f"normal is too short to give a direction (every component below "
             f"{MIN_NORMAL_COMPONENT:.3g}; scale it up)", nrm),
            (~np.isfinite(m), "friction coefficient is not finite", m),
            (~(m > 0), "friction coefficient must be > 0", m),
            (m > MAX_FRICTION_COEFFICIENT,
             f"friction coefficient exceeds {MAX_FRICTION_COEFFICIENT:g}", m),
        ) + (() if torsional is None else torsional_checks(torsional))
    valid = np.ones(n_grasps, dtype=bool)
    # Report the first problem of each grasp: a grasp already found bad is skipped.
    for bad, what, values in checks:
        has_bad, first = _first_per_grasp(bad)
        for g in np.flatnonzero(has_bad & valid):
            reasons[g] = (f"grasp {g}, contact {first[g]}: {what}, got "
                          f"{show_value(values[g, first[g]])}")
        valid &= ~has_bad
    return GraspValidation(valid, reasons)


def show_value(value: np.ndarray | float) -> str:
    """A contact's offending value for a message: ``-0.5`` or ``(0, 0, 0)`` (6 digits)."""
    if np.ndim(value) == 0:
        return f"{float(value):.6g}"
    return "(" + ", ".join(f"{float(v):.6g}" for v in np.ravel(value)) + ")"


def _all_valid(p: np.ndarray, nrm: np.ndarray, m: np.ndarray, normal_size: np.ndarray) -> bool:
    """True iff :func:`_validate` finds no problem, in a few whole-array reductions
    (``normal_size``: :func:`_largest_component` of ``nrm``).

    The common case of good input then skips the per-check, per-grasp bookkeeping,
    which dominates the cost of a call with one grasp. NaN fails every comparison and
    inf every upper bound, so each check of :func:`_validate` is covered.
    """
    with np.errstate(invalid="ignore"):
        return bool(p.shape[1] >= MIN_CONTACTS
                    # |p| <= MAX everywhere, without a temporary of the batch's size
                    # (NaN propagates through max and min and fails the comparison)
                    and (p.size == 0 or (p.max() <= MAX_ABS_COORDINATE
                                         and p.min() >= -MAX_ABS_COORDINATE))
                    and np.isfinite(nrm).all()
                    and (normal_size >= MIN_NORMAL_COMPONENT).all()
                    and ((m > 0) & (m <= MAX_FRICTION_COEFFICIENT)).all())


def _torsional(torsional_friction: npt.ArrayLike | None, single: bool,
               shape: tuple[int, int]) -> np.ndarray | None:
    """gamma broadcast to ``shape`` (N, n), unvalidated; None for None or a plain zero:
    every contact hard, known without building an array (the default of every entry
    point, so a one-grasp call pays nothing for soft contacts)."""
    if torsional_friction is None or (
            isinstance(torsional_friction, (int, float)) and torsional_friction == 0):
        return None
    return _per_contact(torsional_friction, "torsional_friction", single, shape)


def prepare_grasps(positions: npt.ArrayLike, normals: npt.ArrayLike, mu: npt.ArrayLike,
                   torsional_friction: npt.ArrayLike | None = None) -> GraspBatch:
    """Validate input and return it as a normalised batch.

    ``torsional_friction`` (gamma, broadcastable to (N, n)) is optional; None or all
    zeros give a hard batch (``torsional`` None).

    Raises
    ------
    ValueError
        On wrong shapes or any bad value, naming the first bad grasps and contacts.
    """
    p, nrm, m, single = _as_batch_arrays(positions, normals, mu)
    gamma = _torsional(torsional_friction, single, m.shape)
    normal_size = _largest_component(nrm)
    good = _all_valid(p, nrm, m, normal_size) and (gamma is None
                                                   or torsional_all_valid(gamma))
    validation = None if good else _validate(p, nrm, m, gamma)
    if validation is not None and not validation.valid.all():
        bad = [r for r in validation.reasons if r]
        more = f" (and {len(bad) - 3} more)" if len(bad) > 3 else ""
        raise ValueError("invalid grasp input: " + "; ".join(bad[:3]) + more)
    return GraspBatch(p, unit_vectors(nrm, normal_size), np.ascontiguousarray(m), single,
                      None if gamma is None else torsional_or_none(gamma))
