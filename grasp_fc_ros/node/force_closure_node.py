"""The ``force_closure`` ROS 2 node: grasp contacts in, force-closure verdicts out.

Interfaces (package ``grasp_fc_msgs``):

- subscribes ``contacts`` (ContactArray), publishes one ForceClosureVerdict per
  query on ``verdicts``;
- subscribes ``contacts_batch`` (ContactArrayBatch), publishes one
  ForceClosureVerdictArray per batch on ``verdicts_batch``;
- serves ``check_force_closure`` (CheckForceClosure) and ``compute_contact_forces``
  (ComputeContactForces);
- serves the action ``label_grasps`` (LabelGrasps): a long batch with progress feedback
  and cancel (:meth:`ForceClosureNode._start_action`);
- publishes ``/diagnostics`` (diagnostic_msgs/DiagnosticArray) once a second;
- with ``publish_markers``, has visualization_msgs/MarkerArray published on ``markers``
  for answered queries (off the verdict path, by a process of its own:
  :mod:`grasp_fc_ros.markers.publisher`); serves ``clear_markers`` (std_srvs/Empty:
  DELETEALL).

The node is wiring only: messages are converted by :mod:`grasp_fc_ros.interface.conversions`
and decided by :mod:`grasp_fc_ros.engine.evaluation`, large ones in worker processes
(:mod:`grasp_fc_ros.engine.pool`).

Flow control: the query topics are reliable and KEEP_ALL (:data:`QUERY_QOS`), so DDS
pushes back on a publisher instead of overwriting queries the node has not taken yet;
the verdicts go out reliable with a deep history (:data:`VERDICT_QOS`).
Callbacks only queue: single-grasp queries wait for the ``single_queries`` thread (at
most ``max_batch`` of them; more are answered at once with SOLVER_FAILURE "node
overloaded"), batches for the ``next_batch`` thread, which queues the chunks of up to
:data:`BATCHES_IN_PROGRESS` batches for the workers while ``answer_batch`` answers them
in order; the services have a thread of their own
(see :meth:`ForceClosureNode._start_service`). All three decide
through :class:`~grasp_fc_ros.engine.pool.EvaluationPool`: tiny requests at once, larger ones
in chunks on the worker processes, interactive ones (service, single queries) ahead of
batch chunks. So no batch holds up the service, single queries or diagnostics.

Run it with ``grasp-fc-node`` or ``python -m grasp_fc_ros.node`` (``--help``).
"""

from __future__ import annotations

import copy
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import Vector3
from grasp_fc_msgs.action import LabelGrasps
from grasp_fc_msgs.msg import (
    ContactArray,
    ContactArrayBatch,
    ForceClosureVerdict,
    ForceClosureVerdictArray,
)
from grasp_fc_msgs.srv import CheckForceClosure, ComputeContactForces
from rcl_interfaces.msg import SetParametersResult
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.serialization import deserialize_message
from rclpy.task import Future as RclpyFuture
from std_srvs.srv import Empty

from grasp_fc_ros.core import Status, warm_up
from grasp_fc_ros.engine.contact_forces import ContactForces, contact_forces_for_load
from grasp_fc_ros.engine.packed import PackedGrasps, Settings, Verdicts
from grasp_fc_ros.engine.long_jobs import Progress, decide_in_chunks
from grasp_fc_ros.engine.pool import PRIORITY_BATCH, PRIORITY_INTERACTIVE, Cancelled, Decision, EvaluationPool
from grasp_fc_ros.interface import wire
from grasp_fc_ros.interface.conversions import (
    MalformedBatch,
    batch_size,
    batch_to_packed,
    contact_arrays_to_packed,
    verdicts_to_array_msg,
    verdicts_to_msgs,
)
from grasp_fc_ros.interface.message_slots import nan_wrench
from grasp_fc_ros.interface.names import NODE_NAME, QUERY_QOS, VERDICT_QOS
from grasp_fc_ros.interface.wait_sets import ServiceLoop, SubscriptionLoop
from grasp_fc_ros.markers.publisher import MarkerProcess, MarkerPublisher, MarkerSettings
from grasp_fc_ros.node.parameters import (
    MARKER_SETTINGS,
    PARAMETERS,
    QOS_OVERRIDES_PREFIX,
    SETTING_NAMES,
    check_parameter,
)
from grasp_fc_ros.node.statistics import Statistics, Throttle, WARN_THROTTLE_S

DIAGNOSTICS_PERIOD_S = 1.0
# How long shutdown waits for readers to acknowledge the answers it publishes (s).
SHUTDOWN_ACK_TIMEOUT_S = 0.5
# label_grasps goals decided side by side (their chunks share the workers); more wait.
ACTION_THREADS = 4
# How long the action server keeps an ended goal, its request (the whole batch) and
# result for late result requests (s). rclpy's default, 15 minutes, would hold ~60 MB per
# 100,000-grasp goal that long; clients ask for the result as soon as a goal is
# accepted (GraspClient does), so they get it when the goal ends.
ACTION_RESULT_TIMEOUT_S = 30
# At shutdown, how long the goals ended then may take to have their result responses
# sent (s): the action's executor sends each one when the goal's client has asked for it
# (GraspClient asks at acceptance), so this is only waited out in full for a client that
# never asks.
ACTION_RESULT_SEND_TIMEOUT_S = 2.0
# After the last of those responses was sent, time for DDS to deliver it before the
# process goes (s): rclpy has no acknowledgement to wait for on a service response. A fixed
# 0.05 s and then 0.5 s after the goals ended (not after the send) each lost an aborted
# goal's result once in a clean-clone CI run.
ACTION_RESULT_DELIVERY_S = 0.25
# Single-grasp queries taken per wake-up of the contacts loop at most (whatever the
# subscription holds): one wake-up costs about as much as deciding a query. A client
# keeps at most 2,000 in flight.
MAX_TAKE = 2_000
# Batches whose chunks may be queued for the workers at once. With one, the workers
# idled while a decided batch was answered and the next one converted and chunked:
# batches of 1,000 went at 0.94-0.99x the core alone, 1.11-1.20x with two
# (benchmarks/bench_ros.py: one client, two batches in flight; alternating runs).
BATCHES_IN_PROGRESS = 2
# Verdict message of queries still queued when the node is destroyed.
SHUTDOWN_MESSAGE = "node shutting down: query not evaluated"
# A plain integer: comparing an array with an IntEnum member costs microseconds a call.
_INVALID_INPUT = int(Status.INVALID_INPUT)

# The wire status codes are the core's Status values.
assert all(getattr(ForceClosureVerdict, s.name) == s.value for s in Status)


def _failure_replies(queries, status: Status, message: str) -> list[ForceClosureVerdict]:
    """Verdict messages of ``status`` for ContactArray ``queries``, without the core."""
    return [ForceClosureVerdict(header=q.header, client_id=q.client_id, id=q.id,
                                force_closure=False, status=int(status), margin=math.nan,
                                message=message, separating_wrench=nan_wrench(),
                                min_friction=math.nan) for q in queries]


def _batch_failure(msg: ContactArrayBatch, status: Status, message: str
                   ) -> ForceClosureVerdictArray:
    """A verdict array answering every grasp of batch ``msg`` with ``status``."""
    return verdicts_to_array_msg(_failed_batch(msg, status, message), msg)


def _failed_batch(msg: ContactArrayBatch, status: Status, message: str) -> Verdicts:
    ids = np.frombuffer(msg.ids, np.uint64) if len(msg.ids) else np.empty(0, np.uint64)
    return Verdicts.failed(ids, status, message)


def _batch_answer(verdicts: Verdicts, msg: ContactArrayBatch, serialized: bool
                  ) -> ForceClosureVerdictArray | bytes:
    """The verdict array answering batch ``msg``: serialized by :mod:`grasp_fc_ros.interface.wire`
    (rclpy spends ~10x longer converting a large one, holding the GIL) or a message."""
    if serialized:
        return wire.encode_verdict_array(msg.header, msg.client_id, msg.request_id, verdicts)
    return verdicts_to_array_msg(verdicts, msg)


@dataclass
class _BatchInProgress:
    """A batch taken from the queue: its chunks on the workers, or its failed verdicts.

    ``start`` is when it was taken (time.perf_counter(), s), ``conversion_s`` the time
    its conversion took.
    """

    msg: ContactArrayBatch
    start: float
    conversion_s: float
    decision: Decision | None = None
    failed: Verdicts | None = None


class _Goal:
    """One accepted label_grasps goal: its handle, its cancel flag and its end.

    ``finished`` is awaited by the goal's execute coroutine on the action's executor;
    whoever ends the goal (a goal thread, the cancel callback, shutdown) sets it.
    """

    def __init__(self, handle):
        self.handle = handle
        self.cancel = threading.Event()
        self.finished = RclpyFuture()
        self.aborted = False


class _ResultReportingActionServer(ActionServer):
    """An ActionServer that reports each result response it has sent.

    Shutdown waits for the results of the goals it ends to have been sent. rclpy offers
    no public hook for that; ``_send_result_response`` is the method (rclpy 7, Jazzy)
    that sends one, and its response holds the very Result object the execute callback
    returned.
    """

    def __init__(self, *args, on_result_sent, **kwargs):
        super().__init__(*args, **kwargs)
        self._on_result_sent = on_result_sent

    def _send_result_response(self, request_header, future):
        super()._send_result_response(request_header, future)
        self._on_result_sent(future.result().result)


class ForceClosureNode(Node):
    """Answers force-closure queries on topics and a service; see the module docstring."""

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        self._stats = Statistics()
        self._may_log = Throttle(WARN_THROTTLE_S)
        self._lock = threading.RLock()
        # One condition per kind of waiting thread, all on that lock: a notify wakes the
        # thread that has work. With one condition for all, each batch's three
        # notify_all calls woke all seven waiting threads (~20 wake-ups per batch).
        self._goal_queued = threading.Condition(self._lock)
        self._single_queued = threading.Condition(self._lock)
        self._batch_startable = threading.Condition(self._lock)
        self._batch_started = threading.Condition(self._lock)
        # Single-grasp topic queries and batches waiting for their threads, oldest first.
        self._pending: deque[ContactArray] = deque()
        self._batches: deque[ContactArrayBatch] = deque()
        # Batches taken from the queue whose chunks are on the workers, oldest first:
        # answered in this order.
        self._in_progress: deque[_BatchInProgress] = deque()
        self._queued_batch_grasps = 0
        self._busy_batch_grasps = 0
        self._stopping = False
        # label_grasps goals waiting for a goal thread, oldest first; every goal not yet
        # ended, by goal id; goals being decided.
        self._goals: deque[_Goal] = deque()
        self._goal_records: dict[bytes, _Goal] = {}
        # Results of goals ended at shutdown, by id, until sent; when the last was sent.
        self._unsent_results: dict[int, LabelGrasps.Result] = {}
        self._last_result_sent: float | None = None
        self._running_goals = 0
        self._action_thread = None
        self._duplicate_warned = False
        self._settings = Settings(**{name: PARAMETERS[name][0] for name in SETTING_NAMES})
        self._marker_settings = MarkerSettings()
        self._markers: MarkerPublisher | None = None
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._after_set_parameters)
        self.add_post_set_parameters_callback(self._after_set_marker_parameters)
        for name, (default, descriptor) in PARAMETERS.items():
            self.declare_parameter(name, default, descriptor)
        self._warn_unknown_overrides()
        self._pool = EvaluationPool(self.get_parameter("workers").value)
        self._threads: list[threading.Thread] = []
        self._service_loop = None
        self._contacts_loop = None
        try:
            self._start_interfaces()
        except BaseException:
            # E.g. Ctrl-C right after start: threads and the service node are running,
            # and left to the interpreter's exit they abort the process.
            self.destroy_node()
            raise

    def _start_interfaces(self):
        # Compile (or load from numba's cache) the fast exact stage before any query can
        # arrive, so that none pays for it.
        warm_up()
        # Users may set history, depth and reliability of the query and verdict topics
        # from parameters (qos_overrides.<topic>.<publisher|subscription>.<policy>).
        # rclpy writes the overrides into the profile it is given: give it copies, or
        # one topic's override would change the module's profiles for every later one.
        overridable = QoSOverridingOptions.with_default_policies()
        self._verdict_pub = self.create_publisher(ForceClosureVerdict, "verdicts",
                                                  copy.copy(VERDICT_QOS),
                                                  qos_overriding_options=overridable)
        self._batch_pub = self.create_publisher(ForceClosureVerdictArray, "verdicts_batch",
                                                copy.copy(VERDICT_QOS),
                                                qos_overriding_options=overridable)
        self._diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        # Serialized single queries in, serialized verdicts and batch answers out
        # (grasp_fc_ros.interface.wire), unless this rmw's layout is not the one wire reads.
        self._use_wire = wire.layout_matches()
        # Single queries come in many at a time: taken by a loop of their own, every
        # query the subscription holds at each wake-up (see SubscriptionLoop).
        self._contacts_loop = SubscriptionLoop(
            self, ContactArray, "contacts", copy.copy(QUERY_QOS), self._on_contacts,
            lambda exc: self._internal_error("single-grasp queries", exc),
            raw=self._use_wire, max_take=MAX_TAKE, name="contacts",
            qos_overriding_options=overridable)
        # Batches come in serialized too, read with numpy (wire.decode_contact_array_batch):
        # a subscriber took 3.1-3.6 ms of CPU per 10,000-grasp batch so, 8.0 ms taking
        # rclpy's message (measured).
        self.create_subscription(ContactArrayBatch, "contacts_batch",
                                 self._on_raw_batch if self._use_wire else self._on_batch,
                                 copy.copy(QUERY_QOS), raw=self._use_wire,
                                 qos_overriding_options=overridable)
        # Markers are built and published by a process of its own, started when
        # publish_markers turns on (see grasp_fc_ros.markers.publisher).
        self._markers = MarkerPublisher(
            MarkerProcess(self.get_namespace(), f"{self.get_name()}_markers"),
            self._internal_error)
        if self._marker_settings.enabled:
            self._markers.start()
        self.create_service(Empty, "clear_markers", self._on_clear_markers)
        self.create_timer(DIAGNOSTICS_PERIOD_S, self._on_timer)
        self._start_service()
        self._start_action()
        for work in (self._single_queries, self._next_batch, self._answer_batch):
            thread = threading.Thread(target=self._loop, args=(work,), daemon=True,
                                      name=work.__name__)
            thread.start()
            self._threads.append(thread)
        self.get_logger().info(
            f"ready: topics contacts, contacts_batch; services check_force_closure, "
            f"compute_contact_forces; "
            f"action label_grasps; "
            f"settings {self._settings}; workers {self._pool.workers}")

    def _start_service(self):
        """Serve check_force_closure from a helper node on a thread of its own.

        A large request waits for the workers in its callback; on the node's own
        executor that would hold up the topic queries and /diagnostics. Nor does the node
        need a multi-threaded executor then (measured: ~3.5x the CPU per single query of
        a single-threaded one). The helper's services are served by a
        :class:`~grasp_fc_ros.interface.wait_sets.ServiceLoop`, not an executor (less time per
        request, see there). The helper, ``<name>_service``, lives in the node's
        (possibly remapped) namespace and takes no command-line arguments of its own (a
        ``__node`` remapping would give it the node's own name); the service name is
        resolved by the node itself instead, so that the node's remappings (``-r
        check_force_closure:=...``, also ``force_closure:check_force_closure:=...``,
        and ``__ns``) apply to it as to the topics. It serves one request at a time (a
        multi-threaded executor here crashed the process (SIGSEGV) now and then on a
        Ctrl-C right after start).
        """
        self._service_node = Node(f"{self.get_name()}_service", namespace=self.get_namespace(),
                                  context=self.context, use_global_arguments=False,
                                  start_parameter_services=False)
        services = [
            self._service_node.create_service(
                CheckForceClosure, self.resolve_service_name("check_force_closure"),
                self._on_service),
            self._service_node.create_service(
                ComputeContactForces, self.resolve_service_name("compute_contact_forces"),
                self._on_contact_forces)]
        self._service_loop = ServiceLoop(
            services, self.context,
            lambda service, exc: self._internal_error(
                f"a {service.srv_name} request (no response sent)", exc))

    # --- the label_grasps action ------------------------------------------------------

    def _start_action(self):
        """Serve label_grasps from a helper node with an executor of its own.

        As for the service (:meth:`_start_service`): the helper, ``<name>_action`` in
        the node's namespace, keeps goal, cancel and result requests off the node's
        executor. Its callbacks only queue or flag: each goal's execute coroutine waits
        (without blocking the executor) for :data:`ACTION_THREADS` goal threads, which
        decide goals in chunks on the workers and publish their feedback; so a running
        goal does not hold up cancel requests, other goals or the other interfaces.
        """
        self._action_node = Node(f"{self.get_name()}_action", namespace=self.get_namespace(),
                                 context=self.context, use_global_arguments=False,
                                 start_parameter_services=False)
        self._action_server = _ResultReportingActionServer(
            self._action_node, LabelGrasps, "label_grasps", self._execute_goal,
            goal_callback=self._on_goal, cancel_callback=self._on_cancel,
            result_timeout=ACTION_RESULT_TIMEOUT_S, on_result_sent=self._on_result_sent)
        self._action_executor = SingleThreadedExecutor(context=self.context)
        self._action_executor.add_node(self._action_node)
        self._action_thread = threading.Thread(target=self._spin_action, daemon=True,
                                               name="action")
        self._action_thread.start()
        for index in range(ACTION_THREADS):
            thread = threading.Thread(target=self._loop, args=(self._next_goal,), daemon=True,
                                      name=f"goal_{index}")
            thread.start()
            self._threads.append(thread)

    def _spin_action(self):
        try:
            self._action_executor.spin()
        except Exception:  # noqa: BLE001 - rclpy shut down while spinning: end quietly
            pass

    def _on_goal(self, _request) -> GoalResponse:
        if self._stopping:
            return GoalResponse.REJECT
        self._stats.count_goal("received")
        return GoalResponse.ACCEPT

    def _on_cancel(self, goal_handle) -> CancelResponse:
        """Accept every cancel: a queued goal ends at once, a running one at its next poll."""
        with self._lock:
            goal = self._goal_records.get(bytes(goal_handle.goal_id.uuid))
            queued = goal is not None and goal in self._goals
            if queued:
                self._goals.remove(goal)
        if goal is not None:
            goal.cancel.set()
            if queued:
                self._end_goal(goal, self._empty_goal_reply(goal), aborted=False)
        return CancelResponse.ACCEPT

    async def _execute_goal(self, goal_handle) -> LabelGrasps.Result:
        """Queue the goal for a goal thread and await its end (on the action's executor)."""
        goal = _Goal(goal_handle)
        key = bytes(goal_handle.goal_id.uuid)
        with self._lock:
            self._goal_records[key] = goal
            queue_it = not self._stopping and not goal_handle.is_cancel_requested
            if queue_it:
                self._goals.append(goal)
                self._goal_queued.notify()
        if not queue_it:  # canceled before it was queued, or the node is stopping
            self._end_goal(goal, self._empty_goal_reply(goal), aborted=self._stopping)
        try:
            result = await goal.finished
            # The cancel callback and this coroutine both run on the action's executor,
            # so a cancel accepted before this point has already made the goal CANCELING.
            if goal_handle.is_cancel_requested:
                goal_handle.canceled()
                self._stats.count_goal("canceled")
            elif goal.aborted:
                goal_handle.abort()
                self._stats.count_goal("aborted")
            else:
                goal_handle.succeed()
                self._stats.count_goal("succeeded")
            return result
        finally:
            with self._lock:
                del self._goal_records[key]

    def _end_goal(self, goal: _Goal, reply: ForceClosureVerdictArray, aborted: bool):
        """Hand a goal's verdicts to its execute coroutine (from any thread)."""
        goal.aborted = aborted
        result = LabelGrasps.Result(verdicts=reply)
        with self._lock:
            if self._stopping:  # shutdown waits until this result has been sent
                self._unsent_results[id(result)] = result
        goal.finished.set_result(result)
        # The executor resumes waiting coroutines when it wakes up: wake it now.
        try:
            self._action_executor.wake()
        except Exception:  # noqa: BLE001 - rclpy shut down: no result can be sent anyway
            pass

    def _on_result_sent(self, result: LabelGrasps.Result):
        with self._lock:
            if self._unsent_results.pop(id(result), None) is not None:
                self._last_result_sent = time.monotonic()

    def _empty_goal_reply(self, goal: _Goal) -> ForceClosureVerdictArray:
        """The answer of a goal ended before any grasp was decided: no verdicts."""
        msg = goal.handle.request.grasps
        return verdicts_to_array_msg(
            Verdicts.failed(np.empty(0, np.uint64), Status.INVALID_INPUT, ""), msg)

    def _next_goal(self):
        """Decide the oldest queued goal in chunks and end it."""
        with self._lock:
            self._goal_queued.wait_for(lambda: self._goals or self._stopping)
            if self._stopping:
                return
            goal = self._goals.popleft()
            self._running_goals += 1
        try:
            reply, complete = self._goal_reply(goal)
        finally:
            with self._lock:
                self._running_goals -= 1
        self._end_goal(goal, reply, aborted=not complete and not goal.cancel.is_set())

    def _goal_reply(self, goal: _Goal) -> tuple[ForceClosureVerdictArray, bool]:
        """Decide a goal and count it: (verdicts of all or a prefix, complete).

        Answered as the batch topic answers (invalid and oversized goals get
        INVALID_INPUT verdicts); stopped by a cancel or the node's shutdown.
        """
        msg = goal.handle.request.grasps
        start = time.perf_counter()
        n_grasps = batch_size(msg)
        self._stats.count_received(n_grasps)
        settings = self._settings
        if n_grasps > settings.max_batch:
            self._stats.record(np.full(n_grasps, Status.INVALID_INPUT, np.uint8), {}, None)
            return _batch_failure(msg, Status.INVALID_INPUT,
                                  f"{n_grasps} grasps exceed max_batch={settings.max_batch}"), True
        try:
            packed = batch_to_packed(msg)
            conversion_s = time.perf_counter() - start
            outcome = decide_in_chunks(
                self._pool, packed, settings,
                stop=lambda: goal.cancel.is_set() or self._stopping,
                report=lambda progress: self._goal_feedback(goal, progress))
            outcome.seconds["conversion_s"] = conversion_s
            self._warn_invalid(outcome.verdicts)
            reply = verdicts_to_array_msg(outcome.verdicts, msg)
            self._stats.record(outcome.verdicts.status, outcome.seconds,
                               time.perf_counter() - start)
            self._stats.count_undecided(n_grasps - len(outcome.verdicts))
            return reply, outcome.complete
        except MalformedBatch as exc:
            if self._may_log("malformed"):
                self.get_logger().warning(f"label_grasps goal: {exc}")
            self._stats.record(np.full(n_grasps, Status.INVALID_INPUT, np.uint8), {}, None)
            return _batch_failure(msg, Status.INVALID_INPUT, str(exc)), True
        except Exception as exc:  # noqa: BLE001 - the goal must still be answered
            self._internal_error(f"a label_grasps goal of {n_grasps} grasps", exc)
            self._stats.record_failures(n_grasps)
            return _batch_failure(msg, Status.SOLVER_FAILURE, f"internal error: {exc}"), True

    def _goal_feedback(self, goal: _Goal, progress: Progress):
        counts = progress.counts.tolist()
        try:
            goal.handle.publish_feedback(LabelGrasps.Feedback(
                done=progress.done, total=progress.total,
                grasps_per_second=float(progress.grasps_per_second),
                force_closure=counts[Status.FORCE_CLOSURE],
                not_force_closure=counts[Status.NOT_FORCE_CLOSURE],
                filtered_out=counts[Status.FILTERED_OUT],
                invalid_input=counts[Status.INVALID_INPUT],
                solver_failure=counts[Status.SOLVER_FAILURE]))
        except Exception as exc:  # noqa: BLE001 - a lost feedback must not fail the goal
            self._internal_error("label_grasps feedback", exc)

    def _stop_action(self):
        """End the queued goals (aborted, no verdicts), let the results go, stop serving.

        Runs after the goal threads have ended theirs (aborted with their prefix). Waits,
        for a bounded time, until the results of the goals ended at shutdown have been
        sent, then a moment for DDS to deliver them.
        """
        if self._action_thread is None:
            return
        with self._lock:
            queued, self._goals = list(self._goals), deque()
        for goal in queued:
            self._end_goal(goal, self._empty_goal_reply(goal), aborted=True)
        deadline = time.monotonic() + ACTION_RESULT_SEND_TIMEOUT_S
        while ((self._goal_records or self._unsent_results)
               and time.monotonic() < deadline):
            time.sleep(0.01)
        if self._goal_records or self._unsent_results:
            self.get_logger().warning(
                f"label_grasps at shutdown: {len(self._goal_records)} goals not ended, "
                f"{len(self._unsent_results)} results not sent (not asked for?)")
        if self._last_result_sent is not None:
            time.sleep(max(0.0, self._last_result_sent + ACTION_RESULT_DELIVERY_S
                           - time.monotonic()))
        self._action_executor.shutdown()
        self._action_thread.join()
        self._action_server.destroy()
        self._action_node.destroy_node()

    # --- parameters -------------------------------------------------------------------

    def _on_set_parameters(self, parameters) -> SetParametersResult:
        reasons = [check_parameter(p.name, p.value) for p in parameters]
        reasons = [r for r in reasons if r]
        return SetParametersResult(successful=not reasons, reason="; ".join(reasons))

    def _after_set_parameters(self, parameters):
        # Cached so the hot path does not look parameters up per message; replaced whole,
        # so that a reader sees either the old or the new settings.
        changes = {p.name: p.value for p in parameters if p.name in SETTING_NAMES}
        if changes:
            self._settings = replace(self._settings, **changes)

    def _after_set_marker_parameters(self, parameters):
        changes = {MARKER_SETTINGS[p.name]: p.value for p in parameters
                   if p.name in MARKER_SETTINGS}
        if changes:
            self._marker_settings = replace(self._marker_settings, **changes)
            if self._marker_settings.enabled and self._markers is not None:
                try:
                    self._markers.start()
                except Exception as exc:  # noqa: BLE001 - the parameter stays set
                    self._internal_error("markers (marker process not started)", exc)

    def _offer_markers(self, offer, queries, replies):
        """Queue the markers of an answered message; a failure here is only logged (its
        verdicts are out and counted already)."""
        try:
            offer(queries, replies, self._marker_settings, self._settings.friction_coefficient)
        except Exception as exc:  # noqa: BLE001
            self._internal_error("markers", exc)

    def _on_clear_markers(self, request, response):
        """std_srvs/Empty: publish a DELETEALL on ``markers`` (queued marker work goes)."""
        if self._markers is not None:
            self._markers.clear()
        return response

    def _warn_unknown_overrides(self):
        """Warn about parameter values given for this node that match no parameter.

        rclpy drops them silently; a typo (``frction_coefficient``) would go unnoticed.
        rclpy keeps the overrides in a private attribute: read it defensively.
        """
        overrides = getattr(self, "_parameter_overrides", {}) or {}
        unknown = sorted(name for name in set(overrides) - set(PARAMETERS) - {"use_sim_time"}
                         if not name.startswith(QOS_OVERRIDES_PREFIX))
        if unknown:
            self.get_logger().warning(
                f"ignoring unknown parameter(s) {', '.join(unknown)}; this node has "
                f"{', '.join(PARAMETERS)}")

    # --- callbacks: they only queue, and nothing may escape them ----------------------

    def _on_contacts(self, queries: list):
        """Queue single-grasp queries (serialized, or messages without wire), oldest
        first; those beyond ``max_batch`` pending are answered at once."""
        self._stats.count_received(len(queries))
        with self._lock:
            pending = len(self._pending)
            room = 0 if self._stopping else max(0, self._settings.max_batch - pending)
            self._pending.extend(queries[:room])
            pending = len(self._pending)
            if room:
                self._single_queued.notify()
        for refused in queries[room:]:
            if isinstance(refused, bytes):
                refused = deserialize_message(refused, ContactArray)
            self._refuse_single(refused, pending)

    def _overloaded(self, what: str, n_queries: int) -> str:
        message = f"node overloaded: {what}"
        self._stats.count_overloaded(n_queries)
        if self._may_log("overloaded"):
            self.get_logger().warning(f"{message}; refusing {n_queries} queries (max_batch)")
        return message

    def _refuse_single(self, msg: ContactArray, pending: int):
        """Answer a query that cannot be queued (never drop it silently)."""
        message = (SHUTDOWN_MESSAGE if self._stopping
                   else self._overloaded(f"{pending} single-grasp queries pending", 1))
        self._stats.record_failures(1)
        self._verdict_pub.publish(_failure_replies([msg], Status.SOLVER_FAILURE, message)[0])

    def _on_raw_batch(self, raw: bytes):
        """A serialized batch: read with numpy, or by rclpy if in another layout."""
        try:
            try:
                msg = wire.decode_contact_array_batch(raw)
            except ValueError:
                msg = deserialize_message(raw, ContactArrayBatch)
        except Exception as exc:  # noqa: BLE001 - unreadable: nobody to answer
            self._internal_error("an unreadable batch (no reply sent)", exc)
            return
        self._on_batch(msg)

    def _on_batch(self, msg: ContactArrayBatch):
        try:
            n_grasps = batch_size(msg)
            self._stats.count_received(n_grasps)
            settings = self._settings
            if n_grasps > settings.max_batch:
                # Refused before conversion: its size alone settles it.
                self._stats.record(np.full(n_grasps, Status.INVALID_INPUT, np.uint8), {}, None)
                self._batch_pub.publish(_batch_failure(
                    msg, Status.INVALID_INPUT,
                    f"{n_grasps} grasps exceed max_batch={settings.max_batch}"))
                return
            with self._lock:
                queued = self._queued_batch_grasps
                accepted = not self._stopping and not (
                    queued and queued + n_grasps > settings.max_batch)
                if accepted:
                    self._batches.append(msg)
                    self._queued_batch_grasps += n_grasps
                    self._batch_startable.notify()
            if not accepted:
                message = (SHUTDOWN_MESSAGE if self._stopping else self._overloaded(
                    f"{queued} batch grasps pending", n_grasps))
                self._stats.record_failures(n_grasps)
                self._batch_pub.publish(_batch_failure(msg, Status.SOLVER_FAILURE, message))
        except Exception as exc:  # noqa: BLE001
            self._internal_error("a batch (no reply sent)", exc)

    def _on_service(self, request, response):
        try:
            response.verdicts = self._service_reply(request.grasps)
            if self._marker_settings.enabled:
                self._offer_markers(self._markers.offer_service, request.grasps,
                                    response.verdicts)
        except Exception as exc:  # noqa: BLE001 - the response must still be sent
            # Only reachable if even the failure verdicts cannot be built: the client
            # then gets an empty verdict list rather than no response at all.
            self._internal_error("a service request (empty response sent)", exc)
        return response

    def _service_reply(self, grasps) -> list[ForceClosureVerdict]:
        """Decide a service request and count it; any failure becomes SOLVER_FAILURE."""
        start = time.perf_counter()
        self._stats.count_received(len(grasps))
        settings = self._settings
        if len(grasps) > settings.max_batch:
            self._stats.record(np.full(len(grasps), Status.INVALID_INPUT, np.uint8), {}, None)
            return _failure_replies(grasps, Status.INVALID_INPUT,
                                    f"{len(grasps)} grasps exceed max_batch={settings.max_batch}")
        try:
            packed = contact_arrays_to_packed(grasps)
            verdicts, seconds = self._decide_interactive(packed, settings, start)
            replies = verdicts_to_msgs(verdicts, grasps)
            self._stats.record(verdicts.status, seconds, time.perf_counter() - start)
            return replies
        except Cancelled:  # the node is shutting down: the client still gets its answer
            self._stats.record_failures(len(grasps))
            return _failure_replies(grasps, Status.SOLVER_FAILURE, SHUTDOWN_MESSAGE)
        except Exception as exc:  # noqa: BLE001
            self._internal_error(f"a service request of {len(grasps)} grasps", exc)
            self._stats.record_failures(len(grasps))
            return _failure_replies(grasps, Status.SOLVER_FAILURE, f"internal error: {exc}")

    def _on_contact_forces(self, request, response):
        """compute_contact_forces: decided in the service thread (one small SOCP)."""
        try:
            answer = self._contact_forces_reply(request)
        except Exception as exc:  # noqa: BLE001 - the response must still be sent
            self._internal_error("a compute_contact_forces request", exc)
            answer = ContactForces.refused(f"internal error: {exc}")
        response.feasible = answer.feasible
        response.max_normal_force = answer.max_normal_force
        response.contact_forces = [Vector3(x=x, y=y, z=z)
                                   for x, y, z in answer.contact_forces.tolist()]
        response.contact_torques = answer.contact_torques.tolist()
        response.message = answer.message
        return response

    def _contact_forces_reply(self, request) -> ContactForces:
        packed = contact_arrays_to_packed([request.grasp], name_by_id=True)
        force, torque = request.wrench.force, request.wrench.torque
        wrench = (force.x, force.y, force.z, torque.x, torque.y, torque.z)
        answer = contact_forces_for_load(packed, wrench, np.asarray(request.max_normal_forces,
                                                                    dtype=np.float64),
                                         self._settings)
        if answer.message and self._may_log("contact forces"):
            self.get_logger().warning(f"compute_contact_forces: {answer.message}")
        return answer

    def _on_timer(self):
        self._publish_diagnostics()
        self._check_duplicate_name()

    def _internal_error(self, what: str, exc: Exception):
        self._stats.count_error()
        if self._may_log("internal error"):
            self.get_logger().error(f"internal error while answering {what}: {exc!r}")

    # --- the threads that decide ------------------------------------------------------

    def _loop(self, work):
        """Run ``work()`` until the node is destroyed or rclpy shuts down."""
        while not self._stopping:
            try:
                work()
            except Cancelled:
                return
            except Exception as exc:  # noqa: BLE001 - one failed pass must not end the loop
                if not rclpy.ok(context=self.context):
                    return  # publishing after shutdown: nobody can be answered any more
                self._internal_error(f"{work.__name__} (thread continues)", exc)

    def _single_queries(self):
        """Decide the queued single-grasp queries together, in arrival order."""
        with self._lock:
            self._single_queued.wait_for(lambda: self._pending or self._stopping)
            if self._stopping:
                return
            take = min(len(self._pending), self._settings.max_batch)
            msgs = [self._pending.popleft() for _ in range(take)]
        self._answer_single_queries(msgs)

    def _answer_single_queries(self, msgs: list[ContactArray]):
        """Decide ``msgs`` together; publish one verdict each, in order."""
        if msgs and isinstance(msgs[0], bytes):
            self._answer_raw_queries(msgs)
            return
        self._publish_single_verdicts(
            msgs, time.perf_counter(),
            pack=lambda: contact_arrays_to_packed(msgs, name_by_id=True),
            encode=lambda verdicts: verdicts_to_msgs(verdicts, msgs),
            encode_failures=lambda first, message: _failure_replies(
                msgs[first:], Status.SOLVER_FAILURE, message),
            offer=lambda replies, _: self._offer_markers(self._markers.offer_singles,
                                                         msgs, replies))

    def _publish_single_verdicts(self, queries: list, start: float,
                                 pack: Callable[[], PackedGrasps],
                                 encode: Callable[[Verdicts], Sequence],
                                 encode_failures: Callable[[int, str], Sequence],
                                 offer: Callable[[Sequence, Verdicts], None]):
        """Decide single-grasp ``queries`` (messages or bytes) and publish their verdicts.

        ``pack()`` converts them, ``encode(verdicts)`` makes the replies and
        ``encode_failures(first, message)`` the SOLVER_FAILURE replies of
        ``queries[first:]``; ``offer(replies, verdicts)`` queues their markers. If
        anything fails, the queries not answered yet get a failure verdict (none a second
        one); if the node is being destroyed, they go back to the queue for
        :meth:`destroy_node` to answer.
        """
        published = 0
        verdicts = None
        try:
            verdicts, seconds = self._decide_interactive(pack(), self._settings, start)
            replies = encode(verdicts)
            for reply in replies:
                self._verdict_pub.publish(reply)
                published += 1
            self._stats.record(verdicts.status, seconds, time.perf_counter() - start)
            if self._marker_settings.enabled:
                offer(replies, verdicts)
        except Cancelled:
            with self._lock:
                self._pending.extendleft(reversed(queries))
            raise
        except Exception as exc:  # noqa: BLE001
            if not rclpy.ok(context=self.context):
                raise
            self._internal_error(f"{len(queries)} single-grasp queries", exc)
            if published and verdicts is not None:
                self._stats.record(verdicts.status[:published], {}, None)
            self._stats.record_failures(len(queries) - published)
            for reply in encode_failures(published, f"internal error: {exc}"):
                self._verdict_pub.publish(reply)

    def _answer_raw_queries(self, raws: list[bytes]):
        """Decide serialized queries; publish one serialized verdict each, in order.

        Queries that :mod:`grasp_fc_ros.interface.wire` does not decode (another layout) or with
        soft contacts (a torsional_friction) take the message path, in runs, so that
        verdicts still go out in arrival order.
        """
        if self._needs_messages():
            self._answer_single_queries([deserialize_message(r, ContactArray) for r in raws])
            return
        start = time.perf_counter()
        queries = wire.decode_contact_arrays(raws)
        decoded = np.zeros(len(raws), dtype=bool)
        decoded[queries.index] = True
        soft = queries.torsional != 0
        if soft.any():
            owner = np.repeat(np.arange(len(queries.index)), queries.packed.counts)
            decoded[queries.index[owner[soft]]] = False
        if decoded.all():
            self._answer_decoded(raws, queries, time.perf_counter() - start)
            return
        edges = np.flatnonzero(np.diff(decoded.astype(np.int8))) + 1
        for first, last in zip([0, *edges.tolist()], [*edges.tolist(), len(raws)]):
            part = raws[first:last]
            if decoded[first]:
                self._answer_decoded(part, wire.decode_contact_arrays(part), 0.0)
            else:
                self._answer_single_queries([deserialize_message(r, ContactArray)
                                             for r in part])

    def _needs_messages(self) -> bool:
        """Whether single verdicts need more than :mod:`grasp_fc_ros.interface.wire` encodes:
        certificates or minimum friction."""
        return self._settings.certificates or self._settings.compute_min_friction

    def _answer_decoded(self, raws: list[bytes], queries: wire.ContactQueries,
                        conversion_s: float):
        """Decide decoded queries ``queries`` of ``raws``; publish their verdicts' bytes."""
        def encode_failures(first: int, message: str) -> list[bytes]:
            rest = queries.prefixes[first:]
            return wire.encode_verdicts(
                rest, np.zeros(len(rest), bool),
                np.full(len(rest), Status.SOLVER_FAILURE, np.uint8),
                np.full(len(rest), math.nan), [message] * len(rest))

        self._publish_single_verdicts(
            raws, time.perf_counter() - conversion_s,
            pack=lambda: queries.packed,
            encode=lambda verdicts: wire.encode_verdicts(
                queries.prefixes, verdicts.force_closure, verdicts.status, verdicts.margin,
                verdicts.messages),
            encode_failures=encode_failures,
            offer=lambda _, verdicts: self._offer_markers(
                self._markers.offer_serialized_singles, raws, verdicts))

    def _next_batch(self):
        """Start the oldest queued batch on the workers, once fewer than
        :data:`BATCHES_IN_PROGRESS` are in progress; :meth:`_answer_batch` answers it."""
        with self._lock:
            self._batch_startable.wait_for(lambda: self._stopping or (
                self._batches and len(self._in_progress) < BATCHES_IN_PROGRESS))
            if self._stopping:
                return
            msg = self._batches.popleft()
            self._queued_batch_grasps -= len(msg.ids)
            self._busy_batch_grasps += len(msg.ids)
        batch = self._start_batch(msg)
        with self._lock:
            self._in_progress.append(batch)
            self._batch_started.notify()

    def _start_batch(self, msg: ContactArrayBatch) -> _BatchInProgress:
        """Convert a batch and queue its chunks; a failure becomes its answer."""
        start = time.perf_counter()
        try:
            packed = batch_to_packed(msg)
            conversion_s = time.perf_counter() - start
            decision = self._pool.start(packed, self._settings, PRIORITY_BATCH)
            return _BatchInProgress(msg, start, conversion_s, decision)
        except MalformedBatch as exc:
            if self._may_log("malformed"):
                self.get_logger().warning(str(exc))
            self._stats.record(np.full(len(msg.ids), Status.INVALID_INPUT, np.uint8), {}, None)
            failed = _failed_batch(msg, Status.INVALID_INPUT, str(exc))
        except Exception as exc:  # noqa: BLE001 - any failure must still be answered
            failed = self._batch_internal_error(msg, exc)
        return _BatchInProgress(msg, start, 0.0, failed=failed)

    def _answer_batch(self):
        """Publish the answer to the oldest batch in progress once it is decided."""
        with self._lock:
            self._batch_started.wait_for(lambda: self._in_progress or self._stopping)
            if self._stopping:
                return  # destroy_node answers the batches in progress
            batch = self._in_progress[0]
        cancelled = False
        try:
            verdicts, answer = self._batch_reply(batch)
        except Cancelled:
            cancelled = True  # left in progress: destroy_node answers it
            raise
        finally:
            if not cancelled:  # answered, or failed beyond answering: never retried
                with self._lock:
                    self._in_progress.popleft()
                    self._busy_batch_grasps -= len(batch.msg.ids)
                    self._batch_startable.notify()
        self._batch_pub.publish(answer)
        if self._marker_settings.enabled:
            self._offer_markers(self._markers.offer_batch, batch.msg, verdicts)

    def _batch_reply(self, batch: _BatchInProgress
                     ) -> tuple[Verdicts, ForceClosureVerdictArray | bytes]:
        """Wait for a batch's verdicts and count them: the verdicts and the answer to
        publish; any failure becomes one answer for all of it.

        Raises
        ------
        Cancelled
            If the node is destroyed meanwhile.
        """
        serialized = self._use_wire
        msg, failed = batch.msg, batch.failed
        if failed is None:
            try:
                verdicts, seconds = batch.decision.result(self._is_stopping)
                self._warn_invalid(verdicts)
                seconds["conversion_s"] = batch.conversion_s
                answer = _batch_answer(verdicts, msg, serialized)
                # Counted only once the answer exists, so a failure cannot count it twice.
                self._stats.record(verdicts.status, seconds, time.perf_counter() - batch.start)
                return verdicts, answer
            except Cancelled:
                raise
            except Exception as exc:  # noqa: BLE001 - any failure must still be answered
                failed = self._batch_internal_error(msg, exc)
        return failed, _batch_answer(failed, msg, serialized)

    def _batch_internal_error(self, msg: ContactArrayBatch, exc: Exception) -> Verdicts:
        self._internal_error(f"a batch of {len(msg.ids)} grasps", exc)
        self._stats.record_failures(len(msg.ids))
        return _failed_batch(msg, Status.SOLVER_FAILURE, f"internal error: {exc}")

    def _is_stopping(self) -> bool:
        return self._stopping

    def _decide_interactive(self, packed, settings: Settings, start: float
                            ) -> tuple[Verdicts, dict]:
        """Decide converted grasps ahead of batch chunks; warn about invalid ones."""
        conversion_s = time.perf_counter() - start
        verdicts, seconds = self._pool.decide(packed, settings, self._is_stopping,
                                              PRIORITY_INTERACTIVE)
        seconds["conversion_s"] = conversion_s
        self._warn_invalid(verdicts)
        return verdicts, seconds

    def _warn_invalid(self, verdicts: Verdicts):
        invalid = verdicts.status == _INVALID_INPUT
        if invalid.any() and self._may_log("invalid"):
            invalid = np.flatnonzero(invalid)
            self.get_logger().warning(
                f"{len(invalid)} of {len(verdicts)} queries invalid, e.g. "
                f"{verdicts.messages[invalid[0]]}")

    # --- shutdown ---------------------------------------------------------------------

    def destroy_node(self):
        """Stop the threads and workers, answer what is still queued, destroy the node.

        Queued queries get SOLVER_FAILURE with :data:`SHUTDOWN_MESSAGE` while rclpy's
        context is up (grasp-fc-node after Ctrl-C or SIGTERM, which it handles itself;
        the demo, tests, an embedding program); so do the queries being decided (their
        work is abandoned, so that the node stops within a fraction of a second). If the
        context is already shut down (rclpy's own signal handler in an embedding
        program), nothing can be published any more: the log says how many queries stay
        unanswered.
        """
        with self._lock:
            self._stopping = True
            for condition in (self._goal_queued, self._single_queued, self._batch_startable,
                              self._batch_started):
                condition.notify_all()
        if self._contacts_loop is not None:
            self._contacts_loop.stop()
        if self._service_loop is not None:
            self._service_loop.stop()
            self._service_node.destroy_node()
        for thread in self._threads:
            thread.join()
        self._stop_action()
        if self._markers is not None:
            self._markers.close()
        self._pool.close()
        with self._lock:
            singles, self._pending = list(self._pending), deque()
            # In order, with the answer of each batch refused at conversion (counted
            # then); the others get SHUTDOWN_MESSAGE.
            batches = [(batch.msg, batch.failed) for batch in self._in_progress]
            batches += [(msg, None) for msg in self._batches]
            self._in_progress, self._batches = deque(), deque()
        singles = [deserialize_message(q, ContactArray) if isinstance(q, bytes) else q
                   for q in singles]
        unanswered = len(singles) + sum(len(msg.ids) for msg, _ in batches)
        try:
            if (singles or batches) and not rclpy.ok(context=self.context):
                raise RuntimeError("rclpy is shut down")
            for reply in _failure_replies(singles, Status.SOLVER_FAILURE, SHUTDOWN_MESSAGE):
                self._verdict_pub.publish(reply)
                self._stats.record_failures(1)
                unanswered -= 1
            for msg, failed in batches:
                if failed is None:
                    self._batch_pub.publish(_batch_failure(msg, Status.SOLVER_FAILURE,
                                                           SHUTDOWN_MESSAGE))
                    self._stats.record_failures(len(msg.ids))
                else:
                    self._batch_pub.publish(_batch_answer(failed, msg, self._use_wire))
                unanswered -= len(msg.ids)
            if singles or batches:
                # Publishing only queues the answers: let DDS deliver them before the
                # process can exit, for a bounded time.
                for publisher in (self._verdict_pub, self._batch_pub):
                    publisher.wait_for_all_acked(Duration(seconds=SHUTDOWN_ACK_TIMEOUT_S))
        except Exception as exc:  # noqa: BLE001 - shutdown must go on
            self.get_logger().warning(f"cannot answer queued queries at shutdown: {exc}")
        if unanswered:
            self.get_logger().warning(f"{unanswered} queries left unanswered at shutdown")
        return super().destroy_node()

    # --- diagnostics ------------------------------------------------------------------

    def _publish_diagnostics(self):
        try:
            failures = self._stats.failures()
            with self._lock:
                pending = {"pending_single_queries": len(self._pending),
                           "pending_batch_grasps": (self._queued_batch_grasps
                                                    + self._busy_batch_grasps),
                           "action_goals_queued": len(self._goals),
                           "action_goals_running": self._running_goals}
            if self._markers is not None:
                pending.update(self._markers.counts())
            status = DiagnosticStatus(
                level=DiagnosticStatus.WARN if failures else DiagnosticStatus.OK,
                name=f"{self.get_fully_qualified_name()}: force-closure queries",
                message=(f"{failures} solver failures or internal errors" if failures
                         else "ok"),
                hardware_id="none",
                values=self._stats.key_values(pending))
            msg = DiagnosticArray(status=[status])
            msg.header.stamp = self.get_clock().now().to_msg()
            self._diag_pub.publish(msg)
        except Exception as exc:  # noqa: BLE001 - diagnostics must never stop the node
            self._internal_error("diagnostics", exc)

    def _check_duplicate_name(self):
        """Warn (once) when another node has this node's name and namespace."""
        if self._duplicate_warned:
            return
        me = (self.get_name(), self.get_namespace())
        if self.get_node_names_and_namespaces().count(me) > 1:
            self._duplicate_warned = True
            self.get_logger().warning(
                f"another node is named {self.get_fully_qualified_name()}: both answer every "
                "query; give one another name or namespace (--ros-args -r __ns:=/other)")


