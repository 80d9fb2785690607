"""What ``--robustness`` asks of each grasp: its certified radii, whether it holds under
given contact errors, and its probability of force closure under given noise.

The question is the node's (:class:`~grasp_fc_ros.packed.RobustnessQuery`, the fields of
an assess_robustness request); here it also says which columns it adds. The settings
travel with every chunk to the workers and into the output's manifest (only those that
change the columns, so that a re-run resumes whatever the others say). The probability's
noise is drawn per grasp, from a stream of the run's seed and the grasp's id (the core's
``grasp_ids``): a grasp gets the same estimate whatever chunk, worker or run labels it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from grasp_fc_ros.packed import RobustnessQuery

#: Monte-Carlo samples per grasp (the service's default): a 95 % interval of about +-0.03.
DEFAULT_SAMPLES = RobustnessQuery.samples
DEFAULT_CONFIDENCE = RobustnessQuery.confidence

ERRORS = ("position_error", "normal_error", "friction_error")
SIGMAS = ("position_sigma", "normal_sigma", "friction_sigma")


@dataclass(frozen=True)
class Robustness(RobustnessQuery):
    """Robustness columns to label (``grasp-fc-label --robustness``): the fields of
    :class:`~grasp_fc_ros.packed.RobustnessQuery`, checked on construction.

    The radii (``normal_angle``, ``position_radius``, ``friction_drop``) are always
    written; the ``holds`` columns when an error is > 0; the ``probability`` columns when
    a sigma is > 0 (and ``samples`` > 0). ``seed`` is the run's: grasp ``id`` draws its
    noise from ``SeedSequence(seed, spawn_key=(id,))`` (not a stream of the grasps drawn
    on objects, ``default_rng([seed, object, block])``).

    Raises
    ------
    ValueError
        A setting out of range, naming it.
    """

    def __post_init__(self) -> None:
        problem = self.problem()
        if problem:
            raise ValueError(problem)

    @property
    def holds(self) -> bool:
        """Whether the ``holds`` columns are asked for (an error > 0)."""
        return any(getattr(self, name) > 0.0 for name in ERRORS)

    @property
    def probability(self) -> bool:
        """Whether the ``probability`` columns are asked for (a sigma > 0)."""
        return self.samples > 0 and any(getattr(self, name) > 0.0 for name in SIGMAS)

    def manifest(self) -> dict[str, Any]:
        """The settings that change the output: the errors with ``holds``, the noise,
        samples, confidence and seed with ``probability``."""
        settings = asdict(self)
        kept = (ERRORS if self.holds else ()) + (
            (*SIGMAS, "samples", "confidence", "seed") if self.probability else ())
        return {name: settings[name] for name in kept}
