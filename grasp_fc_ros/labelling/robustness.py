"""What ``--robustness`` asks of each grasp: its certified radii, whether it holds under
given contact errors, and its probability of force closure under given noise.

The settings travel with every chunk to the workers and into the output's manifest (only
those that change the columns, so that a re-run resumes whatever the others say). The
probability's noise is drawn per grasp, from a stream of the run's seed and the grasp's
id (the core's ``grasp_ids``): a grasp gets the same estimate whatever chunk, worker or
run labels it.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

#: Monte-Carlo samples per grasp (the core's default): a 95 % interval of about +-0.03.
DEFAULT_SAMPLES = 1000
DEFAULT_CONFIDENCE = 0.95

ERRORS = ("position_error", "normal_error", "friction_error")
SIGMAS = ("position_sigma", "normal_sigma", "friction_sigma")


@dataclass(frozen=True)
class Robustness:
    """Robustness columns to label (``grasp-fc-label --robustness``).

    The radii (``normal_angle``, ``position_radius``, ``friction_drop``) are always
    written; the ``holds`` columns when an error is > 0; the ``probability`` columns when
    a sigma is > 0.

    Attributes
    ----------
    position_error, normal_error, friction_error : float
        The errors of :func:`grasp_fc_ros.core.holds_under` (positions' unit, rad, mu).
    position_sigma, normal_sigma, friction_sigma : float
        The noise of :func:`grasp_fc_ros.core.probability_of_force_closure` (positions'
        unit, rad, mu).
    samples : int
        Monte-Carlo samples per grasp.
    confidence : float
        Of the Clopper-Pearson interval, in (0, 1).
    seed : int
        The run's seed: grasp ``id`` draws its noise from
        ``SeedSequence(seed, spawn_key=(id,))`` (not a stream of the grasps drawn on
        objects, ``default_rng([seed, object, block])``).
    """

    position_error: float = 0.0
    normal_error: float = 0.0
    friction_error: float = 0.0
    position_sigma: float = 0.0
    normal_sigma: float = 0.0
    friction_sigma: float = 0.0
    samples: int = DEFAULT_SAMPLES
    confidence: float = DEFAULT_CONFIDENCE
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ERRORS + SIGMAS:
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be finite and >= 0, got {value}")
        if self.samples < 1:
            raise ValueError(f"samples must be >= 1, got {self.samples}")
        if not 0.0 < self.confidence < 1.0:
            raise ValueError(f"confidence must be in (0, 1), got {self.confidence}")
        if self.seed < 0:
            raise ValueError(f"seed must be >= 0, got {self.seed}")

    @property
    def holds(self) -> bool:
        """Whether the ``holds`` columns are asked for (an error > 0)."""
        return any(getattr(self, name) > 0.0 for name in ERRORS)

    @property
    def probability(self) -> bool:
        """Whether the ``probability`` columns are asked for (a sigma > 0)."""
        return any(getattr(self, name) > 0.0 for name in SIGMAS)

    def manifest(self) -> dict[str, Any]:
        """The settings that change the output: the errors with ``holds``, the noise,
        samples, confidence and seed with ``probability``."""
        settings = asdict(self)
        kept = (ERRORS if self.holds else ()) + (
            (*SIGMAS, "samples", "confidence", "seed") if self.probability else ())
        return {name: settings[name] for name in kept}

