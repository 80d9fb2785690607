"""The robustness lane: the ``assess_robustness`` service.

Open this file to change how the service answers. It is served from a helper node of its
own, ``<name>_robustness``, by a :class:`~grasp_fc_ros.interface.wait_sets.ServiceLoop`
on a thread of its own, so that an assessment, which costs thousands of exact tests a
grasp, never holds up ``check_force_closure`` and ``compute_contact_forces`` (served by
:mod:`.services`). The work goes to the worker pool as epsilon and mu* do, in chunks of
whole grasps sized in samples (:func:`~grasp_fc_ros.engine.chunking.assessment_chunk_contacts`),
ahead of batch chunks; a small request (one grasp with 1,000 samples) is decided in this
thread. The service name is resolved by the node itself, so that its remappings apply
(as in :mod:`.services`).

Every request is answered, one entry per grasp: a request over ``max_batch`` grasps,
``max_message_contacts`` contacts or ``max_assessment_samples`` samples (grasps x
samples), or with a bad error, sigma or confidence, is refused whole (INVALID_INPUT
saying why); a bad grasp is INVALID_INPUT alone; a failure is SOLVER_FAILURE saying so.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from grasp_fc_msgs.msg import ContactArray
from grasp_fc_msgs.srv import AssessRobustness
from rclpy.node import Node

from grasp_fc_ros.core import Status
from grasp_fc_ros.engine.pool import Cancelled
from grasp_fc_ros.interface.conversions import assessment_response, contact_arrays_to_packed
from grasp_fc_ros.interface.names import ASSESS_SERVICE
from grasp_fc_ros.node.lane import Drained, HelperServices, LaneContext, Refusal
from grasp_fc_ros.packed import Assessments, RobustnessQuery, Settings, Verdicts


class RobustnessLane:
    """Serve ``assess_robustness`` from a helper node and a thread of their own.

    Parameters
    ----------
    node : Node
        The force_closure node: its name, namespace, context and remappings.
    context : LaneContext
    """

    def __init__(self, node: Node, context: LaneContext):
        self._context = context
        self._served = HelperServices(node, "robustness", context,
                                      [(AssessRobustness, ASSESS_SERVICE, self._on_assess)])

    def stopping(self) -> bool:
        return self._served.stopping

    def counts(self) -> dict[str, int]:
        return {}

    def _on_assess(self, request: Any, response: Any) -> Any:
        try:
            verdicts = self.assess(request)
        except Exception as exc:  # noqa: BLE001 - the response must still be sent
            self._context.internal_error("an assess_robustness request", exc)
            verdicts = _refused(request.grasps, Refusal(Status.SOLVER_FAILURE,
                                                        f"internal error: {exc}"))
        return assessment_response(verdicts, response)

    def assess(self, request: Any) -> Verdicts:
        """Answer an AssessRobustness request: one row per grasp, in order (see the
        module docstring for what is refused)."""
        context = self._context
        start = context.clock()
        grasps = request.grasps
        context.statistics.count_received(len(grasps))
        query = RobustnessQuery(
            position_error=request.position_error, normal_error=request.normal_error,
            friction_error=request.friction_error, position_sigma=request.position_sigma,
            normal_sigma=request.normal_sigma, friction_sigma=request.friction_sigma,
            samples=request.samples, confidence=request.confidence, seed=request.seed)
        settings = context.settings()
        refusal = self._refusal(grasps, query, settings)
        if refusal is not None:
            return _refused(grasps, refusal)
        try:
            packed = contact_arrays_to_packed(grasps)
            # (the nominal verdicts' own extras are not part of the answer)
            asked = replace(settings, robustness=query, certificates=False,
                            compute_min_friction=False, compute_epsilon=False)
            verdicts, seconds = context.decide_interactive(packed, asked, start,
                                                           self.stopping)
            context.statistics.record(verdicts.status, seconds, context.clock() - start)
            return verdicts
        except Cancelled:  # the node is shutting down: the client still gets its answer
            return _refused(grasps, context.refusals.shutdown(len(grasps)))

    def _refusal(self, grasps: list[ContactArray], query: RobustnessQuery,
                 settings: Settings) -> Refusal | None:
        """Why the whole request is refused, or None."""
        context = self._context
        refusal = context.refusals.oversize(len(grasps), settings,
                                            sum(len(grasp.contacts) for grasp in grasps),
                                            kind="request")
        if refusal is not None:
            return refusal
        problem = query.problem()
        total = len(grasps) * query.samples
        if not problem and total > settings.max_assessment_samples:
            problem = (f"{len(grasps)} grasps x {query.samples} samples = {total} samples "
                       f"exceed max_assessment_samples={settings.max_assessment_samples}: "
                       "ask for fewer samples or send the grasps in several requests")
        if not problem:
            return None
        context.statistics.record_refused(Status.INVALID_INPUT, len(grasps))
        return Refusal(Status.INVALID_INPUT, problem)

    def stop(self) -> None:
        """Let the request in progress be answered (a shutdown answer if it waits for the
        workers), then stop serving."""
        self._served.stop()

    def drain(self) -> Drained:
        return Drained()  # a request is answered in its callback, never queued here


def _refused(grasps: list[ContactArray], refusal: Refusal) -> Verdicts:
    """Every grasp answered with ``refusal``, nothing assessed."""
    verdicts = Verdicts.failed([grasp.id for grasp in grasps], refusal.status,
                               refusal.message)
    verdicts.robustness = Assessments.not_computed(
        len(grasps), sum(len(grasp.contacts) for grasp in grasps))
    return verdicts
