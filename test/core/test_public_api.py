"""The public names of ``grasp_fc_ros.core`` are pinned: a module may move, a name may not.

A name added to or dropped from ``core.__all__`` fails here until this list says so too
(and the CHANGELOG tells users).
"""

import importlib

import grasp_fc_ros.core as core

PUBLIC_NAMES = [
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


def test_core_all_is_exactly_the_pinned_public_names():
    assert sorted(core.__all__) == sorted(PUBLIC_NAMES)
    assert len(core.__all__) == len(set(core.__all__)), "a name listed twice in __all__"


def test_every_public_name_resolves_to_the_module_that_defines_it():
    # The API page documents each object under its defining module: that path must work.
    for name in PUBLIC_NAMES:
        obj = getattr(core, name)
        home = getattr(obj, "__module__", None)
        if home is None:  # a constant (ORIGIN_CHOICES)
            continue
        assert home.startswith("grasp_fc_ros.core."), (name, home)
        assert getattr(importlib.import_module(home), name) is obj, name
