"""Will a grasp hold if its contacts are off? HOLDS from a sound bound, BREAKS with a
witness, UNDECIDED where neither was found.

Errors: every contact may move by up to r (anywhere), every normal tilt by up to delta
and every friction coefficient drop (or rise) by up to dmu, independently.

* HOLDS: every cone shrunk to half-angle alpha_i' = arctan(mu_i - dmu) - delta at its own
  normal (contacts with alpha_i' <= 0 left out) gives a force-closure grasp (exact
  test), and r is below its torque inradius rho' (certified lower bound) where r > 0.
  Every perturbed grasp's cones contain the shrunk ones at the moved contacts (tilt lemma, friction
  monotonicity), and the moved shrunk grasp is force closure (r < rho'): so is the
  perturbed one. ``bound`` says which was used: "shrunk_cones" (r = 0) or
  "shrunk_cones+position_radius".
* BREAKS: a perturbed grasp inside the errors that the exact test certifies not force
  closure, with its separating wrench (checked by :func:`.certificates.verify_batch`).
  Friction drops by the whole dmu; each normal tilts towards -v_i of a wrench that
  separates the shrunk grasp (moved by the search of :mod:`.witness` where r > 0).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ..exact.certificates import verify_batch
from ..model.grasp_input import GraspBatch
from .position_radius import torque_inradius
from .radii import hard_grasps
from .shrink import closed_under, tilted_friction, with_friction, without_vanished
from .witness import (
    breaking_moves,
    exact_verdicts,
    frictionless_wrench,
    tilt_towards,
    turned_axes_wrench,
    work_vectors,
)

#: The witness never shrinks a cone below this half-angle (radians) or drops a friction
#: coefficient below its tangent (or below mu_i if that is smaller): the exact test
#: needs mu > 0, and an error this close to the whole cone breaks a grasp anyway.
WITNESS_MIN_HALF_ANGLE = 1e-3

#: ``bound`` of a HOLDS answer.
SHRUNK_CONES = "shrunk_cones"
SHRUNK_CONES_AND_POSITION_RADIUS = "shrunk_cones+position_radius"


class Holds(enum.IntEnum):
    """The answer of :func:`holds_under` for one grasp."""

    HOLDS = 1      #: a sound bound proves force closure for every perturbation inside the errors
    BREAKS = 2     #: a witness perturbation inside the errors is certified NOT force closure
    UNDECIDED = 3  #: neither was found


@dataclass(frozen=True)
class HoldsUnder:
    """Answers of :func:`holds_under`: per grasp (N,) arrays (0-d / (n, 3) for one grasp).

    Attributes
    ----------
    status : ndarray of int8
        :class:`Holds` values.
    bound : ndarray of str
        The sound bound behind HOLDS ("shrunk_cones" or "shrunk_cones+position_radius"),
        '' elsewhere.
    witness_positions, witness_normals : ndarray, shape (N, n, 3)
        The breaking grasp where BREAKS (normals unit), NaN elsewhere.
    witness_mu : ndarray, shape (N, n)
        Its friction coefficients, NaN elsewhere.
    separating_wrench : ndarray, shape (N, 6)
        The exact test's certificate on the witness (unit wrench: force, torque about
        the caller's origin; no contact force does positive work on it within
        CERTIFICATE_TOL), NaN elsewhere.
    """

    status: np.ndarray
    bound: np.ndarray
    witness_positions: np.ndarray
    witness_normals: np.ndarray
    witness_mu: np.ndarray
    separating_wrench: np.ndarray


def holds_under(positions: npt.ArrayLike, normals: npt.ArrayLike, mu: npt.ArrayLike, *,
                position_error: npt.ArrayLike = 0.0, normal_error: npt.ArrayLike = 0.0,
                friction_error: npt.ArrayLike = 0.0) -> HoldsUnder:
    """Does force closure hold for every perturbation inside the errors (module docstring)?

    Parameters
    ----------
    positions : array_like, shape (n, 3) or (N, n, 3)
        Contact positions (any length unit).
    normals : array_like, same shape as ``positions``
        Inward contact normals, any non-zero length.
    mu : float or array_like broadcastable to (N, n)
        Friction coefficients, > 0.
    position_error : float or array_like of shape (N,)
        r >= 0, the positions' unit: how far each contact may be from where it is given.
    normal_error : float or array_like of shape (N,)
        delta in [0, pi] radians: how far each normal may be tilted.
    friction_error : float or array_like of shape (N,)
        dmu >= 0: how much each friction coefficient may be off.

    Returns
    -------
    HoldsUnder

    Raises
    ------
    ValueError
        On bad input, naming the grasp and contact (or the argument) and the value.
    """
    grasps = hard_grasps(positions, normals, mu)
    n_grasps = grasps.mu.shape[0]
    errors = _Errors(_error(position_error, "position_error", n_grasps, np.inf),
                     _error(normal_error, "normal_error", n_grasps, np.pi),
                     _error(friction_error, "friction_error", n_grasps, np.inf), grasps.mu)
    answers = _Answers.empty(grasps)
    # The witness's shrunk cones, with certificates: mostly the same as HOLDS's.
    closed, wrench = exact_verdicts(GraspBatch(grasps.positions, grasps.normals,
                                               errors.searched_mu, False, None))
    directions = _prove(grasps, errors, closed, answers)
    witness_mu = errors.witness_mu
    moves = _find_witnesses(grasps, errors, closed, directions, answers, wrench, witness_mu)
    candidates = np.flatnonzero(~np.isnan(wrench).any(axis=1) & (answers.status != Holds.HOLDS))
    if candidates.size:
        moved = grasps.positions[candidates] + moves[candidates]
        answers.check_witnesses(candidates, moved, tilt_towards(
            grasps.normals[candidates], work_vectors(moved, wrench[candidates]),
            np.broadcast_to(errors.tilt[candidates, None], moved.shape[:2])),
            witness_mu[candidates], wrench[candidates])
    return answers.result(grasps.single)


@dataclass(frozen=True)
class _Errors:
    """The errors (N,) and the cones they give (N, n).

    ``holds_mu``: the cones every perturbation contains, tan(arctan(mu - dmu) - delta)
    rounded down (:mod:`.shrink`), 0 where the half-angle is not positive (the contact
    is left out of the proof). ``witness_mu``: the witness's friction, mu - dmu, not below
    tan(WITNESS_MIN_HALF_ANGLE) (or mu where that is smaller). ``searched_mu``: the
    shrunk cones a separating wrench is searched for, half-angle arctan(mu_w) - delta
    (not below WITNESS_MIN_HALF_ANGLE or arctan(mu_w)): tilting by delta towards -v_i of
    a wrench that separates them separates mu_w's cones. Where no floor applies,
    searched_mu is holds_mu (one exact test serves both)."""

    radius: np.ndarray
    tilt: np.ndarray
    drop: np.ndarray
    mu: np.ndarray

    @property
    def holds_mu(self) -> np.ndarray:
        lowered = self.mu - self.drop[:, None]
        return np.where(lowered > 0.0, tilted_friction(lowered, self.tilt[:, None]), 0.0)

    @property
    def witness_mu(self) -> np.ndarray:
        floor = np.minimum(self.mu, np.tan(WITNESS_MIN_HALF_ANGLE))
        return np.maximum(self.mu - self.drop[:, None], floor)

    @property
    def searched_mu(self) -> np.ndarray:
        witness = self.witness_mu
        return np.maximum(tilted_friction(witness, self.tilt[:, None]),
                          np.minimum(witness, np.tan(WITNESS_MIN_HALF_ANGLE)))


def _prove(grasps: GraspBatch, errors: _Errors, closed: np.ndarray,
           answers: _Answers) -> np.ndarray:
    """HOLDS where the shrunk cones are force closure (``closed``: the verdicts on
    ``searched_mu``, used where it equals ``holds_mu``) and the position error is below
    their torque inradius. Returns the torque inradius searches' directions (N, 6), NaN
    where none ran (a first guess for the move search)."""
    holds_mu, searched_mu = errors.holds_mu, errors.searched_mu
    proved = np.where((holds_mu == searched_mu).all(axis=1), closed, False)
    other = np.flatnonzero(~(holds_mu == searched_mu).all(axis=1))
    if other.size:
        proved[other] = closed_under(grasps, other, holds_mu[other])
    answers.hold(np.flatnonzero(proved & (errors.radius == 0)), SHRUNK_CONES)
    moving = np.flatnonzero(proved & (errors.radius > 0))
    directions = np.full((grasps.mu.shape[0], 6), np.nan)
    if moving.size:
        inradius = torque_inradius(without_vanished(grasps, moving, holds_mu[moving])[0])
        answers.hold(moving[errors.radius[moving] < inradius.lower],
                     SHRUNK_CONES_AND_POSITION_RADIUS)
        directions[moving] = inradius.direction
    return directions


def _find_witnesses(grasps: GraspBatch, errors: _Errors, closed: np.ndarray,
                    directions: np.ndarray, answers: _Answers, wrench: np.ndarray,
                    witness_mu: np.ndarray) -> np.ndarray:
    """Separating wrenches for the grasps not proved to hold, into ``wrench`` (N, 6)
    (it holds the shrunk grasp's own where it has one): moves that break the shrunk
    grasp, tiny cones turned within the spare tilt, or nearly no friction (and
    ``witness_mu`` (N, n) lowered for those). Returns the moves (N, n, 3)."""
    moves = np.zeros(grasps.positions.shape)
    open_ = answers.status != Holds.HOLDS
    searched_mu = errors.searched_mu
    search = np.flatnonzero(np.isnan(wrench).any(axis=1) & closed & (errors.radius > 0)
                            & open_)
    if search.size:
        # The torque inradius search's direction is a good first guess where it ran.
        found, step, breaking = breaking_moves(
            with_friction(grasps, search, searched_mu[search]), errors.radius[search],
            np.nan_to_num(directions[search, 3:]))
        moves[search[found]], wrench[search[found]] = step[found], breaking[found]
    spare = errors.tilt[:, None] - (np.arctan(errors.witness_mu) - np.arctan(searched_mu))
    # (Such shrunk grasps are often marginal: tiny cones leave a margin below MARGIN_TOL.)
    turning = np.flatnonzero(np.isnan(wrench).any(axis=1) & open_ & (spare > 0).any(axis=1))
    if turning.size:
        wrench[turning] = turned_axes_wrench(
            with_friction(grasps, turning, searched_mu[turning]),
            np.maximum(spare[turning], 0.0))
    # Friction that may drop to nothing: a witness with nearly none.
    bare = np.flatnonzero(np.isnan(wrench).any(axis=1) & open_
                          & (grasps.mu <= errors.drop[:, None]).all(axis=1))
    if bare.size:
        wrench[bare], witness_mu[bare] = frictionless_wrench(
            with_friction(grasps, bare, grasps.mu[bare]), witness_mu[bare])
    return moves


def _error(value: npt.ArrayLike, name: str, n_grasps: int, largest: float) -> np.ndarray:
    """An error argument as (N,) floats in [0, largest]; ValueError naming the grasp."""
    array = np.asarray(value)
    if np.iscomplexobj(array) or not np.issubdtype(array.dtype, np.number):
        raise ValueError(f"{name} must be real numbers, got {array.dtype}")
    if array.shape not in ((), (n_grasps,)):
        raise ValueError(f"{name} must be a number or have shape ({n_grasps},), "
                         f"got {array.shape}")
    array = np.broadcast_to(array.astype(np.float64), (n_grasps,))
    bad = ~((array >= 0.0) & (array <= largest) & np.isfinite(array))
    if bad.any():
        g = int(np.flatnonzero(bad)[0])
        upper = "" if np.isinf(largest) else f" and <= {largest:.6g}"
        raise ValueError(f"{name} of grasp {g} must be finite, >= 0{upper}, got {array[g]!r}")
    return np.ascontiguousarray(array)


class _Answers:
    """The answers being filled in, per grasp."""

    def __init__(self, status: np.ndarray, bound: np.ndarray, positions: np.ndarray,
                 normals: np.ndarray, mu: np.ndarray, wrench: np.ndarray) -> None:
        self.status, self.bound = status, bound
        self.positions, self.normals, self.mu, self.wrench = positions, normals, mu, wrench

    @classmethod
    def empty(cls, grasps: GraspBatch) -> _Answers:
        n_grasps, n_contacts = grasps.mu.shape
        return cls(np.full(n_grasps, Holds.UNDECIDED, dtype=np.int8),
                   np.full(n_grasps, "", dtype=object),
                   np.full((n_grasps, n_contacts, 3), np.nan),
                   np.full((n_grasps, n_contacts, 3), np.nan),
                   np.full((n_grasps, n_contacts), np.nan), np.full((n_grasps, 6), np.nan))

    def hold(self, index: np.ndarray, bound: str) -> None:
        self.status[index] = Holds.HOLDS
        self.bound[index] = bound

    def check_witnesses(self, index: np.ndarray, positions: np.ndarray, normals: np.ndarray,
                        mu: np.ndarray, wrench: np.ndarray) -> None:
        """BREAKS where the exact test certifies the witness not force closure: its own
        separating wrench, or the searched one where it checks out on the witness."""
        closed, certificate = exact_verdicts(GraspBatch(positions, normals, mu, False, None))
        own = ~np.isnan(certificate).any(axis=1)
        _, searched_ok = verify_batch(positions, normals, mu, separating_wrench=wrench)
        certificate = np.where(own[:, None], certificate, wrench)
        breaks = ~closed & (own | searched_ok)
        chosen = index[breaks]
        self.status[chosen] = Holds.BREAKS
        self.positions[chosen], self.normals[chosen] = positions[breaks], normals[breaks]
        self.mu[chosen], self.wrench[chosen] = mu[breaks], certificate[breaks]

    def result(self, single: bool) -> HoldsUnder:
        fields = (self.status, self.bound.astype(str), self.positions, self.normals, self.mu,
                  self.wrench)
        return HoldsUnder(*(value[0] if single else value for value in fields))
