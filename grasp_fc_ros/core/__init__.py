"""ROS-free core of grasp_fc_ros: numpy, clarabel and numba only.

Force closure of n point contacts with Coulomb friction (hard, or soft fingers with
torsional friction: ``torsional_friction=``), after Niparnan, Phoka and
Sudsang, "Heuristic Approach for Multiple Queries of 3D N-Finger Frictional Force
Closure Grasp":

* :mod:`.torque_sets` -- the torque set of one friction cone: a fan, a plane or {0};
* :mod:`.positive_span` -- do fans and planes positively span R^3?
* :mod:`.torque_space_filter` -- the paper's necessary condition (the filter);
* :mod:`.exact_test` -- the exact test, a second-order cone program: the fast stage,
  then Clarabel for what it cannot certify;
* :mod:`.interior_point` -- the fast stage: a compiled interior-point method in the
  6-vector wrench, deciding each grasp from certificates;
* :mod:`.certificates` -- internal forces and bounding wrenches, checked in numpy;
* :mod:`.pipeline` -- the filter, then the exact test on the survivors;
* :mod:`.one_grasp` -- the compiled fast path of one grasp through the pipeline;
* :mod:`.one_grasp_filter` -- the torque filter of that path, compiled;
* :mod:`.epsilon` -- the Ferrari-Canny epsilon (Q1) with circular cones, certified
  bounds; its compiled search in :mod:`.epsilon_kernels`;
* :mod:`.minimum_friction` -- the least friction coefficient that makes a grasp force
  closure (certified bounds);
* :mod:`.robustness` -- how far contacts may be off with force closure kept: certified
  radii, and holds-or-breaks with evidence;
* :mod:`.grasp_forces` -- the least largest normal force that holds a given load;
* :mod:`.force_interior_point` -- its fast stage for hard contacts: a compiled
  interior-point method, every answer checked in numpy;
* :mod:`._kernels` -- the compiled building blocks of the three interior-point stages
  (JIT decorator, contact frames, grasp maps, 6 x 6 Cholesky, second-order cone steps);
* :mod:`.stacked_socp` -- many same-shape SOCPs in one Clarabel solve (for the two above);
* :mod:`.contact_model` -- hard contacts and soft fingers (torsional friction): cones,
  wrench columns, depths and work, in one place;
* :mod:`.grasp_input` -- shapes and per-grasp validation;
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

from .certificates import verify_certificates
from .epsilon import EpsilonResult, epsilon_quality
from .grasp_forces import GraspForces, optimal_contact_forces
from .grasp_input import GraspValidation, validate_grasps
from .minimum_friction import MinimumFriction, minimum_friction, minimum_friction_bounds
from .one_grasp import warm_up
from .pipeline import ForceClosureResult, Status, check_force_closure, exact_force_closure
from .robustness import Holds, HoldsUnder, RobustnessRadii, holds_under, robustness
from .torque_space_filter import ORIGIN_CHOICES, torque_filter

__all__ = [
    "ORIGIN_CHOICES",
    "EpsilonResult",
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
    "robustness",
    "torque_filter",
    "validate_grasps",
    "verify_certificates",
    "warm_up",
]
