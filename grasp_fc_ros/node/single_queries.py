"""The single-query lane: ContactArray queries on ``contacts``, one verdict each.

Queries come in many at a time: a :class:`~grasp_fc_ros.interface.wait_sets.SubscriptionLoop`
takes every query the subscription holds at each wake-up and queues them (at most
``max_batch``; more are refused at once with SOLVER_FAILURE "node overloaded"). One
thread decides all queued queries together, ahead of batch chunks, and publishes one
verdict per query in arrival order. Queries travel serialized where this rmw's layout
is the one :mod:`grasp_fc_ros.interface.wire` reads (no rclpy message per query), as
messages otherwise and for the settings wire does not encode (certificates, minimum
friction).
"""

from __future__ import annotations

import array
import copy
import math
import threading
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from grasp_fc_msgs.msg import ContactArray, ForceClosureVerdict
from rclpy.node import Node
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.serialization import deserialize_message

from grasp_fc_ros.core import Status
from grasp_fc_ros.engine.pool import Cancelled
from grasp_fc_ros.interface import message_slots as slots
from grasp_fc_ros.interface import wire
from grasp_fc_ros.interface.conversions import contact_arrays_to_packed, verdicts_to_msgs
from grasp_fc_ros.interface.names import CONTACTS_TOPIC, QUERY_QOS
from grasp_fc_ros.interface.wait_sets import SubscriptionLoop
from grasp_fc_ros.node.lane import Drained, LaneContext, Refusal, start_thread
from grasp_fc_ros.node.marker_lane import MarkerLane
from grasp_fc_ros.node.replies import Replies
from grasp_fc_ros.packed import PackedGrasps, Verdicts

# Queries taken per wake-up of the contacts loop at most (whatever the subscription
# holds): one wake-up costs about as much as deciding a query. A GraspClient keeps at
# most its window (2,000) in flight.
MAX_TAKE = 2_000

# A query: serialized bytes, or a message where wire does not read this rmw's layout.
Query = Any


def failure_replies(queries: Sequence[ContactArray], refusal: Refusal
                    ) -> list[ForceClosureVerdict]:
    """Verdict messages answering ContactArray ``queries`` with ``refusal``.

    In bulk: one message object per query (its header is the query's own) and nothing
    else; the message text, the empty certificates and the NaN wrench are shared by all,
    so the replies are only to be sent, never changed.
    """
    status, message = int(refusal.status), refusal.message
    forces: list[Any] = []
    torques = array.array("d")
    wrench = slots.nan_wrench()
    return [slots.verdict(q.header, q.client_id, q.id, False, status, math.nan, message,
                          forces, torques, wrench, math.nan)
            for q in queries]


def serialized_failure_replies(raws: Sequence[bytes], refusal: Refusal) -> list[Any]:
    """Verdicts answering serialized ``raws`` with ``refusal``, in order: bytes, or
    messages for queries in a layout wire does not read."""
    decoded = wire.decode_contact_arrays(list(raws))
    replies: list[Any] = [None] * len(raws)
    n = len(decoded.index)
    encoded = wire.encode_verdicts(decoded.prefixes, np.zeros(n, bool),
                                   np.full(n, refusal.status, np.uint8), np.full(n, math.nan),
                                   [refusal.message] * n)
    for i, reply in zip(decoded.index.tolist(), encoded, strict=True):
        replies[i] = reply
    for i in decoded.undecoded.tolist():
        replies[i] = failure_replies([deserialize_message(raws[i], ContactArray)], refusal)[0]
    return replies


def refusal_replies(queries: Sequence[Query], refusal: Refusal) -> list[Any]:
    """Verdicts answering ``queries`` (all bytes or all messages) with ``refusal``."""
    if queries and isinstance(queries[0], bytes):
        return serialized_failure_replies(queries, refusal)
    return failure_replies(queries, refusal)


class SingleQueryLane:
    """Queue, decide and answer single-grasp queries.

    Parameters
    ----------
    node : Node
        Owns the subscription.
    context : LaneContext
    replies : Replies
        Publishes the verdicts.
    markers : MarkerLane
        Offered every answered query.
    serialized : bool
        Take the queries as bytes (:mod:`grasp_fc_ros.interface.wire`).
    """

    def __init__(self, node: Node, context: LaneContext, replies: Replies,
                 markers: MarkerLane, serialized: bool):
        self._context = context
        self._replies = replies
        self._markers = markers
        self._queue: deque[Query] = deque()
        self._queued = threading.Condition()
        self._stopping = False
        qos = copy.copy(QUERY_QOS)
        self._loop = SubscriptionLoop(
            node, ContactArray, CONTACTS_TOPIC, qos, self._on_queries,
            lambda exc: context.internal_error("single-grasp queries", exc),
            raw=serialized, max_take=MAX_TAKE, name="contacts",
            qos_overriding_options=QoSOverridingOptions.with_default_policies(),
            event_callbacks=context.subscription_events(CONTACTS_TOPIC, qos))
        self._thread = start_thread("single_queries", self._answer_queued, self.stopping,
                                    context)

    @property
    def pending(self) -> int:
        """Queries queued and not being decided yet."""
        with self._queued:
            return len(self._queue)

    def stopping(self) -> bool:
        return self._stopping

    def counts(self) -> dict[str, int]:
        return {"pending_single_queries": self.pending}

    # --- in: the subscription loop's thread ---------------------------------------------

    def _on_queries(self, queries: list[Query]) -> None:
        """Queue queries, oldest first; those beyond ``max_batch`` pending (or all, once
        stopping) are answered at once."""
        context = self._context
        context.statistics.count_received(len(queries))
        settings = context.settings()
        with self._queued:
            room = 0 if self._stopping else max(0, settings.max_batch - len(self._queue))
            self._queue.extend(queries[:room])
            pending = len(self._queue)
            if room:
                self._queued.notify()
        refused = queries[room:]
        if not refused:
            return
        refusal = (context.refusals.shutdown(len(refused)) if self._stopping else
                   context.refusals.overloaded(f"{pending} single-grasp queries pending",
                                               len(refused), settings))
        for reply in refusal_replies(refused, refusal):
            self._replies.publish_verdict(reply)

    # --- deciding: the lane's thread ------------------------------------------------------

    def _answer_queued(self) -> None:
        """Decide the queued queries together, in arrival order."""
        with self._queued:
            self._queued.wait_for(lambda: self._queue or self._stopping)
            if self._stopping:
                return
            take = min(len(self._queue), self._context.settings().max_batch)
            queries = [self._queue.popleft() for _ in range(take)]
        self.answer(queries)

    def answer(self, queries: list[Query]) -> None:
        """Decide ``queries`` (all bytes or all messages) together and publish one
        verdict each, in order (what the lane's thread does with each drain).

        If anything fails, the queries not answered yet get a SOLVER_FAILURE verdict
        (none a second one); if the lane is stopping, they go back to the queue for
        :meth:`drain`.
        """
        if queries and isinstance(queries[0], bytes):
            self._answer_serialized(queries)
        else:
            self._answer_messages(queries)

    def _answer_messages(self, msgs: list[ContactArray]) -> None:
        self._publish_verdicts(
            msgs, self._context.clock(),
            pack=lambda: contact_arrays_to_packed(msgs, name_by_id=True),
            encode=lambda verdicts: verdicts_to_msgs(verdicts, msgs),
            encode_failures=lambda first, refusal: failure_replies(msgs[first:], refusal),
            offer=lambda replies, _: self._markers.offer_singles(msgs, replies))

    def _answer_serialized(self, raws: list[bytes]) -> None:
        """Decide serialized queries; publish one serialized verdict each, in order.

        Queries that :mod:`grasp_fc_ros.interface.wire` does not decode (another layout)
        or with soft contacts (a torsional_friction), and all of them when the settings
        ask for certificates, minimum friction or epsilon, take the message path, in
        runs, so that verdicts still go out in arrival order.
        """
        settings = self._context.settings()
        if settings.certificates or settings.compute_min_friction or settings.compute_epsilon:
            self._answer_messages([deserialize_message(r, ContactArray) for r in raws])
            return
        start = self._context.clock()
        queries = wire.decode_contact_arrays(raws)
        decoded = np.zeros(len(raws), dtype=bool)
        decoded[queries.index] = True
        soft = queries.torsional != 0
        if soft.any():
            owner = np.repeat(np.arange(len(queries.index)), queries.packed.counts)
            decoded[queries.index[owner[soft]]] = False
        if decoded.all():
            self._answer_decoded(raws, queries, start)
            return
        edges = np.flatnonzero(np.diff(decoded.astype(np.int8))) + 1
        for first, last in zip([0, *edges.tolist()], [*edges.tolist(), len(raws)], strict=True):
            part = raws[first:last]
            if decoded[first]:
                self._answer_decoded(part, wire.decode_contact_arrays(part),
                                     self._context.clock())
            else:
                self._answer_messages([deserialize_message(r, ContactArray) for r in part])

    def _answer_decoded(self, raws: list[bytes], queries: wire.ContactQueries,
                        start: float) -> None:
        """Decide decoded queries ``queries`` of ``raws``; publish their verdicts' bytes."""
        def encode_failures(first: int, refusal: Refusal) -> list[bytes]:
            rest = queries.prefixes[first:]
            return wire.encode_verdicts(
                rest, np.zeros(len(rest), bool), np.full(len(rest), refusal.status, np.uint8),
                np.full(len(rest), math.nan), [refusal.message] * len(rest))

        self._publish_verdicts(
            raws, start,
            pack=lambda: queries.packed,
            encode=lambda verdicts: wire.encode_verdicts(
                queries.prefixes, verdicts.force_closure, verdicts.status, verdicts.margin,
                verdicts.messages),
            encode_failures=encode_failures,
            offer=lambda _, verdicts: self._markers.offer_serialized_singles(raws, verdicts))

    def _publish_verdicts(self, queries: list[Query], start: float,
                          pack: Callable[[], PackedGrasps],
                          encode: Callable[[Verdicts], Sequence[Any]],
                          encode_failures: Callable[[int, Refusal], Sequence[Any]],
                          offer: Callable[[Sequence[Any], Verdicts], None]) -> None:
        """Decide ``queries`` and publish their verdicts.

        ``pack()`` converts them, ``encode(verdicts)`` makes the replies and
        ``encode_failures(first, refusal)`` the replies refusing ``queries[first:]``;
        ``offer(replies, verdicts)`` queues their markers.
        """
        context = self._context
        published = 0
        verdicts = None
        try:
            verdicts, seconds = context.decide_interactive(pack(), context.settings(), start,
                                                           self.stopping)
            replies = encode(verdicts)
            for reply in replies:
                self._replies.publish_verdict(reply)
                published += 1
            context.statistics.record(verdicts.status, seconds, context.clock() - start)
            offer(replies, verdicts)
        except Cancelled:
            with self._queued:
                self._queue.extendleft(reversed(queries))
            raise
        except Exception as exc:  # noqa: BLE001 - every query still gets a verdict
            if not context.rclpy_context.ok():
                raise
            context.internal_error(f"{len(queries)} single-grasp queries", exc)
            if published and verdicts is not None:
                context.statistics.record(verdicts.status[:published], {}, None)
            context.statistics.record_failures(len(queries) - published)
            for reply in encode_failures(published, _internal_refusal(exc)):
                self._replies.publish_verdict(reply)

    # --- shutdown -------------------------------------------------------------------------

    def stop(self) -> None:
        """Refuse new queries, end the loop and the thread (a drain in progress gives its
        queries back to the queue)."""
        with self._queued:
            self._stopping = True
            self._queued.notify_all()
        self._loop.stop()
        self._thread.join()

    def drain(self) -> Drained:
        """Answer the queued queries with SHUTDOWN_MESSAGE."""
        with self._queued:
            queries, self._queue = list(self._queue), deque()
        if not queries or not self._context.rclpy_context.ok():
            return Drained(unanswered=len(queries))
        answered = 0
        try:
            for reply in refusal_replies(queries, self._context.refusals.shutdown(len(queries))):
                self._replies.publish_verdict(reply)
                answered += 1
        except Exception as exc:  # noqa: BLE001 - shutdown goes on
            self._context.logger.warning(f"cannot answer queued queries at shutdown: {exc}")
        return Drained(answered, len(queries) - answered)


def _internal_refusal(exc: Exception) -> Refusal:
    return Refusal(Status.SOLVER_FAILURE, f"internal error: {exc}")
