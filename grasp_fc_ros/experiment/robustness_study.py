"""The experiment's robustness part (issue 29): what robustness changes for users.

On random grasps of the experiment's objects (built in metres), ``FINGERS`` contacts at
friction ``MU``, over the force-closure grasps:

* the Spearman rank correlation between the margin t*, the Ferrari-Canny epsilon, the
  three certified radii (:func:`grasp_fc_ros.core.robustness`) and the probability of
  force closure under ``NOISE`` (2 mm, 3 degrees, friction 0.1);
* of the top 10 % of each object's grasps by epsilon, how many fall in the bottom half by
  probability (Weisz and Allen's point: the grasp most robust to contact errors is often
  not the highest-epsilon one);

and over all the grasps (force closure or not), with Dex-Net's noise mapped onto this
package's error model (``DEXNET_NOISE``), how often the label "probability > 0.5" from
``DEXNET_SAMPLES`` samples (Dex-Net's test config) differs from the one from
``REFERENCE_SAMPLES`` samples drawn from other streams.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

from grasp_fc_ros.objects import ContactSurface, sample_grasps

FINGERS = 4
MU = 0.5
#: Issue 29's noise: each position coordinate 2 mm, each normal tilted |N(0, 3 deg)|,
#: the friction coefficient 0.1 (the objects are in metres).
NOISE = {"position_sigma": 0.002, "normal_sigma": math.radians(3.0), "friction_sigma": 0.1}
#: Dex-Net's test config (docs/robustness.md#probability-of-force-closure) moves the
#: gripper by 5 mm and the object by 1 cm (standard deviations, rigidly), rotates them by
#: 0.001 and 0.01 rad and shifts mu = 0.5 by 0.1. Here every contact moves and tilts on
#: its own: the two translations' sigmas add in quadrature into one per contact, as do
#: the rotations' into a tilt (a rigid rotation by theta tilts every normal by at most
#: theta). The same sizes, a different (independent per contact) law.
DEXNET_NOISE = {"position_sigma": math.hypot(0.005, 0.01),
                "normal_sigma": math.hypot(0.001, 0.01), "friction_sigma": 0.1}
DEXNET_SAMPLES = 25
REFERENCE_SAMPLES = 2000
#: Share of each object's force-closure grasps counted as its "top" by epsilon.
TOP_SHARE = 0.1
#: The measures compared, in the order of the correlation matrix.
MEASURES = ("margin", "epsilon", "normal_angle", "position_radius", "friction_drop",
            "probability")
#: Reference streams start here, apart from the 25-sample labels' 0..N-1.
REFERENCE_STREAMS = 1 << 40


@dataclass(frozen=True)
class ObjectRobustness:
    """The measures of one object's random grasps.

    Attributes
    ----------
    name : str
    grasps : int
        Random grasps drawn.
    measures : dict
        Name (:data:`MEASURES`) -> (F,) values over the F force-closure grasps.
    few, many : ndarray, shape (grasps,)
        Probability estimates under DEXNET_NOISE from DEXNET_SAMPLES and from
        REFERENCE_SAMPLES samples, over all the grasps.
    """

    name: str
    grasps: int
    measures: dict[str, np.ndarray]
    few: np.ndarray
    many: np.ndarray

    def top_epsilon_in_bottom_probability(self) -> tuple[int, int]:
        """(top, in bottom half): the top TOP_SHARE of the force-closure grasps by
        epsilon (at least one), and how many of them rank in the bottom half by
        probability (average ranks of ties <= half the count)."""
        epsilon, probability = self.measures["epsilon"], self.measures["probability"]
        count = epsilon.size
        if not count:
            return 0, 0
        top = np.argsort(-epsilon)[:max(1, int(round(TOP_SHARE * count)))]
        bottom = stats.rankdata(probability) <= count / 2
        return top.size, int(np.count_nonzero(bottom[top]))

    def label_flips(self) -> tuple[int, int]:
        """(differ, grasps): grasps whose label "probability > 0.5" from DEXNET_SAMPLES
        samples differs from the one from REFERENCE_SAMPLES."""
        return int(np.count_nonzero((self.few > 0.5) != (self.many > 0.5))), self.grasps


def measure_object(surface: ContactSurface, n_grasps: int, samples: int,
                   rng: np.random.Generator, reference_samples: int = REFERENCE_SAMPLES,
                   ) -> ObjectRobustness:
    """The measures of ``n_grasps`` random grasps of ``surface`` (see the module
    docstring); the probabilities from ``samples`` samples each."""
    from grasp_fc_ros.core import (
        check_force_closure,
        epsilon_quality,
        probability_of_force_closure,
        robustness,
    )

    positions, normals = sample_grasps(surface, n_grasps, FINGERS, rng)
    seed = int(rng.integers(2 ** 63))
    verdicts = check_force_closure(positions, normals, MU)
    fc = np.flatnonzero(verdicts.force_closure)
    p, n = positions[fc], normals[fc]
    radii = robustness(p, n, MU)
    epsilon = epsilon_quality(p, n, MU, center=np.zeros(3))
    chance = probability_of_force_closure(p, n, MU, samples=samples, seed=seed, **NOISE)
    measures = {"margin": verdicts.margin[fc], "epsilon": 0.5 * (epsilon.lower + epsilon.upper),
                "normal_angle": radii.normal_angle, "position_radius": radii.position_radius,
                "friction_drop": radii.friction_drop, "probability": chance.estimate}
    few = probability_of_force_closure(positions, normals, MU, samples=DEXNET_SAMPLES,
                                       seed=seed, **DEXNET_NOISE).estimate
    many = probability_of_force_closure(
        positions, normals, MU, samples=reference_samples, seed=seed,
        grasp_ids=REFERENCE_STREAMS + np.arange(n_grasps), **DEXNET_NOISE).estimate
    return ObjectRobustness(surface.name, n_grasps, measures, few, many)


def measure_objects(surfaces: Iterable[ContactSurface], n_grasps: int, samples: int,
                    rng: np.random.Generator, reference_samples: int = REFERENCE_SAMPLES,
                    ) -> list[ObjectRobustness]:
    return [measure_object(s, n_grasps, samples, rng, reference_samples) for s in surfaces]


def pooled(objects: Sequence[ObjectRobustness], name: str) -> np.ndarray:
    """One measure over the force-closure grasps of every object."""
    return np.concatenate([o.measures[name] for o in objects])


def correlations(objects: Sequence[ObjectRobustness]) -> np.ndarray:
    """Spearman's rank correlation between the :data:`MEASURES` (6, 6), over the
    force-closure grasps of all objects (NaN where a measure is constant or there are
    fewer than three grasps)."""
    columns = np.stack([pooled(objects, name) for name in MEASURES], axis=1)
    if columns.shape[0] < 3:
        return np.full((len(MEASURES), len(MEASURES)), np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        matrix = stats.spearmanr(columns).statistic
    return np.atleast_2d(np.asarray(matrix, dtype=float))


def summary_rows(objects: Sequence[ObjectRobustness]) -> list[dict[str, object]]:
    """One row per object and an "all" row: force-closure grasps, the probability's
    rank correlation with each other measure, the top-by-epsilon count, and the label
    disagreements."""
    rows = []
    for name, group in [(o.name, [o]) for o in objects] + [("all", list(objects))]:
        matrix = correlations(group)
        top = [o.top_epsilon_in_bottom_probability() for o in group]
        flips = [o.label_flips() for o in group]
        row: dict[str, object] = {"object": name,
                                  "grasps": sum(o.grasps for o in group),
                                  "force_closure": int(pooled(group, "margin").size)}
        for k, measure in enumerate(MEASURES[:-1]):
            row[f"rho_probability_{measure}"] = float(matrix[-1, k])
        row["top_epsilon"] = sum(t for t, _ in top)
        row["top_epsilon_bottom_probability"] = sum(b for _, b in top)
        row["label_differ"] = sum(d for d, _ in flips)
        row["label_grasps"] = sum(g for _, g in flips)
        rows.append(row)
    return rows
