"""The service lane: ``check_force_closure`` and ``compute_contact_forces``.

Open this file to change how the services answer. Both are served from a helper node,
``<name>_service`` in the node's (possibly remapped) namespace, by a
:class:`~grasp_fc_ros.interface.wait_sets.ServiceLoop` on a thread of its own: a large
request waits for the workers in its callback, which on the node's executor would hold
up /diagnostics, and a bare wait set answers a one-grasp call faster than an executor
(docs/performance.md#service-latency). The helper takes no command-line arguments of
its own (a ``__node`` remapping would give it the node's own name); the service names
are resolved by the node itself, so that the node's remappings (``-r
check_force_closure:=...``, ``force_closure:check_force_closure:=...``, ``__ns``) apply
to them as to the topics. One request is served at a time (a multi-threaded executor
here crashed the process (SIGSEGV) now and then on a Ctrl-C right after start), so a
big request holds up the calls behind it: ``max_message_contacts`` bounds a request
as it bounds a batch message, and GraspClient sends a big call as several requests.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from geometry_msgs.msg import Vector3
from grasp_fc_msgs.msg import ContactArray, ForceClosureVerdict
from grasp_fc_msgs.srv import CheckForceClosure, ComputeContactForces
from rclpy.node import Node

from grasp_fc_ros.core import Status
from grasp_fc_ros.engine.contact_forces import contact_forces_for_load
from grasp_fc_ros.engine.pool import Cancelled
from grasp_fc_ros.interface.conversions import contact_arrays_to_packed, verdicts_to_msgs
from grasp_fc_ros.interface.names import CHECK_SERVICE, CONTACT_FORCES_SERVICE
from grasp_fc_ros.node.lane import Drained, HelperServices, LaneContext, Refusal
from grasp_fc_ros.node.marker_lane import MarkerLane
from grasp_fc_ros.node.single_queries import failure_replies
from grasp_fc_ros.packed import ContactForces


class ServiceLane:
    """Serve the node's two services from a helper node and a thread of their own.

    Parameters
    ----------
    node : Node
        The force_closure node: its name, namespace, context and remappings.
    context : LaneContext
    markers : MarkerLane
        Offered every answered check_force_closure request.
    """

    def __init__(self, node: Node, context: LaneContext, markers: MarkerLane):
        self._context = context
        self._markers = markers
        self._served = HelperServices(node, "service", context, [
            (CheckForceClosure, CHECK_SERVICE, self._on_check),
            (ComputeContactForces, CONTACT_FORCES_SERVICE, self._on_contact_forces)])

    def stopping(self) -> bool:
        return self._served.stopping

    def counts(self) -> dict[str, int]:
        return {}

    # --- check_force_closure --------------------------------------------------------------

    def _on_check(self, request: Any, response: Any) -> Any:
        try:
            response.verdicts = self.check(request.grasps)
            self._markers.offer_service(request.grasps, response.verdicts)
        except Exception as exc:  # noqa: BLE001 - the response must still be sent
            # Only reachable if even the failure verdicts cannot be built: the client
            # then gets an empty verdict list rather than no response at all.
            self._context.internal_error("a service request (empty response sent)", exc)
        return response

    def check(self, grasps: list[ContactArray]) -> list[ForceClosureVerdict]:
        """Decide a check_force_closure request and count it: one verdict per grasp, in
        order. A request of more than ``max_batch`` grasps or ``max_message_contacts``
        contacts is refused whole (INVALID_INPUT saying why) before any of it is
        converted; any failure becomes SOLVER_FAILURE, a shutdown meanwhile its
        message."""
        context = self._context
        start = context.clock()
        context.statistics.count_received(len(grasps))
        settings = context.settings()
        refusal = context.refusals.oversize(len(grasps), settings, _contacts(grasps),
                                            kind="request")
        if refusal is not None:
            return failure_replies(grasps, refusal)
        try:
            packed = contact_arrays_to_packed(grasps)
            verdicts, seconds = context.decide_interactive(packed, settings, start,
                                                           self.stopping)
            replies = verdicts_to_msgs(verdicts, grasps)
            context.statistics.record(verdicts.status, seconds, context.clock() - start)
            return replies
        except Cancelled:  # the node is shutting down: the client still gets its answer
            return failure_replies(grasps, context.refusals.shutdown(len(grasps)))
        except Exception as exc:  # noqa: BLE001
            context.internal_error(f"a service request of {len(grasps)} grasps", exc)
            context.statistics.record_failures(len(grasps))
            return failure_replies(grasps, Refusal(Status.SOLVER_FAILURE,
                                                   f"internal error: {exc}"))

    # --- compute_contact_forces -----------------------------------------------------------

    def _on_contact_forces(self, request: Any, response: Any) -> Any:
        """Decided in the service thread (one small SOCP)."""
        try:
            answer = self.contact_forces(request)
        except Exception as exc:  # noqa: BLE001 - the response must still be sent
            self._context.internal_error("a compute_contact_forces request", exc)
            answer = ContactForces.refused(f"internal error: {exc}")
        response.feasible = answer.feasible
        response.max_normal_force = answer.max_normal_force
        response.contact_forces = [Vector3(x=x, y=y, z=z)
                                   for x, y, z in answer.contact_forces.tolist()]
        response.contact_torques = answer.contact_torques.tolist()
        response.message = answer.message
        return response

    def contact_forces(self, request: Any) -> ContactForces:
        """The contact forces answering a ComputeContactForces request."""
        context = self._context
        packed = contact_arrays_to_packed([request.grasp], name_by_id=True)
        force, torque = request.wrench.force, request.wrench.torque
        wrench = (force.x, force.y, force.z, torque.x, torque.y, torque.z)
        answer = contact_forces_for_load(
            packed, wrench, np.asarray(request.max_normal_forces, dtype=np.float64),
            context.settings())
        if answer.message and context.may_log("contact forces"):
            context.logger.warning(f"compute_contact_forces: {answer.message}")
        return answer

    # --- shutdown -------------------------------------------------------------------------

    def stop(self) -> None:
        """Let the request in progress be answered (a shutdown answer if it waits for the
        workers), then stop serving."""
        self._served.stop()

    def drain(self) -> Drained:
        return Drained()  # a request is answered in its callback, never queued here


def _contacts(grasps: list[ContactArray]) -> int:
    """Contacts in a check_force_closure request (its grasps are messages already)."""
    return sum(len(grasp.contacts) for grasp in grasps)
