"""The ``force_closure`` ROS 2 node: grasp contacts in, force-closure verdicts out.

Interfaces (package ``grasp_fc_msgs``), each served by a lane of its own:

============================  =====================================  ==================
interface                     what                                   lane (module)
============================  =====================================  ==================
``contacts`` -> ``verdicts``  ContactArray in, one ForceClosure-     :mod:`.single_queries`
                              Verdict out per query
``contacts_batch`` ->         ContactArrayBatch in, one ForceClo-    :mod:`.batches`
``verdicts_batch``            sureVerdictArray out per batch
``check_force_closure``,      services (CheckForceClosure,           :mod:`.services`
``compute_contact_forces``    ComputeContactForces)
``assess_robustness``         service (AssessRobustness): radii,     :mod:`.robustness_service`
                              holds status, probability
``label_grasps``              action (LabelGrasps): a long batch     :mod:`.label_action`
                              with feedback and cancel               (goals: :mod:`.label_goal`)
``markers``,                  visualization_msgs/MarkerArray of      :mod:`.marker_lane`
``clear_markers``             answered queries (``publish_markers``)
``/diagnostics``              once a second                          :mod:`.diagnostics`
============================  =====================================  ==================

This module is the wiring: it declares the parameters (:mod:`.parameters`), makes the
worker pool that decides (:class:`~grasp_fc_ros.engine.pool.EvaluationPool`), the
verdict publishers (:mod:`.replies`), the DDS participant of the batch topic
(:mod:`.participant`) and the lanes, and on :meth:`destroy_node` walks
the lanes: stop each, close the pool, then let each answer what it still holds. Every
lane owns its queue, threads and stop flag (:mod:`.lane`); refusals (oversize,
overload, shutdown) are worded in one place, :class:`~.lane.Refusals`. Messages are
converted by :mod:`grasp_fc_ros.interface` and decided by :mod:`grasp_fc_ros.engine`:
a new contact model goes in :mod:`grasp_fc_ros.core` (and its fields through
``interface.conversions``), not here.

Flow control: the query topics are reliable and KEEP_ALL (``QUERY_QOS``), so DDS
pushes back on a publisher instead of overwriting queries the node has not taken yet;
the verdicts go out reliable with a deep history (``VERDICT_QOS``), each to its asker:
on the client's reply topic (``verdicts/c<client id>``), or on ``verdicts`` /
``verdicts_batch`` for client id 0 (:mod:`.replies`). Interactive
requests (service, single queries) are decided ahead of batch chunks, so no batch
holds them up.

Run it with ``grasp-fc-node`` or ``python -m grasp_fc_ros.node`` (``--help``).
"""

from __future__ import annotations

from typing import Any, TypeVar

from grasp_fc_msgs.msg import ForceClosureVerdict
from rclpy.node import Node

from grasp_fc_ros.core import Status, warm_up
from grasp_fc_ros.engine.pool import EvaluationPool
from grasp_fc_ros.interface import wire
from grasp_fc_ros.interface.names import NODE_NAME
from grasp_fc_ros.node.batches import BatchLane
from grasp_fc_ros.node.diagnostics import Diagnostics
from grasp_fc_ros.node.label_action import LabelAction
from grasp_fc_ros.node.lane import Lane, LaneContext, Refusals
from grasp_fc_ros.node.marker_lane import MarkerLane
from grasp_fc_ros.node.parameters import LiveParameters
from grasp_fc_ros.node.participant import BatchParticipant
from grasp_fc_ros.node.replies import Replies
from grasp_fc_ros.node.robustness_service import RobustnessLane
from grasp_fc_ros.node.services import ServiceLane
from grasp_fc_ros.node.single_queries import SingleQueryLane
from grasp_fc_ros.node.statistics import WARN_THROTTLE_S, Statistics, Throttle

LaneT = TypeVar("LaneT", bound=Lane)

# The wire status codes are the core's Status values (UNKNOWN = 0 included): checked at
# import, also under python -O.
if not all(getattr(ForceClosureVerdict, s.name) == s.value for s in Status):
    raise ImportError("grasp_fc_msgs' ForceClosureVerdict status constants differ from "
                      "grasp_fc_ros.core.Status: rebuild grasp_fc_msgs from this "
                      "checkout's msg_defs/ (make setup)")


class ForceClosureNode(Node):
    """Answers force-closure queries on topics, services and an action; see the module
    docstring.

    Parameters
    ----------
    pool : EvaluationPool, optional
        What decides the grasps (default: one with the ``workers`` parameter's number of
        worker processes, closed with the node). A test may give its own.
    **kwargs
        As for ``rclpy.node.Node`` (namespace, parameter_overrides, ...).

    Attributes
    ----------
    parameters : LiveParameters
    statistics : Statistics
    replies : Replies
    batch_participant : BatchParticipant
        The DDS participant (and helper node) of the batch topic's subscription.
    single_queries, batches, service_requests, robustness, label_action, markers
        The lanes.
    """

    def __init__(self, *, pool: EvaluationPool | None = None, **kwargs: Any):
        super().__init__(NODE_NAME, **kwargs)
        self._lanes: list[Lane] = []
        self.batch_participant: BatchParticipant | None = None
        self._own_pool = pool is None
        self.statistics = Statistics()
        self.parameters = LiveParameters(self)
        self.pool = pool if pool is not None else EvaluationPool(
            self.parameters.workers, worker_timeout_s=self.parameters.worker_timeout_s,
            log=self.get_logger().warning,
            warm_epsilon=self.parameters.settings.compute_epsilon)
        try:
            self._start_lanes()
        except BaseException:
            # E.g. Ctrl-C right after start: threads and helper nodes are running, and
            # left to the interpreter's exit they abort the process.
            self.destroy_node()
            raise

    def _start_lanes(self) -> None:
        # Compile (or load from numba's cache) the fast exact stage before any query can
        # arrive, so that none pays for it.
        warm_up()
        may_log = Throttle(WARN_THROTTLE_S)
        context = LaneContext(
            pool=self.pool, statistics=self.statistics,
            refusals=Refusals(self.statistics, self.get_logger(), may_log),
            settings=lambda: self.parameters.settings, logger=self.get_logger(),
            rclpy_context=self.context, may_log=may_log)
        # Serialized queries in, serialized verdicts and batch answers out, unless this
        # rmw's layout is not the one grasp_fc_ros.interface.wire reads and writes.
        self.replies = Replies(self, serialized=wire.layout_matches())
        # In the order they are stopped in reverse: the markers, which the others offer
        # their answers to, last.
        self.markers = self._add(MarkerLane(self, self.parameters, context.internal_error))
        self.single_queries = self._add(SingleQueryLane(
            self, context, self.replies, self.markers, serialized=self.replies.serialized))
        # The batch topic on a DDS participant of its own (see .participant).
        self.batch_participant = BatchParticipant(self)
        self.batches = self._add(BatchLane(self.batch_participant, context, self.replies,
                                           self.markers))
        self.service_requests = self._add(ServiceLane(self, context, self.markers))
        self.robustness = self._add(RobustnessLane(self, context))
        self.label_action = self._add(LabelAction(self, context, self.batch_participant))
        self.diagnostics = Diagnostics(self, self.statistics, lambda: self._lanes,
                                       context.internal_error, self._node_counts)
        self.get_logger().info(
            f"ready: topics contacts, contacts_batch; services check_force_closure, "
            f"compute_contact_forces, assess_robustness, clear_markers; action label_grasps; "
            f"settings {self.parameters.settings}; workers {self.pool.workers}")

    def _node_counts(self) -> dict[str, int]:
        """What /diagnostics reports beside the lanes' counts: the worker processes
        replaced since start (dead or hung)."""
        return {"worker_restarts": self.pool.worker_restarts}

    def _add(self, lane: LaneT) -> LaneT:
        self._lanes.append(lane)
        return lane

    @property
    def uses_wire(self) -> bool:
        """Whether queries and answers travel serialized (grasp_fc_ros.interface.wire)."""
        return self.replies.serialized

    def destroy_node(self) -> None:
        """Stop the lanes and the workers, answer what is still queued, destroy the node.

        Queued queries get SOLVER_FAILURE with
        :data:`~grasp_fc_ros.node.lane.SHUTDOWN_MESSAGE` while rclpy's context is up
        (grasp-fc-node after Ctrl-C or SIGTERM, which it handles itself; the demo, tests,
        an embedding program); so do the queries being decided (their work is
        abandoned, so that the node stops within a fraction of a second). If the
        context is already shut down (rclpy's own signal handler in an embedding
        program), nothing can be published any more: the log says how many queries stay
        unanswered.
        """
        lanes, self._lanes = self._lanes, []
        for lane in reversed(lanes):
            lane.stop()
        if self._own_pool:
            self.pool.close()
        answered = unanswered = 0
        for lane in lanes:
            drained = lane.drain()
            answered += drained.answered
            unanswered += drained.unanswered
        if answered:
            # Publishing only queues the answers: let DDS deliver them before the
            # process can exit, for a bounded time.
            try:
                self.replies.wait_for_acks()
            except Exception as exc:  # noqa: BLE001 - shutdown must go on
                self.get_logger().warning(f"cannot wait for readers at shutdown: {exc}")
        if unanswered:
            self.get_logger().warning(
                f"{unanswered} {'query' if unanswered == 1 else 'queries'} left unanswered "
                "at shutdown")
        if self.batch_participant is not None:
            self.batch_participant.close()
        super().destroy_node()
