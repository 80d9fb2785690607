"""Every public function of the core takes an empty batch (N = 0) and returns empty
results of its documented shapes: no reshape error, no solver call, nothing invented."""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

import grasp_fc_ros.core as core

N_CONTACTS = 4
EMPTY = np.zeros((0, N_CONTACTS, 3))


def _fields(result: Any, expected: dict[str, tuple[tuple[int, ...], type]]) -> None:
    for name, (shape, kind) in expected.items():
        value = result[int(name)] if name.isdigit() else getattr(result, name)
        assert isinstance(value, np.ndarray), f"{name}: {type(value)}"
        assert value.shape == shape, f"{name}: {value.shape}, documented {shape}"
        assert np.issubdtype(value.dtype, kind), f"{name}: {value.dtype}"


VERDICT = {"force_closure": ((0,), np.bool_), "filtered_out": ((0,), np.bool_),
           "margin": ((0,), np.floating), "status": ((0,), np.integer),
           "margin_upper": ((0,), np.floating)}
CERTIFICATES = {"contact_forces": ((0, N_CONTACTS, 3), np.floating),
                "separating_wrench": ((0, 6), np.floating), "marginal": ((0,), np.bool_)}
EPSILON = {"lower": ((0,), np.floating), "upper": ((0,), np.floating),
           "direction": ((0, 6), np.floating), "force_closure": ((0,), np.bool_),
           "converged": ((0,), np.bool_), "center": ((0, 3), np.floating),
           "torque_scale": ((0,), np.floating), "support_points": ((0,), np.integer)}
BOUNDS = {name: ((0,), np.number) for name in ("value", "lower", "upper", "solves")}
FORCES = {"max_normal_force": ((0,), np.floating),
          "forces": ((0, N_CONTACTS, 3), np.floating),
          "torques": ((0, N_CONTACTS), np.floating)}
RADII = {"normal_angle": ((0,), np.floating), "position_radius": ((0,), np.floating),
         "friction_drop": ((0,), np.floating), "force_closure": ((0,), np.bool_)}
HOLDS = {"status": ((0,), np.integer), "bound": ((0,), np.str_),
         "witness_positions": ((0, N_CONTACTS, 3), np.floating),
         "witness_normals": ((0, N_CONTACTS, 3), np.floating),
         "witness_mu": ((0, N_CONTACTS), np.floating),
         "separating_wrench": ((0, 6), np.floating)}
PAIR = {"0": ((0,), np.bool_), "1": ((0,), np.bool_)}
FILTER_PAIR = {"0": ((0,), np.bool_), "1": ((0, 6), np.floating)}


def _array(shape: tuple[int, ...], kind: type) -> Callable[[Any], None]:
    def check(result: Any) -> None:
        assert isinstance(result, np.ndarray) and result.shape == shape, repr(result)
        assert np.issubdtype(result.dtype, kind), result.dtype
    return check


def _validation(result: core.GraspValidation) -> None:
    _array((0,), np.bool_)(result.valid)
    assert result.reasons == []


SOFT = {"torsional_friction": 0.01}
# function name -> [(keyword arguments, check of the result)]
CASES: dict[str, list[tuple[dict[str, Any], Callable[[Any], None]]]] = {
    "check_force_closure": [
        ({"mu": 0.5}, lambda r: _fields(r, VERDICT)),
        ({"mu": 0.5, "use_filter": True}, lambda r: _fields(r, VERDICT)),
        ({"mu": 0.5, "margin": "bound"}, lambda r: _fields(r, VERDICT)),
        ({"mu": 0.5, "certificates": True}, lambda r: _fields(r, VERDICT | CERTIFICATES)),
        ({"mu": 0.5, "certificates": True, **SOFT},
         lambda r: _fields(r, VERDICT | CERTIFICATES))],
    "exact_force_closure": [({"mu": 0.5}, _array((0,), np.bool_)),
                            ({"mu": 0.5, **SOFT}, _array((0,), np.bool_))],
    "minimum_friction": [({}, _array((0,), np.floating)),
                         ({"margin": 0.01, **SOFT}, _array((0,), np.floating))],
    "minimum_friction_bounds": [({}, lambda r: _fields(r, BOUNDS)),
                                ({**SOFT}, lambda r: _fields(r, BOUNDS))],
    "epsilon_quality": [({"mu": 0.5}, lambda r: _fields(r, EPSILON)),
                        ({"mu": 0.5, "budget": "linf", "center": np.zeros((0, 3)),
                          "torque_scale": np.ones(0), **SOFT},
                         lambda r: _fields(r, EPSILON))],
    "optimal_contact_forces": [
        ({"mu": 0.5, "wrench": np.zeros(6)}, lambda r: _fields(r, FORCES)),
        ({"mu": 0.5, "wrench": np.zeros((0, 6)), "max_normal_force": 1.0, **SOFT},
         lambda r: _fields(r, FORCES))],
    "robustness": [({"mu": 0.5}, lambda r: _fields(r, RADII))],
    "holds_under": [({"mu": 0.5, "position_error": 0.1, "normal_error": 0.1,
                      "friction_error": 0.1}, lambda r: _fields(r, HOLDS))],
    "torque_filter": [({"mu": 0.5}, _array((0,), np.bool_)),
                      ({"mu": 0.5, "origins": "all", "certificates": True},
                       lambda r: _fields(r, FILTER_PAIR))],
    "validate_grasps": [({"mu": 0.5}, _validation), ({"mu": 0.5, **SOFT}, _validation)],
    "verify_certificates": [
        ({"mu": 0.5, "contact_forces": EMPTY, "separating_wrench": np.zeros((0, 6))},
         lambda r: _fields(r, PAIR)),
        ({"mu": 0.5, "contact_forces": EMPTY, "contact_torques": np.zeros((0, N_CONTACTS)),
          **SOFT}, lambda r: _fields(r, PAIR))],
}


def test_every_public_function_of_the_core_is_covered():
    public = {name for name in core.__all__
              if inspect.isfunction(getattr(core, name)) and name != "warm_up"}
    assert public == set(CASES)


@pytest.mark.parametrize("name,kwargs,check", [
    pytest.param(name, kwargs, check, id=f"{name}-{i}")
    for name, cases in CASES.items() for i, (kwargs, check) in enumerate(cases)])
def test_an_empty_batch_gives_empty_results_of_the_documented_shapes(name, kwargs, check):
    check(getattr(core, name)(EMPTY, EMPTY, **kwargs))
