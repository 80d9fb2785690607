"""Certified robustness radii of force closure: how far normals may tilt, contacts move
and friction drop, each alone, before a grasp can lose force closure.

* ``normal_angle``: the largest delta at which the grasp with every cone shrunk to
  half-angle arctan(mu_i) - delta at its own normal is force closure (tilt lemma,
  :mod:`.shrink`; cones shrunk away left out), bracketed by exact tests; the radius is
  the lower end, a shrink tested force closure.
* ``friction_drop``: likewise with every mu_i lowered by d.
* ``position_radius``: the torque inradius rho (:mod:`.position_radius`), its certified
  lower bound.

What they certify: force closure in exact arithmetic (an equilibrium force strictly
inside every cone) of every perturbed grasp inside the radius, each radius derived from
grasps the exact test certified force closure (a verified internal force at least
MARGIN_TOL deep). Radii are 0 where the nominal grasp is not force closure by
:func:`.pipeline.check_force_closure` (marginal grasps included). docs/robustness.md
has the proofs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ..exact.exact_test import solve_exact
from ..model.grasp_input import GraspBatch, prepare_grasps
from .position_radius import torque_inradius
from .shrink import dropped_friction, largest_closed_shrink, tilted_friction, with_friction


@dataclass(frozen=True)
class RobustnessRadii:
    """Certified robustness radii: 0-d arrays for one grasp, (N,) for a batch.

    Attributes
    ----------
    normal_angle : ndarray of float
        Radians: force closure for every choice of normals, each within this angle of
        its own (positions and friction as given).
    position_radius : ndarray of float
        The positions' unit: force closure when every contact moves anywhere within a
        ball of this radius (normals and friction as given).
    friction_drop : ndarray of float
        Force closure when every contact's friction coefficient drops by up to this
        much (below the largest mu_i; a contact whose friction would reach 0 is left
        out of the proof, not trusted as frictionless).
    force_closure : ndarray of bool
        The nominal verdict of the exact test; the radii are 0 where it is False.
    """

    normal_angle: np.ndarray
    position_radius: np.ndarray
    friction_drop: np.ndarray
    force_closure: np.ndarray


def robustness(positions: npt.ArrayLike, normals: npt.ArrayLike, mu: npt.ArrayLike, *,
               torsional_friction: npt.ArrayLike | None = 0.0) -> RobustnessRadii:
    """Certified robustness radii of one grasp or a batch (module docstring).

    Parameters
    ----------
    positions : array_like, shape (n, 3) or (N, n, 3)
        Contact positions (any length unit).
    normals : array_like, same shape as ``positions``
        Inward contact normals, any non-zero length.
    mu : float or array_like broadcastable to (N, n)
        Friction coefficients, > 0: one for all, one per grasp ((N, 1)) or per contact.
    torsional_friction : float or array_like, optional
        Must be 0 (hard contacts): soft fingers are refused (ValueError), because a
        tilted normal turns the torsional moment's axis with it, which the tilt lemma
        does not cover (docs/robustness.md#limits).

    Returns
    -------
    RobustnessRadii

    Raises
    ------
    ValueError
        On bad input, naming the grasp and contact (or the argument) and the value.
    """
    grasps = hard_grasps(positions, normals, mu, torsional_friction)
    closed = solve_exact(grasps, "bound").force_closure
    angle, _ = largest_closed_shrink(grasps, closed, tilted_friction,
                                     np.arctan(grasps.mu).max(axis=1))
    drop, _ = largest_closed_shrink(grasps, closed, dropped_friction, grasps.mu.max(axis=1))
    radius = np.zeros(closed.shape)
    index = np.flatnonzero(closed)
    if index.size:
        radius[index] = torque_inradius(with_friction(grasps, index, grasps.mu[index])).lower
    return RobustnessRadii(normal_angle=grasps.unbatch(angle),
                           position_radius=grasps.unbatch(radius),
                           friction_drop=grasps.unbatch(drop),
                           force_closure=grasps.unbatch(closed))


def hard_grasps(positions: npt.ArrayLike, normals: npt.ArrayLike, mu: npt.ArrayLike,
                torsional_friction: npt.ArrayLike | None = 0.0) -> GraspBatch:
    """The validated batch; ValueError for soft fingers (torsional friction > 0)."""
    grasps = prepare_grasps(positions, normals, mu, torsional_friction)
    if grasps.torsional is not None:
        raise ValueError(
            "robustness radii are for hard contacts: got torsional_friction > 0 (a normal "
            "that tilts turns the torsional moment's axis with it, which the tilt lemma "
            "does not cover; docs/robustness.md#limits)")
    return grasps

