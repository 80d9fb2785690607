"""The node's parameters: names, defaults, descriptors with ranges, their checks, and
:class:`LiveParameters`, which declares them on a node and keeps their current values.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import fields, replace
from typing import Any

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.node import Node
from rclpy.parameter import Parameter

from grasp_fc_ros.core import ORIGIN_CHOICES
from grasp_fc_ros.core.tolerances import MAX_FRICTION_COEFFICIENT
from grasp_fc_ros.engine.worker_crew import WORKER_TIMEOUT_S
from grasp_fc_ros.markers.build import DEFAULT_LIFETIME_S
from grasp_fc_ros.markers.publisher import (
    DEFAULT_MARKER_SAMPLE,
    MAX_MARKER_SAMPLE,
    MarkerSettings,
)
from grasp_fc_ros.packed import MIN_CONTACTS, Settings

# Upper bounds of the integer parameters: beyond these a single message would not fit
# any sensible memory budget.
MAX_CONTACTS_LIMIT = 10_000
MAX_BATCH_LIMIT = 10_000_000
MAX_MESSAGE_CONTACTS_LIMIT = 100_000_000
# Contacts in one batch message, goal or service request by default: 80 parts of GraspClient's
# MAX_MESSAGE_CONTACTS, the largest one-message batch from another process measured to
# keep service calls within their targets before batches had a DDS participant of their
# own; much larger ones held them up for 0.2 s (tuned: docs/performance.md#big-batches).
DEFAULT_MAX_MESSAGE_CONTACTS = 491_520
MAX_WORKERS = 64
# Samples (grasps x samples per grasp) of one assess_robustness request by default:
# about 2.5 s of one core at 4 contacts (docs/performance.md#robustness-service), so that a
# request cannot keep the workers from batches for long; 1,000 grasps at 1,000 samples.
DEFAULT_MAX_ASSESSMENT_SAMPLES = 1_000_000
MAX_ASSESSMENT_SAMPLES_LIMIT = 1_000_000_000
# Worker processes by default: the 2 cores of the machines this was measured on. A fixed
# number, so that a params file and the docs say the same on every machine.
DEFAULT_WORKERS = 2

# Range of worker_timeout_s (s): below a second a loaded machine's scheduling alone would
# count healthy workers as hung; an hour is beyond any chunk's time (docs/node.rst).
MIN_WORKER_TIMEOUT_S = 1.0
MAX_WORKER_TIMEOUT_S = 3600.0

# Longest accepted marker_lifetime (s): a year; 0 already means forever.
MAX_MARKER_LIFETIME_S = 365 * 24 * 3600.0
# Parameters that users may set through QoSOverridingOptions, e.g.
# qos_overrides./contacts.subscription.depth (rclpy declares them, read-only).
QOS_OVERRIDES_PREFIX = "qos_overrides."


def _int_descriptor(description: str, low: int, high: int,
                    read_only: bool = False) -> ParameterDescriptor:
    return ParameterDescriptor(
        type=ParameterType.PARAMETER_INTEGER, description=description, read_only=read_only,
        integer_range=[IntegerRange(from_value=low, to_value=high, step=1)])


def _bool_descriptor(description: str) -> ParameterDescriptor:
    return ParameterDescriptor(type=ParameterType.PARAMETER_BOOL, description=description)


PARAMETERS: dict[str, tuple[Any, ParameterDescriptor]] = {
    # name: (default, descriptor)
    "friction_coefficient": (0.5, ParameterDescriptor(
        type=ParameterType.PARAMETER_DOUBLE,
        description="Coulomb friction coefficient for contacts that give 0 (none); a "
                    "negative one makes the query INVALID_INPUT",
        additional_constraints=f"finite, > 0 and <= {MAX_FRICTION_COEFFICIENT:g}")),
    "use_filter": (True, _bool_descriptor(
        "Run the torque-space filter before the exact test where it pays "
        "for the grasp's contact count (the core's use_filter='auto'); false: "
        "never. Verdicts are the same either way")),
    "filter_origins": ("seed", ParameterDescriptor(
        type=ParameterType.PARAMETER_STRING,
        description="Torque origins of the filter: 'seed' (the paper's) or 'all'",
        additional_constraints="one of: " + ", ".join(ORIGIN_CHOICES))),
    "max_contacts": (64, _int_descriptor(
        "Largest number of contacts accepted in one grasp", MIN_CONTACTS, MAX_CONTACTS_LIMIT)),
    "max_batch": (100_000, _int_descriptor(
        "Largest number of grasps accepted in one batch message or service request, of "
        "single-grasp topic queries waiting to be decided, and of batch grasps waiting; "
        "beyond that a query is answered at once with SOLVER_FAILURE 'node overloaded'",
        1, MAX_BATCH_LIMIT)),
    "max_message_contacts": (DEFAULT_MAX_MESSAGE_CONTACTS, _int_descriptor(
        "Largest number of contacts accepted in one batch message, label_grasps goal "
        "or check_force_closure request (0: no limit); a larger one is answered whole "
        "with INVALID_INPUT saying to split it (GraspClient does). A goal or request that "
        "large may have held up the node's service calls while it arrived (a batch "
        "message arrives on a DDS participant of its own): the limit tells its sender",
        0, MAX_MESSAGE_CONTACTS_LIMIT)),
    "certificates": (False, _bool_descriptor(
        "Every verdict carries its certificate: contact forces of a "
        "force-closure grasp, the separating wrench of a rejected one "
        "(larger verdict messages, more time per grasp)")),
    "compute_min_friction": (False, _bool_descriptor(
        "Every verdict carries the grasp's minimum friction coefficient "
        "(about a hundred exact tests' worth of time per grasp)")),
    "compute_epsilon": (False, _bool_descriptor(
        "Every verdict carries certified bounds epsilon_lower <= epsilon <= "
        "epsilon_upper on the grasp's Ferrari-Canny epsilon (circular friction cones, "
        "normal forces summing to <= 1, torques about the frame's origin over the largest "
        "contact distance from it); costs more than the verdict itself "
        "(docs/epsilon.md#cost)")),
    "max_assessment_samples": (DEFAULT_MAX_ASSESSMENT_SAMPLES, _int_descriptor(
        "Largest number of samples (grasps x samples per grasp) of one assess_robustness "
        "request; a larger one is answered whole with INVALID_INPUT saying so",
        1, MAX_ASSESSMENT_SAMPLES_LIMIT)),
    "workers": (DEFAULT_WORKERS, _int_descriptor(
        "Worker processes deciding large batches and service requests (0: none, decide "
        "in the node's threads); set at start-up", 0, MAX_WORKERS, read_only=True)),
    "worker_timeout_s": (WORKER_TIMEOUT_S, ParameterDescriptor(
        type=ParameterType.PARAMETER_DOUBLE, read_only=True,
        description="Least seconds a worker process may take to answer a chunk (plus a "
                    "time per contact of the chunk) before it counts as hung: it is then "
                    "killed and replaced, and its chunk decided again; set at start-up",
        floating_point_range=[FloatingPointRange(from_value=MIN_WORKER_TIMEOUT_S,
                                                 to_value=MAX_WORKER_TIMEOUT_S)])),
    "publish_markers": (False, _bool_descriptor(
        "Publish visualization_msgs/MarkerArray on 'markers' for answered "
        "queries (built off the verdict path; dropped, never the verdicts, "
        "when they fall behind)")),
    "marker_lifetime": (DEFAULT_LIFETIME_S, ParameterDescriptor(
        type=ParameterType.PARAMETER_DOUBLE,
        description="Seconds until RViz drops a query's markers (0: never)",
        floating_point_range=[FloatingPointRange(from_value=0.0,
                                                 to_value=MAX_MARKER_LIFETIME_S)])),
    "marker_batch_sample": (DEFAULT_MARKER_SAMPLE, _int_descriptor(
        "At most this many grasps of each batch and service request get markers "
        "(evenly spread; single topic queries always do)", 0, MAX_MARKER_SAMPLE)),
}
# Marker parameter name -> MarkerSettings field.
MARKER_SETTINGS = {"publish_markers": "enabled", "marker_lifetime": "lifetime_s",
                    "marker_batch_sample": "batch_sample"}

# The Settings fields that are parameters (``robustness`` is set per request).
SETTING_NAMES = frozenset(f.name for f in fields(Settings)) & frozenset(PARAMETERS)


def check_parameter(name: str, value: Any) -> str:
    """Return why ``value`` is not acceptable for parameter ``name`` ('' if it is)."""
    if name == "friction_coefficient":
        if not (math.isfinite(value) and 0 < value <= MAX_FRICTION_COEFFICIENT):
            return (f"friction_coefficient must be finite, > 0 and <= "
                    f"{MAX_FRICTION_COEFFICIENT:g}, got {value}")
    elif name == "marker_lifetime" and not (math.isfinite(value)
                                            and 0 <= value <= MAX_MARKER_LIFETIME_S):
        return (f"marker_lifetime must be finite, >= 0 and <= {MAX_MARKER_LIFETIME_S:g} s, "
                f"got {value}")
    elif name == "worker_timeout_s" and not (
            math.isfinite(value) and MIN_WORKER_TIMEOUT_S <= value <= MAX_WORKER_TIMEOUT_S):
        return (f"worker_timeout_s must be finite, >= {MIN_WORKER_TIMEOUT_S:g} and <= "
                f"{MAX_WORKER_TIMEOUT_S:g} s, got {value}")
    elif name == "filter_origins" and value not in ORIGIN_CHOICES:
        return f"filter_origins must be one of {ORIGIN_CHOICES}, got {value!r}"
    return ""


class LiveParameters:
    """Declares the node's parameters, checks every change, and keeps the values the
    lanes read as snapshots.

    :attr:`settings` (the :class:`~grasp_fc_ros.packed.Settings` that decide
    queries) and :attr:`markers` (:class:`~grasp_fc_ros.markers.publisher.MarkerSettings`)
    are replaced whole on a change, so that a reader sees either the old or the new
    values, and read without looking parameters up on the hot path. Unknown parameter
    overrides given to the node are logged (rclpy drops them silently).
    """

    def __init__(self, node: Node):
        self.settings = Settings(**{name: PARAMETERS[name][0] for name in SETTING_NAMES})
        self.markers = MarkerSettings()
        self._marker_listeners: list[Callable[[MarkerSettings], None]] = []
        node.add_on_set_parameters_callback(self._check)
        node.add_post_set_parameters_callback(self._changed)
        for name, (default, descriptor) in PARAMETERS.items():
            node.declare_parameter(name, default, descriptor)
        self.workers: int = node.get_parameter("workers").value
        self.worker_timeout_s: float = node.get_parameter("worker_timeout_s").value
        self._warn_unknown_overrides(node)

    def on_marker_settings(self, listener: Callable[[MarkerSettings], None]) -> None:
        """Call ``listener(markers)`` after every change of a marker parameter."""
        self._marker_listeners.append(listener)

    def _check(self, parameters: list[Parameter]) -> SetParametersResult:
        reasons = [check_parameter(p.name, p.value) for p in parameters]
        reasons = [r for r in reasons if r]
        return SetParametersResult(successful=not reasons, reason="; ".join(reasons))

    def _changed(self, parameters: list[Parameter]) -> None:
        changes = {p.name: p.value for p in parameters if p.name in SETTING_NAMES}
        if changes:
            self.settings = replace(self.settings, **changes)
        marker_changes = {MARKER_SETTINGS[p.name]: p.value for p in parameters
                          if p.name in MARKER_SETTINGS}
        if marker_changes:
            self.markers = replace(self.markers, **marker_changes)
            for listener in self._marker_listeners:
                listener(self.markers)

    @staticmethod
    def _warn_unknown_overrides(node: Node) -> None:
        """Warn about parameter values given for this node that match no parameter
        (a typo such as ``frction_coefficient`` would go unnoticed). rclpy keeps the
        overrides in a private attribute: read it defensively."""
        overrides = getattr(node, "_parameter_overrides", {}) or {}
        unknown = sorted(name for name in set(overrides) - set(PARAMETERS) - {"use_sim_time"}
                         if not name.startswith(QOS_OVERRIDES_PREFIX))
        if unknown:
            node.get_logger().warning(
                f"ignoring unknown parameter(s) {', '.join(unknown)}; this node has "
                f"{', '.join(PARAMETERS)}")
