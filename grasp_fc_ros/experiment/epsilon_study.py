"""The experiment's epsilon part: the exact Ferrari-Canny epsilon against the pyramid Q1.

Dataset tools rank grasps by Q1 computed on friction pyramids (DexGraspBench q1.py,
BODex chq1.py): per contact ``edges`` forces of unit normal part on the cone's surface
(an inscribed pyramid), Qhull of their wrenches and the origin, least facet offset.
On the same random grasps of the experiment's objects this part measures, against
:func:`grasp_fc_ros.core.epsilon_quality` (certified to ``EXACT_RTOL``), how wrong that
is: the relative error over force-closure grasps, how often two grasps whose exact
order is certain come out in the opposite order, and how many force-closure grasps the
pyramid scores 0. Torques are about the object's centre (its frame's origin) divided by
each grasp's largest |p_i - c|, for both.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from grasp_fc_ros.objects import ContactSurface, sample_grasps

#: Pyramid edges compared: the coarsest in use and the dataset tools' default.
EDGE_COUNTS = (4, 8)
#: Accuracy of the exact epsilon: far below the pyramids' errors, so its midpoint
#: stands in for epsilon in the relative errors.
EXACT_RTOL = 1e-4


def pyramid_q1(positions: np.ndarray, normals: np.ndarray, mu: float, centre: np.ndarray,
               scale: float, edges: int = 8) -> float:
    """Q1 of one grasp as DexGraspBench q1.py / BODex chq1.py compute it.

    Parameters
    ----------
    positions, normals : ndarray, shape (n, 3)
        Contacts and unit inward normals.
    mu : float
    centre : ndarray, shape (3,)
        Centre of the torques.
    scale : float
        Torque scale L (torques are divided by it).
    edges : int
        Pyramid edges n + mu (cos a t1 + sin a t2), a = 2 pi k / edges.

    Returns
    -------
    float
        Least facet offset of conv(origin, edge wrenches); 0 if the origin is not
        strictly inside (or the wrenches span less than six dimensions).
    """
    angle = 2 * np.pi * np.arange(edges) / edges
    points = [np.zeros((1, 6))]
    for p, n in zip(positions, normals, strict=True):
        helper = np.eye(3)[np.abs(n).argmin()]
        t1 = np.cross(n, helper)
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(n, t1)
        forces = n + mu * (np.cos(angle)[:, None] * t1 + np.sin(angle)[:, None] * t2)
        points.append(np.concatenate([forces, np.cross((p - centre) / scale, forces)], axis=1))
    try:
        hull = ConvexHull(np.vstack(points))
    except QhullError:
        return 0.0
    return max(0.0, float(-hull.equations[:, -1].max()))


def pyramid_q1_batch(positions: np.ndarray, normals: np.ndarray, mu: float,
                     centre: np.ndarray, scales: np.ndarray, edges: int = 8) -> np.ndarray:
    """:func:`pyramid_q1` of each grasp (N,): one Qhull call per grasp, as the tools run it."""
    return np.array([pyramid_q1(positions[g], normals[g], mu, centre, scales[g], edges)
                     for g in range(positions.shape[0])])


@dataclass(frozen=True)
class EpsilonComparison:
    """Exact epsilon and pyramid Q1 of the same random grasps of one object.

    Attributes
    ----------
    name : str
    n_fingers : int
    mu : float
    force_closure : ndarray of bool, shape (N,)
    lower, upper : ndarray, shape (N,)
        Certified bounds on epsilon (to EXACT_RTOL).
    pyramid : dict
        Edge count -> pyramid Q1 (N,).
    exact_s : float
        CPU seconds of the batched ``epsilon_quality`` call.
    pyramid_s : dict
        Edge count -> CPU seconds of the pyramid Q1 of all grasps.
    """

    name: str
    n_fingers: int
    mu: float
    force_closure: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    pyramid: dict
    exact_s: float
    pyramid_s: dict

    @property
    def exact(self) -> np.ndarray:
        """The midpoint of the certified bounds (within EXACT_RTOL / 2 of epsilon)."""
        return 0.5 * (self.lower + self.upper)

    def relative_errors(self, edges: int) -> np.ndarray:
        """(epsilon - Q1) / epsilon over the force-closure grasps (1 where Q1 = 0)."""
        fc = self.force_closure
        return (self.exact[fc] - self.pyramid[edges][fc]) / self.exact[fc]

    def order_flips(self, edges: int) -> tuple[int, int, int]:
        """(flipped, tied, pairs) over the pairs of force-closure grasps whose exact order
        is certain (one's upper bound below the other's lower bound): flipped where the
        pyramid orders them the other way, tied where it scores them equal (mostly both
        0)."""
        fc = self.force_closure
        lower, upper, q1 = self.lower[fc], self.upper[fc], self.pyramid[edges][fc]
        below = upper[:, None] < lower[None, :]           # grasp i certainly below grasp j
        flipped = int(np.count_nonzero(below & (q1[:, None] > q1[None, :])))
        tied = int(np.count_nonzero(below & (q1[:, None] == q1[None, :])))
        return flipped, tied, int(np.count_nonzero(below))

    def pyramid_above_upper(self, edges: int) -> int:
        """Grasps whose pyramid Q1 exceeds the certified upper bound: must be 0 (the
        inscribed pyramid's wrench space lies inside W)."""
        return int(np.count_nonzero(self.pyramid[edges] > self.upper))


def compare_object(surface: ContactSurface, n_grasps: int, n_fingers: int, mu: float,
                   rng: np.random.Generator) -> EpsilonComparison:
    """Exact epsilon and the pyramid Q1 of ``n_grasps`` random grasps of ``surface``."""
    from grasp_fc_ros.core import epsilon_quality

    positions, normals = sample_grasps(surface, n_grasps, n_fingers, rng)
    centre = np.zeros(3)
    start = time.process_time()
    result = epsilon_quality(positions, normals, mu, center=centre, rtol=EXACT_RTOL)
    exact_s = time.process_time() - start
    pyramid, pyramid_s = {}, {}
    for edges in EDGE_COUNTS:
        start = time.process_time()
        pyramid[edges] = pyramid_q1_batch(positions, normals, mu, centre,
                                          result.torque_scale, edges)
        pyramid_s[edges] = time.process_time() - start
    return EpsilonComparison(surface.name, n_fingers, mu, result.force_closure,
                             result.lower, result.upper, pyramid, exact_s, pyramid_s)


def compare_objects(surfaces: Iterable[ContactSurface], n_grasps: int, n_fingers: int, mu: float,
                    rng: np.random.Generator) -> list[EpsilonComparison]:
    return [compare_object(s, n_grasps, n_fingers, mu, rng) for s in surfaces]


def summary_rows(comparisons: Sequence[EpsilonComparison]) -> list[dict[str, Any]]:
    """One row per object and edge count (and an "all" row per edge count)."""
    rows = []
    for edges in EDGE_COUNTS:
        for c in comparisons:
            rows.append(_summary(c.name, [c], edges))
        rows.append(_summary("all", comparisons, edges))
    return rows


def _summary(name: str, comparisons: Sequence[EpsilonComparison],
             edges: int) -> dict[str, Any]:
    errors = np.concatenate([c.relative_errors(edges) for c in comparisons])
    flips = np.sum([c.order_flips(edges) for c in comparisons], axis=0)
    fc = sum(int(c.force_closure.sum()) for c in comparisons)
    grasps = sum(c.force_closure.size for c in comparisons)

    def quantile(q: float) -> float:
        return float(np.quantile(errors, q)) if errors.size else float("nan")

    return {
        "object": name, "edges": edges, "grasps": grasps, "force_closure": fc,
        "median_error": quantile(0.5), "p90_error": quantile(0.9), "max_error": quantile(1.0),
        "pyramid_zero": sum(int(np.count_nonzero(c.force_closure & (c.pyramid[edges] == 0)))
                            for c in comparisons),
        "flipped_pairs": int(flips[0]), "tied_pairs": int(flips[1]),
        "ordered_pairs": int(flips[2]),
        "flip_share": float(flips[0] / flips[2]) if flips[2] else float("nan"),
        "above_upper": sum(c.pyramid_above_upper(edges) for c in comparisons),
        "exact_grasps_per_s": grasps / max(sum(c.exact_s for c in comparisons), 1e-9),
        "pyramid_grasps_per_s": grasps / max(sum(c.pyramid_s[edges] for c in comparisons),
                                             1e-9),
    }
