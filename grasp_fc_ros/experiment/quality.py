"""The experiment's grasp-quality part: mu* labels per object, soft against hard fingers.

GraspNet-style datasets label a grasp with the least friction that holds it, scanned on a
grid of mu values; here it is the certified minimum friction coefficient mu*
(:func:`grasp_fc_ros.core.quality.minimum_friction.minimum_friction`). The soft-finger sweep counts
force-closure grasps among the same random grasps with hard contacts (gamma = 0) and with
soft ones, gamma growing as a fraction of the object's size.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from grasp_fc_ros.objects import ContactSurface, sample_grasps

# Soft fingertips are rubber pads: their Coulomb friction is high. At the paper's
# mu = tan 10 deg random 2-finger grasps are almost never force closure, soft or hard.
SOFT_SWEEP_MU = 0.5
SOFT_SWEEP_FINGERS = (2, 3, 4)
# Torsional friction gamma as a fraction of the object's size (bounding-box diagonal):
# a fingertip's contact patch is a few percent of a hand-sized object.
SOFT_GAMMA_FRACTIONS = (0.0, 0.002, 0.005, 0.01, 0.02, 0.05)
# Fingers of the mu* labels: the paper's grasp size.
LABEL_FINGERS = 6


@dataclass(frozen=True)
class FrictionLabels:
    """mu* of random grasps on one object.

    Attributes
    ----------
    name : str
    n_fingers : int
    mu_star : numpy.ndarray, shape (N,)
        Minimum friction coefficient per grasp (0, finite, inf, or NaN if not certified).
    seconds : float
        Wall time of the batched ``minimum_friction`` call.
    """

    name: str
    n_fingers: int
    mu_star: np.ndarray
    seconds: float

    def share_at_most(self, mu: float) -> float:
        """Share of the grasps that are force closure at friction ``mu``."""
        return float(np.mean(self.mu_star < mu))


@dataclass(frozen=True)
class SoftRow:
    """Force-closure count of one object's random grasps at one torsional friction."""

    name: str
    n_fingers: int
    gamma_fraction: float
    gamma: float
    grasps: int
    force_closure: int

    @property
    def share(self) -> float:
        return self.force_closure / self.grasps


def object_size(surface: ContactSurface) -> float:
    """Diagonal of the surface's bounding box (the positions' unit)."""
    return float(np.linalg.norm(np.ptp(surface.points, axis=0)))


def friction_labels(surfaces: Iterable[ContactSurface], n_grasps: int, rng: np.random.Generator,
                    n_fingers: int = LABEL_FINGERS) -> list[FrictionLabels]:
    """mu* of ``n_grasps`` random grasps per surface, equal friction at every contact."""
    from grasp_fc_ros.core.quality.minimum_friction import minimum_friction

    labels = []
    for surface in surfaces:
        positions, normals = sample_grasps(surface, n_grasps, n_fingers, rng)
        start = time.perf_counter()
        mu_star = minimum_friction(positions, normals)
        labels.append(FrictionLabels(surface.name, n_fingers, np.atleast_1d(mu_star),
                                     time.perf_counter() - start))
    return labels


def soft_sweep(surfaces: Iterable[ContactSurface], n_grasps: int, rng: np.random.Generator,
               mu: float = SOFT_SWEEP_MU, finger_counts: Iterable[int] = SOFT_SWEEP_FINGERS,
               gamma_fractions: Iterable[float] = SOFT_GAMMA_FRACTIONS) -> list[SoftRow]:
    """Force-closure counts of the same random grasps as the torsional friction grows."""
    from grasp_fc_ros.core import check_force_closure

    rows = []
    for surface in surfaces:
        size = object_size(surface)
        for n_fingers in finger_counts:
            positions, normals = sample_grasps(surface, n_grasps, n_fingers, rng)
            for fraction in gamma_fractions:
                gamma = fraction * size
                result = check_force_closure(positions, normals, mu,
                                             torsional_friction=gamma)
                rows.append(SoftRow(surface.name, n_fingers, fraction, gamma, n_grasps,
                                    int(np.count_nonzero(result.force_closure))))
    return rows
