"""The ``force_closure`` ROS 2 node: grasp contacts in, force-closure verdicts out.

Interfaces (package ``grasp_fc_msgs``):

- subscribes ``contacts`` (ContactArray), publishes one ForceClosureVerdict per
  query on ``verdicts``;
- subscribes ``contacts_batch`` (ContactArrayBatch), publishes one
  ForceClosureVerdictArray per batch on ``verdicts_batch``;
- serves ``check_force_closure`` (CheckForceClosure);
- publishes ``/diagnostics`` (diagnostic_msgs/DiagnosticArray) once a second.

The node is a thin layer: it converts messages to numpy arrays, groups grasps by
contact count, and hands each group to :func:`grasp_fc_ros.core.check_force_closure`.
Every query gets exactly one verdict carrying its id; bad queries are answered with
``INVALID_INPUT`` and a reason, internal errors with ``SOLVER_FAILURE``.

Single-grasp topic queries are only queued by their subscription callback; a worker
thread decides whatever has queued up in one call per contact count and publishes the
verdicts in arrival order. One core call per query would cap the rate at the core's
per-call cost. At most ``max_batch`` queries wait: a query arriving when the queue is
full is answered at once with ``SOLVER_FAILURE`` ("node overloaded: <k> single-grasp
queries pending"), so it may overtake the verdicts of queries still queued. Batches and
service requests are answered in their callbacks.

Grasps named in messages: a single-grasp topic query by its id ("query id 12, contact
2: normal has zero length"), a grasp of a batch or service request by its index there
and its id ("grasp 3 (id 1003), contact 2: ...").

Run it with ``grasp-fc-node`` or ``python -m grasp_fc_ros.node`` (``--ros-args -p
name:=value`` sets parameters).
"""

from __future__ import annotations

import math
import re
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, fields, replace

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from grasp_fc_msgs.msg import (
    ContactArray,
    ContactArrayBatch,
    ForceClosureVerdict,
    ForceClosureVerdictArray,
)
from grasp_fc_msgs.srv import CheckForceClosure
from rcl_interfaces.msg import IntegerRange, ParameterDescriptor, ParameterType, SetParametersResult
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from grasp_fc_ros.conversions import (
    PackedGrasps,
    Verdicts,
    batch_to_packed,
    contact_arrays_to_packed,
    verdicts_to_array_msg,
    verdicts_to_msgs,
)
from grasp_fc_ros.core import ORIGIN_CHOICES, Status, check_force_closure, validate_grasps
from grasp_fc_ros.core.grasp_input import MIN_CONTACTS

NODE_NAME = "force_closure"
DIAGNOSTICS_PERIOD_S = 1.0
WARN_THROTTLE_S = 2.0
# Processing times kept for the diagnostics' mean and p99.
TIMING_WINDOW = 2000
# Upper bounds of the integer parameters: beyond these a single message would not fit
# any sensible memory budget.
MAX_QOS_DEPTH = 100_000
MAX_CONTACTS_LIMIT = 10_000
MAX_BATCH_LIMIT = 10_000_000
# Verdict message of single-grasp queries still queued when the node is destroyed.
SHUTDOWN_MESSAGE = "node shutting down: query not evaluated"

# The wire status codes are the core's Status values.
assert all(getattr(ForceClosureVerdict, s.name) == s.value for s in Status)


def _int_descriptor(description, low, high, read_only=False):
    return ParameterDescriptor(
        type=ParameterType.PARAMETER_INTEGER, description=description, read_only=read_only,
        integer_range=[IntegerRange(from_value=low, to_value=high, step=1)])


PARAMETERS = {
    # name: (default, descriptor)
    "friction_coefficient": (0.5, ParameterDescriptor(
        type=ParameterType.PARAMETER_DOUBLE,
        description="Coulomb friction coefficient for contacts that give none (finite <= 0)",
        additional_constraints="finite and > 0")),
    "use_filter": (True, ParameterDescriptor(
        type=ParameterType.PARAMETER_BOOL,
        description="Run the torque-space filter before the exact test")),
    "filter_origins": ("seed", ParameterDescriptor(
        type=ParameterType.PARAMETER_STRING,
        description="Torque origins of the filter: 'seed' (the paper's) or 'all'",
        additional_constraints="one of: " + ", ".join(ORIGIN_CHOICES))),
    "qos_depth": (100, _int_descriptor(
        "History depth of the reliable topics' QoS (applied at start-up)", 1, MAX_QOS_DEPTH,
        read_only=True)),
    "max_contacts": (64, _int_descriptor(
        "Largest number of contacts accepted in one grasp", MIN_CONTACTS, MAX_CONTACTS_LIMIT)),
    "max_batch": (100_000, _int_descriptor(
        "Largest number of grasps accepted in one batch message or service request, and of "
        "single-grasp topic queries waiting to be decided; a topic query arriving when that "
        "many wait is answered at once with SOLVER_FAILURE 'node overloaded'",
        1, MAX_BATCH_LIMIT)),
}


def check_parameter(name: str, value) -> str:
    """Return why ``value`` is not acceptable for parameter ``name`` ('' if it is)."""
    if name == "friction_coefficient":
        if not (math.isfinite(value) and value > 0):
            return f"friction_coefficient must be finite and > 0, got {value}"
    elif name == "filter_origins" and value not in ORIGIN_CHOICES:
        return f"filter_origins must be one of {ORIGIN_CHOICES}, got {value!r}"
    return ""


@dataclass(frozen=True)
class _Settings:
    """The parameters that decide queries, replaced as a whole when one changes.

    Each evaluation reads the node's settings once, so a parameter change arriving
    meanwhile (from another thread) cannot mix old and new values within one message.
    """

    friction_coefficient: float
    use_filter: bool
    filter_origins: str
    max_contacts: int
    max_batch: int


_SETTING_NAMES = frozenset(f.name for f in fields(_Settings))


class _Statistics:
    """Counters and processing times reported on /diagnostics (thread-safe)."""

    def __init__(self):
        self._lock = threading.Lock()
        self.counts = {s: 0 for s in Status}
        self.queries = 0
        self.callback_errors = 0
        self.overloaded = 0
        self.seconds = {"conversion_s": 0.0, "filter_s": 0.0, "exact_s": 0.0}
        self.processing_s = deque(maxlen=TIMING_WINDOW)

    def record(self, status: np.ndarray, seconds: dict, processing_s: float | None):
        """Count answered queries: their verdict codes and where their time went.

        ``processing_s`` is None for answers that did no real work (failures), which
        must not pull the mean and p99 processing time down.
        """
        codes, counts = np.unique(status, return_counts=True)
        with self._lock:
            self.queries += len(status)
            for code, count in zip(codes.tolist(), counts.tolist()):
                self.counts[Status(code)] += count
            for key in self.seconds:
                self.seconds[key] += seconds.get(key, 0.0)
            if processing_s is not None:
                self.processing_s.append(processing_s)

    def record_failures(self, n_queries: int):
        """Count ``n_queries`` answered with SOLVER_FAILURE without being decided."""
        self.record(np.full(n_queries, Status.SOLVER_FAILURE, dtype=np.uint8), {}, None)

    def count_error(self):
        with self._lock:
            self.callback_errors += 1

    def count_overloaded(self):
        with self._lock:
            self.overloaded += 1

    def failures(self) -> int:
        with self._lock:
            return self.counts[Status.SOLVER_FAILURE] + self.callback_errors

    def key_values(self, pending: int) -> list[KeyValue]:
        with self._lock:
            times_ms = np.array(self.processing_s) * 1e3
            counts = dict(self.counts)
            values = {
                "queries": self.queries,
                "force_closure": counts[Status.FORCE_CLOSURE],
                "rejected_by_filter": counts[Status.FILTERED_OUT],
                "decided_by_exact_test": (counts[Status.FORCE_CLOSURE]
                                          + counts[Status.NOT_FORCE_CLOSURE]),
                "invalid_input": counts[Status.INVALID_INPUT],
                "solver_failures": counts[Status.SOLVER_FAILURE],
                "callback_errors": self.callback_errors,
                "overloaded": self.overloaded,
                "pending_single_queries": pending,
                "conversion_time_total_s": f"{self.seconds['conversion_s']:.3f}",
                "filter_time_total_s": f"{self.seconds['filter_s']:.3f}",
                "exact_time_total_s": f"{self.seconds['exact_s']:.3f}",
            }
        mean_ms = float(times_ms.mean()) if len(times_ms) else 0.0
        p99_ms = float(np.percentile(times_ms, 99)) if len(times_ms) else 0.0
        values["processing_time_mean_ms"] = f"{mean_ms:.3f}"
        values["processing_time_p99_ms"] = f"{p99_ms:.3f}"
        return [KeyValue(key=k, value=str(v)) for k, v in values.items()]


def _grasp_label(packed: PackedGrasps, index: int) -> str:
    """How messages name grasp ``index``: 'query id 12', or 'grasp 3 (id 1003)' in a batch."""
    if packed.name_by_id:
        return f"query id {packed.ids[index]}"
    return f"grasp {index} (id {packed.ids[index]})"


def _relabel(reason: str, label: str) -> str:
    """Make a reason starting 'grasp k' (core, conversions) name the grasp by ``label``."""
    return re.sub(r"^grasp \d+", lambda _: label, reason)


def _failure_replies(ids, message: str) -> list[ForceClosureVerdict]:
    """SOLVER_FAILURE verdict messages, built without numpy or the conversions."""
    return [ForceClosureVerdict(id=int(i), force_closure=False, status=Status.SOLVER_FAILURE,
                                margin=math.nan, message=message) for i in ids]


class ForceClosureNode(Node):
    """Answers force-closure queries on topics and a service; see the module docstring."""

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        self._stats = _Statistics()
        # Single-grasp topic queries waiting for the worker thread, oldest first; at most
        # max_batch of them (more are refused as overloaded).
        self._pending: deque[ContactArray] = deque()
        self._pending_ready = threading.Condition()
        self._stopping = False
        self._settings = _Settings(**{name: PARAMETERS[name][0] for name in _SETTING_NAMES})
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._after_set_parameters)
        for name, (default, descriptor) in PARAMETERS.items():
            self.declare_parameter(name, default, descriptor)

        qos = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                         depth=self.get_parameter("qos_depth").value)
        self._verdict_pub = self.create_publisher(ForceClosureVerdict, "verdicts", qos)
        self._batch_pub = self.create_publisher(ForceClosureVerdictArray, "verdicts_batch", qos)
        self._diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(ContactArray, "contacts", self._on_contacts, qos)
        self.create_subscription(ContactArrayBatch, "contacts_batch", self._on_batch, qos)
        self.create_service(CheckForceClosure, "check_force_closure", self._on_service)
        self.create_timer(DIAGNOSTICS_PERIOD_S, self._publish_diagnostics)
        self._worker = threading.Thread(target=self._single_query_loop, daemon=True,
                                        name="single_queries")
        self._worker.start()
        self.get_logger().info("ready: topics contacts, contacts_batch; service check_force_closure")

    # --- parameters -------------------------------------------------------------------

    def _on_set_parameters(self, parameters) -> SetParametersResult:
        reasons = [check_parameter(p.name, p.value) for p in parameters]
        reasons = [r for r in reasons if r]
        return SetParametersResult(successful=not reasons, reason="; ".join(reasons))

    def _after_set_parameters(self, parameters):
        # Cached so the hot path does not look parameters up per message; replaced whole,
        # so that a reader sees either the old or the new settings (see _Settings).
        changes = {p.name: p.value for p in parameters if p.name in _SETTING_NAMES}
        if changes:
            self._settings = replace(self._settings, **changes)

    # --- callbacks: nothing may escape them, so that spin never dies ------------------

    def _on_contacts(self, msg: ContactArray):
        # Only queue it: the worker thread decides queued queries together, in one core
        # call per contact count, which is what makes thousands of queries/s possible.
        try:
            with self._pending_ready:
                pending = len(self._pending)
                accepted = not self._stopping and pending < self._settings.max_batch
                if accepted:
                    self._pending.append(msg)
                    self._pending_ready.notify()
            if not accepted:
                self._refuse(msg, pending)
        except Exception as exc:  # noqa: BLE001
            self._internal_error("a single-grasp query", exc)

    def _refuse(self, msg: ContactArray, pending: int):
        """Answer a query that cannot be queued at once (never drop it silently)."""
        if self._stopping:
            message = SHUTDOWN_MESSAGE
        else:
            message = f"node overloaded: {pending} single-grasp queries pending"
            self._stats.count_overloaded()
            self.get_logger().warning(f"{message}; refusing query id {msg.id} (max_batch)",
                                      throttle_duration_sec=WARN_THROTTLE_S)
        self._stats.record_failures(1)
        self._verdict_pub.publish(_failure_replies([msg.id], message)[0])

    def _on_batch(self, msg: ContactArrayBatch):
        try:
            self._batch_pub.publish(self._batch_reply(msg))
        except Exception as exc:  # noqa: BLE001 - e.g. the failure reply itself failed
            self._internal_error("a batch (no reply sent)", exc)

    def _batch_reply(self, msg: ContactArrayBatch) -> ForceClosureVerdictArray:
        """Decide a batch and count it; any failure becomes SOLVER_FAILURE for all of it."""
        start = time.perf_counter()
        try:
            verdicts, seconds = self._decide(lambda: batch_to_packed(msg))
            reply = verdicts_to_array_msg(verdicts, msg.header)
            # Counted only once the reply exists, so a failure cannot count it twice.
            self._stats.record(verdicts.status, seconds, time.perf_counter() - start)
            return reply
        except Exception as exc:  # noqa: BLE001 - any failure must still be answered
            self._internal_error(f"a batch of {len(msg.ids)} grasps", exc)
            ids = np.frombuffer(msg.ids, np.uint64) if len(msg.ids) else np.empty(0, np.uint64)
            self._stats.record_failures(len(ids))
            failed = Verdicts(ids=ids, force_closure=np.zeros(len(ids), bool),
                              status=np.full(len(ids), Status.SOLVER_FAILURE, dtype=np.uint8),
                              margin=np.full(len(ids), np.nan),
                              messages=[f"internal error: {exc}"] * len(ids))
            return verdicts_to_array_msg(failed, msg.header)

    def _on_service(self, request, response):
        try:
            response.verdicts = self._service_reply(request)
        except Exception as exc:  # noqa: BLE001 - the response must still be sent
            # Only reachable if even the failure verdicts cannot be built: the client
            # then gets an empty verdict list rather than no response at all.
            self._internal_error("a service request (empty response sent)", exc)
        return response

    def _service_reply(self, request) -> list[ForceClosureVerdict]:
        """Decide a service request and count it; any failure becomes SOLVER_FAILURE."""
        start = time.perf_counter()
        try:
            verdicts, seconds = self._decide(lambda: contact_arrays_to_packed(request.grasps))
            replies = verdicts_to_msgs(verdicts)
            self._stats.record(verdicts.status, seconds, time.perf_counter() - start)
            return replies
        except Exception as exc:  # noqa: BLE001
            self._internal_error(f"a service request of {len(request.grasps)} grasps", exc)
            self._stats.record_failures(len(request.grasps))
            return _failure_replies([g.id for g in request.grasps], f"internal error: {exc}")

    def _internal_error(self, what: str, exc: Exception):
        self._stats.count_error()
        self.get_logger().error(f"internal error while answering {what}: {exc!r}",
                                throttle_duration_sec=WARN_THROTTLE_S)

    # --- single-grasp queries: a worker thread, in arrival order ----------------------

    def _single_query_loop(self):
        """Answer queued queries until the node is destroyed or rclpy shuts down."""
        while True:
            try:
                with self._pending_ready:
                    self._pending_ready.wait_for(lambda: self._pending or self._stopping)
                    if self._stopping:
                        return
                    take = min(len(self._pending), self._settings.max_batch)
                    msgs = [self._pending.popleft() for _ in range(take)]
                self._answer_single_queries(msgs)
            except Exception as exc:  # noqa: BLE001 - one failed pass must not end the worker
                if not rclpy.ok(context=self.context):
                    return  # publishing after shutdown: nobody can be answered any more
                self._internal_error("queued single-grasp queries (worker continues)", exc)

    def _answer_single_queries(self, msgs: list[ContactArray]):
        """Decide queued queries together; publish one verdict each, in arrival order."""
        start = time.perf_counter()
        published = 0
        try:
            verdicts, seconds = self._decide(
                lambda: contact_arrays_to_packed(msgs, name_by_id=True))
            for reply in verdicts_to_msgs(verdicts):
                self._verdict_pub.publish(reply)
                published += 1
            self._stats.record(verdicts.status, seconds, time.perf_counter() - start)
        except Exception as exc:  # noqa: BLE001
            if not rclpy.ok(context=self.context):
                raise
            self._internal_error(f"{len(msgs)} single-grasp queries", exc)
            if published:
                self._stats.record(verdicts.status[:published], {}, None)
            # Queries already answered must not get a second verdict.
            rest = msgs[published:]
            self._stats.record_failures(len(rest))
            for reply in _failure_replies([m.id for m in rest], f"internal error: {exc}"):
                self._verdict_pub.publish(reply)

    def destroy_node(self):
        """Stop the worker, answer the queries still queued, destroy the node.

        Still-queued queries get SOLVER_FAILURE with :data:`SHUTDOWN_MESSAGE` when
        rclpy's context is still up (the node destroyed by its owner: the demo, tests,
        an embedding program). After Ctrl-C or SIGTERM the context is already shut
        down and nothing can be published any more: those queries stay unanswered,
        which is logged.
        """
        with self._pending_ready:
            self._stopping = True
            self._pending_ready.notify()
        self._worker.join()
        with self._pending_ready:
            leftover = list(self._pending)
            self._pending.clear()
        if leftover:
            try:
                if not rclpy.ok(context=self.context):
                    raise RuntimeError("rclpy is shut down")
                self._stats.record_failures(len(leftover))
                for reply in _failure_replies([m.id for m in leftover], SHUTDOWN_MESSAGE):
                    self._verdict_pub.publish(reply)
            except Exception as exc:  # noqa: BLE001 - shutdown must go on
                self.get_logger().warning(
                    f"{len(leftover)} queued single-grasp queries left unanswered at "
                    f"shutdown: {exc}")
        return super().destroy_node()

    # --- evaluation -------------------------------------------------------------------

    def _decide(self, convert) -> tuple[Verdicts, dict]:
        """Convert a message with ``convert()`` and decide all its grasps; warn about bad ones.

        Returns the verdicts and the seconds spent per stage; counting is the caller's
        job, once its reply exists.
        """
        start = time.perf_counter()
        packed = convert()
        seconds = {"conversion_s": time.perf_counter() - start}
        verdicts = self.evaluate(packed, seconds)
        for note in packed.notes:
            self.get_logger().warning(f"malformed batch: {note}",
                                      throttle_duration_sec=WARN_THROTTLE_S)
        invalid = np.flatnonzero(verdicts.status == Status.INVALID_INPUT)
        if len(invalid):
            self.get_logger().warning(
                f"{len(invalid)} of {len(verdicts)} queries invalid, e.g. "
                f"{verdicts.messages[invalid[0]]}", throttle_duration_sec=WARN_THROTTLE_S)
        return verdicts, seconds

    def evaluate(self, packed: PackedGrasps, seconds: dict | None = None) -> Verdicts:
        """Decide every grasp of ``packed``; one verdict per grasp, in order.

        Time spent in the core's stages is added to ``seconds['filter_s']`` and
        ``seconds['exact_s']`` when a dict is given.

        Grasps are grouped by contact count and each group goes through the core in
        one batched call. Invalid grasps get ``INVALID_INPUT``; a failing group gets
        ``SOLVER_FAILURE`` without spoiling the other groups. The parameters are read
        once, so every grasp of one call is decided with the same settings.
        """
        settings = self._settings
        n_grasps = len(packed)
        verdicts = Verdicts(ids=packed.ids, force_closure=np.zeros(n_grasps, bool),
                            status=np.full(n_grasps, Status.INVALID_INPUT, dtype=np.uint8),
                            margin=np.full(n_grasps, np.nan), messages=[""] * n_grasps)
        if n_grasps > settings.max_batch:
            verdicts.messages = [f"{n_grasps} grasps exceed max_batch={settings.max_batch}"
                                 ] * n_grasps
            return verdicts
        for i, reason in packed.unreadable.items():
            verdicts.messages[i] = _relabel(reason, _grasp_label(packed, i))
        counts = packed.counts
        eligible = np.ones(n_grasps, bool)
        eligible[list(packed.unreadable)] = False
        wrong_size = (counts < MIN_CONTACTS) | (counts > settings.max_contacts)
        for i in np.flatnonzero(eligible & wrong_size):
            eligible[i] = False
            verdicts.messages[i] = (f"{_grasp_label(packed, i)}: {counts[i]} contacts; a grasp "
                                    f"needs {MIN_CONTACTS} to max_contacts={settings.max_contacts}")
        # Only a finite contact friction <= 0 means "use the parameter"; NaN and +-inf stay
        # and are rejected by the validation as not finite.
        mu = np.where(np.isfinite(packed.mu) & (packed.mu <= 0),
                      settings.friction_coefficient, packed.mu)
        starts = packed.starts
        for n in np.unique(counts[eligible]):
            group = np.flatnonzero(eligible & (counts == n))
            rows = starts[group, None] + np.arange(n)
            try:
                timing = self._evaluate_group(packed, group, rows, mu[rows], settings, verdicts)
                if seconds is not None:
                    for key in ("filter_s", "exact_s"):
                        seconds[key] = seconds.get(key, 0.0) + timing.get(key, 0.0)
            except Exception as exc:  # noqa: BLE001 - one group must not spoil the others
                self._internal_error(f"{len(group)} grasps of {n} contacts (core failed)", exc)
                verdicts.status[group] = Status.SOLVER_FAILURE
                for i in group:
                    verdicts.messages[i] = f"internal error: {exc}"
        return verdicts

    def _evaluate_group(self, packed: PackedGrasps, group: np.ndarray, rows: np.ndarray,
                        mu: np.ndarray, settings: _Settings, verdicts: Verdicts) -> dict:
        """Decide grasps ``group`` (indices into ``packed``), all with equal contact count.

        ``rows`` (len(group), n) indexes their contacts; verdicts are written in place.
        Returns the core's timing dict ({} when no grasp was valid).
        """
        positions, normals = packed.positions[rows], packed.normals[rows]
        validation = validate_grasps(positions, normals, mu)
        for k in np.flatnonzero(~validation.valid):
            verdicts.messages[group[k]] = _relabel(validation.reasons[k],
                                                   _grasp_label(packed, int(group[k])))
        valid = validation.valid
        if not valid.any():
            return {}
        result = check_force_closure(positions[valid], normals[valid], mu[valid],
                                     use_filter=settings.use_filter,
                                     origins=settings.filter_origins)
        target = group[valid]
        verdicts.status[target] = result.status
        verdicts.force_closure[target] = result.force_closure
        verdicts.margin[target] = result.margin
        return result.timing

    # --- diagnostics ------------------------------------------------------------------

    def _publish_diagnostics(self):
        try:
            failures = self._stats.failures()
            with self._pending_ready:
                pending = len(self._pending)
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


def main(args=None) -> int:
    """Run the node until Ctrl-C or SIGTERM; return the process exit code."""
    rclpy.init(args=args)
    node = None
    try:
        # The executor exists before the node logs "ready": a Ctrl-C right after that
        # line must not land inside the executor's constructor (which then leaves a
        # half-built executor whose __del__ prints a traceback).
        executor = SingleThreadedExecutor()
        node = ForceClosureNode()
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except ParameterException as exc:
        print(f"{NODE_NAME}: bad parameter: {exc}", file=sys.stderr)
        return 1
    except Exception:
        # A signal can shut the context down while the executor builds its next wait
        # set; rclpy then raises an RCLError instead of ExternalShutdownException.
        if rclpy.ok():
            raise
    finally:
        if node is not None:
            node.destroy_node()
        shutdown_rclpy()
    return 0


def shutdown_rclpy():
    """Shut rclpy down unless a signal already did.

    ``try_shutdown`` checks the context and then shuts it down; rclpy's signal handler
    can shut it down in between, and the second shutdown raises RCLError.
    """
    try:
        rclpy.try_shutdown()
    except Exception:  # noqa: BLE001 - rclpy raises its private RCLError here
        if rclpy.ok():
            raise


if __name__ == "__main__":
    sys.exit(main())
