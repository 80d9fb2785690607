"""Robustness of force closure to contact errors (issue 29): how far normals may tilt,
contacts move and friction drop with force closure kept.

* :mod:`.radii` -- :func:`robustness`: certified radii for each kind of error alone;
* :mod:`.holds` -- :func:`holds_under`: for given errors, HOLDS (a sound bound),
  BREAKS (a witness the exact test certifies) or UNDECIDED;
* :mod:`.shrink` -- shrunk friction cones (the tilt lemma) and the bisection on them;
* :mod:`.position_radius` -- the torque inradius behind the position radius;
* :mod:`.break_distance` -- the least moves that let a torque direction separate a
  grasp (a conic program per direction), searched over directions;
* :mod:`.witness` -- tilts and moves that break force closure;
* :mod:`.probability` -- :func:`probability_of_force_closure`: Monte Carlo under random
  errors, every sample decided by the exact test, with Clopper-Pearson bounds.

docs/robustness.md has the definitions and the proofs.
"""

from .holds import Holds, HoldsUnder, holds_under
from .probability import ForceClosureProbability, probability_of_force_closure
from .radii import RobustnessRadii, robustness

__all__ = ["ForceClosureProbability", "Holds", "HoldsUnder", "RobustnessRadii",
           "holds_under", "probability_of_force_closure", "robustness"]
