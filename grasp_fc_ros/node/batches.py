"""The batch lane: ContactArrayBatch messages on ``contacts_batch``, one verdict array
each on ``verdicts_batch``.

The subscription, taken by a loop of its own
(:class:`~grasp_fc_ros.interface.wait_sets.SubscriptionLoop`), only queues (a batch of
more than ``max_batch`` grasps or ``max_message_contacts`` contacts is refused at once,
and so is one that would make more than ``max_batch`` grasps wait) and starts the
queued batches while fewer than :data:`BATCHES_IN_PROGRESS` are in progress: converts
each and queues its chunks for the workers. The ``answer_batch`` thread waits for the
oldest batch in progress, publishes its answer (answers go out in arrival order) and
starts the batches that waited for its place. Batches are taken serialized and read with numpy where
:mod:`grasp_fc_ros.interface.wire` reads this rmw's layout.
"""

from __future__ import annotations

import copy
import threading
from collections import deque
from dataclasses import dataclass

from grasp_fc_msgs.msg import ContactArrayBatch, ForceClosureVerdictArray
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.serialization import deserialize_message

from grasp_fc_ros.core import Status
from grasp_fc_ros.engine.pool import PRIORITY_BATCH, Cancelled, Decision
from grasp_fc_ros.interface import wire
from grasp_fc_ros.interface.conversions import (
    MalformedBatch,
    batch_contacts,
    batch_size,
    batch_to_packed,
)
from grasp_fc_ros.interface.names import CONTACTS_BATCH_TOPIC, QUERY_QOS
from grasp_fc_ros.interface.wait_sets import SubscriptionLoop
from grasp_fc_ros.node.lane import Drained, LaneContext, Refusal, start_thread
from grasp_fc_ros.node.marker_lane import MarkerLane
from grasp_fc_ros.node.participant import BatchParticipant
from grasp_fc_ros.node.replies import Replies, refused_verdicts
from grasp_fc_ros.packed import Verdicts

# Batches whose chunks may be queued for the workers at once: with one, the workers
# idle while a decided batch is answered and the next one converted and chunked; a
# client's large batch comes in parts of one chunk each, so that with fewer than two
# per worker the workers wait for the answer of the oldest.
# Tuned: docs/performance.md#batches-in-parts-issue-22.
BATCHES_IN_PROGRESS = 4
# Batches taken from the subscription at one wake-up: parts of a client's large batch
# come one after the other, each a few hundred KB.
MAX_TAKE = 16


@dataclass
class BatchInProgress:
    """A batch taken from the queue: its chunks on the workers, or its failed verdicts
    (neither while it is being converted).

    ``start`` is when it was taken (the lane's clock, s), ``conversion_s`` the time its
    conversion took.
    """

    query: ContactArrayBatch
    start: float
    conversion_s: float = 0.0
    decision: Decision | None = None
    failed: Verdicts | None = None

    @property
    def started(self) -> bool:
        """Whether its chunks are queued, or its answer known."""
        return self.decision is not None or self.failed is not None


class BatchLane:
    """Queue, decide and answer batches, in arrival order.

    Parameters
    ----------
    participant : BatchParticipant
        The node's participant for batches, whose helper node owns the subscription.
    context : LaneContext
    replies : Replies
        Encodes and publishes the answers.
    markers : MarkerLane
        Offered every answered batch.
    """

    def __init__(self, participant: BatchParticipant, context: LaneContext, replies: Replies,
                 markers: MarkerLane):
        self._context = context
        self._replies = replies
        self._markers = markers
        self._lock = threading.Lock()
        self._started = threading.Condition(self._lock)  # the answer thread waits on it
        self._queue: deque[ContactArrayBatch] = deque()
        # Batches whose chunks are on the workers, oldest first: answered in this order.
        self._in_progress: deque[BatchInProgress] = deque()
        self._queued_grasps = 0
        self._busy_grasps = 0
        self._stopping = False
        serialized = replies.serialized
        # A loop of its own: on the node's executor every batch (a client's large batch
        # comes in parts of MAX_MESSAGE_CONTACTS contacts) cost a rebuild of its wait set
        # (docs/performance.md#batches-in-parts-issue-22). On a DDS participant of its
        # own, and taken without the GIL, so that a batch of tens of MB sent as one
        # message holds up no service call (docs/performance.md#raw-one-message-batches).
        topic, qos = participant.subscription_topic(
            CONTACTS_BATCH_TOPIC, copy.copy(QUERY_QOS),
            QoSOverridingOptions.with_default_policies())
        self._loop = SubscriptionLoop(
            participant.node, ContactArrayBatch, topic, qos,
            self._on_serialized_batches if serialized else self._on_batches,
            lambda exc: context.internal_error("batches", exc),
            raw=serialized, gil_free=serialized, max_take=MAX_TAKE, name="contacts_batch",
            event_callbacks=context.subscription_events(topic, qos))
        self._thread = start_thread("answer_batch", self._answer_oldest, self.stopping,
                                    context)

    def stopping(self) -> bool:
        return self._stopping

    @property
    def queued(self) -> int:
        """Batches waiting to be started."""
        with self._lock:
            return len(self._queue)

    @property
    def in_progress(self) -> int:
        """Batches started and not answered yet."""
        with self._lock:
            return len(self._in_progress)

    def counts(self) -> dict[str, int]:
        with self._lock:
            return {"pending_batch_grasps": self._queued_grasps + self._busy_grasps}

    # --- in: the subscription loop's thread ----------------------------------------------

    def _on_serialized_batches(self, raws: list[bytes]) -> None:
        for raw in raws:
            self._on_serialized(raw)

    def _on_batches(self, queries: list[ContactArrayBatch]) -> None:
        for query in queries:
            self._on_batch(query)

    def _on_serialized(self, raw: bytes) -> None:
        """A serialized batch: read with numpy, or by rclpy if in another layout."""
        try:
            try:
                query = wire.decode_contact_array_batch(raw)
            except ValueError:
                query = deserialize_message(raw, ContactArrayBatch)
        except Exception as exc:  # noqa: BLE001 - unreadable: nobody to answer
            self._context.internal_error("an unreadable batch (no reply sent)", exc)
            return
        self._on_batch(query)

    def _on_batch(self, query: ContactArrayBatch) -> None:
        context = self._context
        try:
            n_grasps = batch_size(query)
            context.statistics.count_received(n_grasps)
            settings = context.settings()
            refusal = context.refusals.oversize(n_grasps, settings, batch_contacts(query))
            if refusal is None:
                with self._lock:
                    queued = self._queued_grasps
                    accepted = not self._stopping and not (
                        queued and queued + n_grasps > settings.max_batch)
                    if accepted:
                        self._queue.append(query)
                        self._queued_grasps += n_grasps
                if accepted:
                    self._start_queued()
                    return
                refusal = (context.refusals.shutdown(n_grasps) if self._stopping else
                           context.refusals.overloaded(f"{queued} batch grasps pending",
                                                       n_grasps, settings))
            self._replies.publish_batch(self._replies.batch_refusal(query, refusal))
        except Exception as exc:  # noqa: BLE001
            context.internal_error("a batch (no reply sent)", exc)

    # --- starting: the subscription loop's thread and the answer_batch thread -----------

    def _start_queued(self) -> None:
        """Start the queued batches, oldest first, while fewer than BATCHES_IN_PROGRESS
        are in progress. Called by the thread that made a batch startable (it arrived,
        or one in progress was answered): no thread of its own to wake per batch
        (docs/performance.md#worker-messages)."""
        while True:
            with self._lock:
                if (self._stopping or not self._queue
                        or len(self._in_progress) >= BATCHES_IN_PROGRESS):
                    return
                query = self._queue.popleft()
                self._queued_grasps -= len(query.ids)
                self._busy_grasps += len(query.ids)
                # In its place among the batches in progress before it is converted:
                # answers keep the arrival order whichever thread converts it.
                batch = BatchInProgress(query, self._context.clock())
                self._in_progress.append(batch)
            self._start(batch)
            with self._lock:
                self._started.notify()

    def _start(self, batch: BatchInProgress) -> None:
        """Convert a batch and queue its chunks; a failure becomes its answer."""
        context, query = self._context, batch.query
        try:
            packed = batch_to_packed(query)
            conversion_s = context.clock() - batch.start
            decision = context.pool.start(packed, context.settings(), PRIORITY_BATCH)
            with self._lock:
                batch.conversion_s, batch.decision = conversion_s, decision
            return
        except MalformedBatch as exc:
            if context.may_log("malformed"):
                context.logger.warning(str(exc))
            context.statistics.record_refused(Status.INVALID_INPUT, len(query.ids))
            failed = refused_verdicts(query, Refusal(Status.INVALID_INPUT, str(exc)))
        except Exception as exc:  # noqa: BLE001 - any failure must still be answered
            failed = self._internal_error(query, exc)
        with self._lock:
            batch.failed = failed

    # --- the answer_batch thread ----------------------------------------------------------

    def _answer_oldest(self) -> None:
        """Publish the answer to the oldest batch in progress once it is decided, then
        start the batches that waited for its place."""
        with self._lock:
            self._started.wait_for(lambda: self._stopping or (
                self._in_progress and self._in_progress[0].started))
            if self._stopping:
                return  # drain() answers the batches in progress
            batch = self._in_progress[0]
        cancelled = False
        try:
            verdicts, answer = self._answer(batch)
        except Cancelled:
            cancelled = True  # left in progress: drain() answers it
            raise
        finally:
            if not cancelled:  # answered, or failed beyond answering: never retried
                with self._lock:
                    self._in_progress.popleft()
                    self._busy_grasps -= len(batch.query.ids)
                self._start_queued()
        self._replies.publish_batch(answer)
        self._markers.offer_batch(batch.query, verdicts)

    def _answer(self, batch: BatchInProgress
                ) -> tuple[Verdicts, ForceClosureVerdictArray | bytes]:
        """Wait for a batch's verdicts and count them: the verdicts and the answer to
        publish; any failure becomes one answer for all of it.

        Raises
        ------
        Cancelled
            If the lane stops meanwhile.
        """
        context = self._context
        query, failed = batch.query, batch.failed
        if failed is None:
            assert batch.decision is not None
            try:
                verdicts, seconds = batch.decision.result(self.stopping)
                context.warn_invalid(verdicts)
                seconds["conversion_s"] = batch.conversion_s
                answer = self._replies.batch_answer(verdicts, query)
                # Counted only once the answer exists, so a failure cannot count it twice.
                context.statistics.record(verdicts.status, seconds,
                                          context.clock() - batch.start)
                return verdicts, answer
            except Cancelled:
                raise
            except Exception as exc:  # noqa: BLE001 - any failure must still be answered
                failed = self._internal_error(query, exc)
        return failed, self._replies.batch_answer(failed, query)

    def _internal_error(self, query: ContactArrayBatch, exc: Exception) -> Verdicts:
        self._context.internal_error(f"a batch of {len(query.ids)} grasps", exc)
        self._context.statistics.record_failures(len(query.ids))
        return refused_verdicts(query, Refusal(Status.SOLVER_FAILURE, f"internal error: {exc}"))

    # --- shutdown -------------------------------------------------------------------------

    def stop(self) -> None:
        """Refuse new batches, end the subscription loop and the answer thread (the
        batches in progress stay, for :meth:`drain`)."""
        with self._lock:
            self._stopping = True
            self._started.notify_all()
        self._loop.stop()
        self._thread.join()

    def drain(self) -> Drained:
        """Answer the batches in progress and queued, in order: each refused at
        conversion keeps its answer, the others get SHUTDOWN_MESSAGE (counted in
        grasps)."""
        with self._lock:
            batches = [(b.query, b.failed) for b in self._in_progress]
            batches += [(query, None) for query in self._queue]
            self._in_progress, self._queue = deque(), deque()
        total = sum(len(query.ids) for query, _ in batches)
        if not batches or not self._context.rclpy_context.ok():
            return Drained(unanswered=total)
        answered = 0
        try:
            for query, failed in batches:
                if failed is None:
                    answer = self._replies.batch_refusal(
                        query, self._context.refusals.shutdown(len(query.ids)))
                else:
                    answer = self._replies.batch_answer(failed, query)
                self._replies.publish_batch(answer)
                answered += len(query.ids)
        except Exception as exc:  # noqa: BLE001 - shutdown goes on
            self._context.logger.warning(f"cannot answer queued batches at shutdown: {exc}")
        return Drained(answered, total - answered)
