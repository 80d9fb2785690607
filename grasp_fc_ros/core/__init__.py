"""ROS-free core of grasp_fc_ros: numpy, clarabel and numba only.

Force closure of n point contacts with Coulomb friction (hard, or soft fingers with
torsional friction: ``torsional_friction=``), after Niparnan, Phoka and
Sudsang, "Heuristic Approach for Multiple Queries of 3D N-Finger Frictional Force
Closure Grasp". Each idea has one place, grouped by folder; a folder or module imports
only what stands below it in this list:

* :mod:`.robustness` -- how far contacts may be off with force closure kept: certified
  radii (:mod:`.robustness.radii`), holds-or-breaks with evidence
  (:mod:`.robustness.holds`), and the probability of force closure under random errors
  (:mod:`.robustness.probability`);
* :mod:`.quality` -- how good a grasp is:

  * :mod:`.quality.epsilon` -- the Ferrari-Canny epsilon (Q1) with circular cones,
    certified bounds; its compiled search in :mod:`.quality.epsilon_kernels`;
  * :mod:`.quality.minimum_friction` -- the least friction coefficient that makes a
    grasp force closure (certified bounds);

* :mod:`.pipeline` -- the filter, then the exact test on the survivors;
* :mod:`.one_grasp` -- the compiled fast path of one grasp through the pipeline;
* :mod:`.forces` -- contact forces for a load:

  * :mod:`.forces.grasp_forces` -- the least largest normal force that holds a given
    load;
  * :mod:`.forces.force_interior_point` -- its fast stage for hard contacts: a compiled
    interior-point method, every answer checked in numpy;

* :mod:`.exact` -- the exact test and its certificates:

  * :mod:`.exact.exact_test` -- the exact test, a second-order cone program: the fast
    stage, then Clarabel for what it cannot certify;
  * :mod:`.exact.interior_point` -- the fast stage: a compiled interior-point method in
    the 6-vector wrench, deciding each grasp from certificates;
  * :mod:`.exact.certificates` -- internal forces and bounding wrenches, checked in numpy;
  * :mod:`.exact.stacked_socp` -- many same-shape SOCPs in one Clarabel solve (for the
    exact test, grasp forces and minimum friction);

* :mod:`.filter` -- the paper's torque-space filter:

  * :mod:`.filter.torque_sets` -- the torque set of one friction cone: a fan, a plane or
    {0};
  * :mod:`.filter.positive_span` -- do fans and planes positively span R^3?
  * :mod:`.filter.torque_space_filter` -- the paper's necessary condition (the filter);
  * :mod:`.filter.one_grasp_filter` -- the torque filter of the one-grasp path, compiled;

* :mod:`.model` -- the grasp as the core takes it:

  * :mod:`.model.contact_model` -- hard contacts and soft fingers (torsional friction):
    cones, wrench columns, depths and work, in one place;
  * :mod:`.model.grasp_input` -- shapes and per-grasp validation;

* :mod:`._kernels` -- the compiled building blocks of the three interior-point stages
  (JIT decorator, contact frames, grasp maps, 6 x 6 Cholesky, second-order cone steps);
* :mod:`.tolerances` -- every numerical tolerance, with the reason for its value.

Example
-------
>>> import numpy as np
>>> from grasp_fc_ros.core import check_force_closure
>>> positions = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]], float)
>>> result = check_force_closure(positions, -positions, mu=0.5)
>>> bool(result.force_closure)
True
"""

from .exact.certificates import verify_certificates
from .filter.torque_space_filter import ORIGIN_CHOICES, torque_filter
from .forces.grasp_forces import GraspForces, optimal_contact_forces
from .model.grasp_input import GraspValidation, validate_grasps
from .one_grasp import warm_up
from .pipeline import ForceClosureResult, Status, check_force_closure, exact_force_closure
from .quality.epsilon import EpsilonNotConverged, EpsilonResult, epsilon_quality
from .quality.minimum_friction import MinimumFriction, minimum_friction, minimum_friction_bounds
from .robustness import (
    ForceClosureProbability,
    Holds,
    HoldsUnder,
    RobustnessRadii,
    holds_under,
    probability_of_force_closure,
    robustness,
)

__all__ = [
    "ORIGIN_CHOICES",
    "EpsilonNotConverged",
    "EpsilonResult",
    "ForceClosureProbability",
    "ForceClosureResult",
    "GraspForces",
    "GraspValidation",
    "Holds",
    "HoldsUnder",
    "MinimumFriction",
    "RobustnessRadii",
    "Status",
    "check_force_closure",
    "epsilon_quality",
    "exact_force_closure",
    "holds_under",
    "minimum_friction",
    "minimum_friction_bounds",
    "optimal_contact_forces",
    "probability_of_force_closure",
    "robustness",
    "torque_filter",
    "validate_grasps",
    "verify_certificates",
    "warm_up",
]
