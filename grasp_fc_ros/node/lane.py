"""What the node's lanes share: the context they are given, refusals, their threads.

A lane is one way in to the node (single queries, batches, services, the action, the
marker glue): it owns its queue, its condition, its threads and its stop flag, and
answers everything it took. :class:`Lane` is what the node's wiring asks of each:
``stop()`` (take no more work, let the threads end), ``drain()`` (answer what is still
queued, once the workers are gone) and ``counts()`` (its queue lengths for
/diagnostics). No lock or condition is shared between lanes; the statistics keep
their own lock.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple, Protocol

import numpy as np
from rclpy.context import Context
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.impl.rcutils_logger import RcutilsLogger
from rclpy.node import Node

from grasp_fc_ros.core import Status
from grasp_fc_ros.engine.pool import PRIORITY_INTERACTIVE, Cancelled, EvaluationPool
from grasp_fc_ros.interface.wait_sets import ServiceLoop
from grasp_fc_ros.node.statistics import Statistics, Throttle
from grasp_fc_ros.packed import PackedGrasps, Settings, Verdicts

# Verdict message of queries still queued when the node is destroyed.
SHUTDOWN_MESSAGE = "node shutting down: query not evaluated"
# A plain integer: comparing an array with an IntEnum member costs microseconds a call.
_INVALID_INPUT = int(Status.INVALID_INPUT)


class Lane(Protocol):
    """One way in to the node, as its wiring sees it."""

    def stop(self) -> None:
        """Take no more work; end the lane's threads (work in progress is abandoned or
        answered, never lost: it goes back to the queue for :meth:`drain`)."""

    def drain(self) -> Drained:
        """Answer what is still queued (after :meth:`stop` and the workers' end)."""

    def counts(self) -> dict[str, int]:
        """Queue lengths and the like, for /diagnostics."""


class Drained(NamedTuple):
    """What a lane's :meth:`Lane.drain` answered, and what it could not (rclpy was
    shut down, or publishing failed), in queries."""

    answered: int = 0
    unanswered: int = 0


class Refusal(NamedTuple):
    """Why queries are answered without being decided: a status and its message."""

    status: Status
    message: str


class Refusals:
    """The one place where refusals are worded, counted and logged.

    Every lane answers a refused query with the :class:`Refusal` one of these methods
    returns, in the form its interface needs, in bulk (one message for all of them).
    """

    def __init__(self, statistics: Statistics, logger: RcutilsLogger, may_log: Throttle):
        self._statistics = statistics
        self._logger = logger
        self._may_log = may_log

    def oversize(self, n_grasps: int, settings: Settings, n_contacts: int | None = None,
                 kind: str = "message") -> Refusal | None:
        """INVALID_INPUT for a message of more than ``max_batch`` grasps, or (where
        ``n_contacts`` is given: batch messages, goals and service requests) of more
        than ``max_message_contacts`` contacts (counted as answered); None if it is not
        oversized. ``kind`` names such a message in the refusal ("message", "request")."""
        cap = settings.max_message_contacts
        if n_grasps > settings.max_batch:
            message = f"{n_grasps} grasps exceed max_batch={settings.max_batch}"
        elif n_contacts is not None and cap and n_contacts > cap:
            message = (f"{n_contacts} contacts in one {kind} exceed "
                       f"max_message_contacts={cap}: split it into {kind}s of whole "
                       "grasps (GraspClient does)")
        else:
            return None
        self._statistics.record_refused(Status.INVALID_INPUT, n_grasps)
        return Refusal(Status.INVALID_INPUT, message)

    def overloaded(self, what: str, n_queries: int, settings: Settings) -> Refusal:
        """SOLVER_FAILURE for queries beyond a full queue (``what`` says which)."""
        message = f"node overloaded: {what}"
        self._statistics.count_overloaded(n_queries)
        self._statistics.record_refused(Status.SOLVER_FAILURE, n_queries)
        if self._may_log("overloaded"):
            self._logger.warning(
                f"{message}; refused {n_queries} {'query' if n_queries == 1 else 'queries'} "
                f"(queue limit max_batch={settings.max_batch})")
        return Refusal(Status.SOLVER_FAILURE, message)

    def shutdown(self, n_queries: int) -> Refusal:
        """SOLVER_FAILURE for queries the node no longer decides (it is shutting down)."""
        self._statistics.record_refused(Status.SOLVER_FAILURE, n_queries)
        return Refusal(Status.SOLVER_FAILURE, SHUTDOWN_MESSAGE)


@dataclass
class LaneContext:
    """What the node gives every lane.

    Attributes
    ----------
    pool : EvaluationPool
        Decides packed grasps (a test may give a pool of its own).
    statistics : Statistics
    refusals : Refusals
    settings : callable () -> Settings
        The current parameter snapshot; read once per message.
    logger : RcutilsLogger
    rclpy_context : Context
        The node's context: once it is shut down nothing can be published.
    may_log : Throttle
        Decides whether a warning of a given key may be logged now.
    clock : callable () -> float
        Seconds, for processing times (``time.perf_counter``).
    """

    pool: EvaluationPool
    statistics: Statistics
    refusals: Refusals
    settings: Callable[[], Settings]
    logger: RcutilsLogger
    rclpy_context: Context
    may_log: Throttle
    clock: Callable[[], float] = field(default=time.perf_counter)

    def internal_error(self, what: str, exc: BaseException) -> None:
        """Count and log (throttled) a failure while answering ``what``."""
        self.statistics.count_error()
        if self.may_log("internal error"):
            self.logger.error(f"internal error while answering {what}: {exc!r}")

    def subscription_events(self, topic: str) -> SubscriptionEventCallbacks:
        """QoS event callbacks for the subscription to ``topic``: messages the middleware
        reports lost (where the rmw does: Fast DDS does, e.g. for a publisher whose
        KEEP_LAST history overwrote queries not yet delivered, though a run of them
        skipped at once may count as one) are counted for /diagnostics
        (``messages_lost``) and logged (throttled)."""
        def on_lost(info: object) -> None:
            lost = int(getattr(info, "total_count_change", 0))
            self.statistics.count_lost(lost)
            if lost and self.may_log(f"lost {topic}"):
                self.logger.warning(
                    f"{lost} messages on {topic} lost before the node took them (their "
                    "publisher's QoS history overwrote them; use RELIABLE KEEP_ALL, see "
                    "grasp_fc_ros.interface.names.QUERY_QOS); they get no answer")

        return SubscriptionEventCallbacks(message_lost=on_lost)

    def warn_invalid(self, verdicts: Verdicts) -> None:
        """Log (throttled) that some verdicts are INVALID_INPUT, with an example."""
        invalid = verdicts.status == _INVALID_INPUT
        if invalid.any() and self.may_log("invalid"):
            first = int(np.flatnonzero(invalid)[0])
            self.logger.warning(
                f"{int(invalid.sum())} of {len(verdicts)} queries invalid, e.g. "
                f"{verdicts.messages[first]}")

    def decide_interactive(self, packed: PackedGrasps, settings: Settings, start: float,
                           cancelled: Callable[[], bool]) -> tuple[Verdicts, dict]:
        """Decide converted grasps ahead of batch chunks; warn about invalid ones.

        ``start`` is when the request was taken (:attr:`clock`), so that the conversion
        counts. Raises :class:`~grasp_fc_ros.engine.pool.Cancelled` if ``cancelled()``
        becomes true first.
        """
        conversion_s = self.clock() - start
        verdicts, seconds = self.pool.decide(packed, settings, cancelled, PRIORITY_INTERACTIVE)
        seconds["conversion_s"] = conversion_s
        self.warn_invalid(verdicts)
        return verdicts, seconds


def start_thread(name: str, step: Callable[[], None], stopping: Callable[[], bool],
                 context: LaneContext) -> threading.Thread:
    """A daemon thread that runs ``step()`` until ``stopping()``.

    A :class:`~grasp_fc_ros.engine.pool.Cancelled` ends it (its lane is stopping); any
    other exception is counted as an internal error and the thread goes on, unless rclpy
    is shut down (nothing can be answered any more).
    """
    def run() -> None:
        while not stopping():
            try:
                step()
            except Cancelled:
                return
            except Exception as exc:  # noqa: BLE001 - one failed pass must not end the lane
                if not context.rclpy_context.ok():
                    return
                context.internal_error(f"{name} (thread continues)", exc)

    thread = threading.Thread(target=run, daemon=True, name=name)
    thread.start()
    return thread


class HelperServices:
    """Services served from a helper node ``<node>_<suffix>`` and a thread of their own
    (the service lanes' shared part).

    The helper takes no command-line arguments of its own (a ``__node`` remapping would
    give it the node's own name); the service names are resolved by the node itself, so
    that the node's remappings apply to them.

    Parameters
    ----------
    node : Node
        The force_closure node: its name, namespace, context and remappings.
    suffix : str
        The helper node's name after the node's and an underscore.
    context : LaneContext
    services : sequence of (service type, name, callback)
    """

    def __init__(self, node: Node, suffix: str, context: LaneContext,
                 services: Sequence[tuple[Any, str, Callable[[Any, Any], Any]]]):
        self.stopping = False
        self._helper = Node(f"{node.get_name()}_{suffix}", namespace=node.get_namespace(),
                            context=node.context, use_global_arguments=False,
                            start_parameter_services=False)
        self._loop = ServiceLoop(
            [self._helper.create_service(kind, node.resolve_service_name(name), callback)
             for kind, name, callback in services],
            node.context,
            lambda service, exc: context.internal_error(
                f"a {service.srv_name} request (no response sent)", exc),
            name=suffix)

    def stop(self) -> None:
        """Let the request in progress be answered, then stop serving."""
        self.stopping = True
        self._loop.stop()
        self._helper.destroy_node()
