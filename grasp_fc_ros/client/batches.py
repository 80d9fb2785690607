"""The client's batches: ContactArrayBatch messages on ``contacts_batch``, a Future of
their :class:`~grasp_fc_ros.packed.Verdicts` from the client's reply topic
``verdicts_batch/c<client id>``.

A batch of more than :data:`~grasp_fc_ros.interface.names.MAX_MESSAGE_CONTACTS`
contacts goes out as several messages (parts) of whole grasps, each with a request id
of its own; its Future resolves once every part is answered, with their verdicts in
order. The parts go out from a thread of their own, each once the node has
acknowledged the one before (for at most :data:`PART_ACK_WAIT_S`): no message is then
large enough, and no burst of them long enough, to hold up a service call of the node
or of this process behind it (docs/performance.md#big-batches); and at most
:data:`PARTS_IN_FLIGHT` sent and not answered yet (for at most :data:`PART_ANSWER_WAIT_S`
each), so that a large batch does not fill the node's queue faster than it decides.
Every part is kept until answered and sent again as :mod:`grasp_fc_ros.client.pending`
says.
"""

from __future__ import annotations

import math
import queue
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np
from grasp_fc_msgs.msg import ContactArrayBatch, ForceClosureVerdictArray
from numpy.typing import ArrayLike
from rclpy.duration import Duration
from rclpy.node import Node

from grasp_fc_ros.client.pending import (
    RESEND_AFTER_S,
    Pending,
    publish,
    publish_again,
    resend_after,
)
from grasp_fc_ros.interface import wire
from grasp_fc_ros.interface.conversions import (
    BatchArrays,
    batch_arrays,
    batch_msg,
    grasps_to_batch_msg,
    verdict_array_to_numpy,
)
from grasp_fc_ros.interface.names import (
    CONTACTS_BATCH_TOPIC,
    MAX_MESSAGE_CONTACTS,
    QUERY_QOS,
    VERDICTS_BATCH_TOPIC,
    reply_topic,
    resolve,
)
from grasp_fc_ros.interface.wait_sets import SubscriptionLoop
from grasp_fc_ros.packed import Verdicts, chunk_end

# Longest the sending thread waits for the node to acknowledge a part before it sends the
# next one anyway (s): a slow or vanished node delays a batch's parts by this much each,
# never forever (tuned: docs/performance.md#big-batches).
PART_ACK_WAIT_S = 1.0
# Parts sent and not yet answered at most: as many as the node keeps in progress, and as
# many more queued to cover the time an answer takes back; a client that sent parts as fast
# as they were acknowledged filled the node's queue (max_batch grasps) with a slow node
# and got its later parts refused as overload (tuned: docs/performance.md#worker-messages).
PARTS_IN_FLIGHT = 8
# Longest the sending thread waits for an answer while PARTS_IN_FLIGHT are out before it
# sends the next part anyway (s): a vanished node holds a batch up by this much a part,
# never forever (its parts are sent again when a node appears).
PART_ANSWER_WAIT_S = 1.0
# Verdict arrays taken at one wake-up of the reply loop (one per part of a batch).
MAX_TAKE = 16


@dataclass
class _Batch:
    """One submitted batch: its Future and its parts' verdicts as they come in."""

    future: Future
    parts: list[Verdicts | None]
    missing: int = field(init=False)

    def __post_init__(self) -> None:
        self.missing = len(self.parts)


class BatchQueries:
    """Send batches and resolve their futures from the verdict arrays.

    Parameters
    ----------
    node : Node
        The client's node (spun by the client's executor).
    node_name : str
        The force_closure node's full name.
    client_id : int
        Carried by every batch; names the reply topic the answers come on.
    serialized : bool
        Take the answers as bytes (:mod:`grasp_fc_ros.interface.wire`: much faster than
        rclpy's message for a large batch, docs/performance.md#wire-format).
    resend_s : float
        Seconds without an answer after which a batch is sent again, plus
        :data:`~grasp_fc_ros.client.pending.RESEND_PER_GRASP_S` per grasp.
    """

    def __init__(self, node: Node, node_name: str, client_id: int, serialized: bool,
                 resend_s: float = RESEND_AFTER_S):
        self._node = node
        self._client_id = client_id
        self._resend_s = resend_s
        self._closed = False
        self._lock = threading.Lock()
        # request id -> (the part's query, its batch, its index in the batch)
        self._in_flight: dict[int, tuple[Pending, _Batch, int]] = {}
        # Request ids of the parts the sending thread sent, not answered yet.
        self._parts_out: set[int] = set()
        self._part_answered = threading.Condition(self._lock)
        self._next_request = 1
        self.publisher = node.create_publisher(
            ContactArrayBatch, resolve(node_name, CONTACTS_BATCH_TOPIC), QUERY_QOS)
        self.verdict_topic = resolve(node_name, reply_topic(VERDICTS_BATCH_TOPIC, client_id))
        # Taken by a loop of its own: on the client's executor each verdict array (one
        # per part of a large batch) cost a rebuild of its wait set
        # (docs/performance.md#batches-in-parts-issue-22).
        self._loop = SubscriptionLoop(
            node, ForceClosureVerdictArray, self.verdict_topic, QUERY_QOS,
            self._on_serialized if serialized else self._on_messages, self._on_loop_error,
            raw=serialized, max_take=MAX_TAKE, name="grasp_client_batch_verdicts")
        # Parts of large batches, in order, for the sending thread; None ends it.
        self._parts: queue.SimpleQueue[ContactArrayBatch | None] = queue.SimpleQueue()
        self._sender = threading.Thread(target=self._send_parts, daemon=True,
                                        name="grasp_client_batches")
        self._sender.start()

    @property
    def in_flight(self) -> int:
        """Messages (batches, or parts of one) sent and not answered yet."""
        with self._lock:
            return len(self._in_flight)

    def message(self, positions: ArrayLike, normals: ArrayLike, mu: ArrayLike | None,
                counts: ArrayLike | None, ids: ArrayLike | None, frame_id: str = "",
                torsional_friction: ArrayLike | None = None) -> ContactArrayBatch:
        """One stamped ContactArrayBatch of this client, with the next request id (see
        :meth:`grasp_fc_ros.client.GraspClient.submit_batch` for the arguments)."""
        ids = np.arange(n_grasps_of(positions, counts)) if ids is None else ids
        with self._lock:
            request_id, self._next_request = self._next_request, self._next_request + 1
        msg = grasps_to_batch_msg(ids, positions, normals, mu, counts,
                                  client_id=self._client_id, request_id=request_id,
                                  torsional_friction=torsional_friction)
        msg.header.frame_id = frame_id
        msg.header.stamp = self._node.get_clock().now().to_msg()
        return msg

    def submit(self, positions: ArrayLike, normals: ArrayLike, mu: ArrayLike | None,
               counts: ArrayLike | None, ids: ArrayLike | None, frame_id: str = "",
               torsional_friction: ArrayLike | None = None) -> Future:
        """Publish a batch (arguments as :meth:`message`), in parts of at most
        MAX_MESSAGE_CONTACTS contacts; a Future of all its Verdicts, in order. A failed
        publish (no node up) leaves a part due: sent when a node is there."""
        ids = np.arange(n_grasps_of(positions, counts)) if ids is None else ids
        fields = batch_arrays(ids, positions, normals, mu, counts, torsional_friction)
        parts = split_batch(fields, MAX_MESSAGE_CONTACTS)
        batch = _Batch(Future(), [None] * len(parts))
        stamp = self._node.get_clock().now().to_msg()
        for index, part in enumerate(parts):
            with self._lock:
                request_id, self._next_request = self._next_request, self._next_request + 1
            msg = batch_msg(part, client_id=self._client_id, request_id=request_id)
            msg.header.frame_id = frame_id
            msg.header.stamp = stamp
            pending = Pending.new(msg, resend_after(len(msg.ids), self._resend_s))
            if len(parts) > 1:
                pending.due = math.inf  # not due for a re-send before the sender sent it
            with self._lock:
                self._in_flight[request_id] = (pending, batch, index)
            if len(parts) == 1:
                publish(self.publisher, pending)
            else:
                self._parts.put(pending)
        return batch.future

    def _send_parts(self) -> None:
        """The sending thread: publish queued parts one at a time, each once the node
        acknowledged the previous one (or PART_ACK_WAIT_S passed)."""
        wait = Duration(seconds=PART_ACK_WAIT_S)
        while (pending := self._parts.get()) is not None:
            request_id = pending.msg.request_id
            with self._lock:
                self._part_answered.wait_for(
                    lambda: self._closed or len(self._parts_out) < PARTS_IN_FLIGHT,
                    PART_ANSWER_WAIT_S)
                wanted = request_id in self._in_flight  # not answered, not closed
                if wanted:
                    self._parts_out.add(request_id)
            if not wanted:
                continue
            if not publish(self.publisher, pending):
                continue  # due at once: re-sent when a node is there
            try:
                self.publisher.wait_for_all_acked(wait)
            except Exception:  # noqa: BLE001 - closed or shut down: re-sent on reconnect
                if not self._node.context.ok():
                    return

    def resend(self, everything: bool) -> int:
        """Publish again the unanswered parts: all of them, or those due
        (:mod:`grasp_fc_ros.client.pending`); how many grasps."""
        with self._lock:
            pendings = [pending for pending, _, _ in self._in_flight.values()]
        if everything:  # parts the sender has not sent yet go out from there
            pendings = [pending for pending in pendings if pending.due != math.inf]
        sent = publish_again(self.publisher, pendings, everything, lambda: self._closed)
        return sum(len(pending.msg.ids) for pending in sent)

    def _on_messages(self, msgs: list[ForceClosureVerdictArray]) -> None:
        for msg in msgs:
            if msg.client_id == self._client_id:
                self._answered(msg.request_id, partial(verdict_array_to_numpy, msg))

    def _on_serialized(self, raws: list[bytes]) -> None:
        """Serialized verdict arrays: read with numpy; other clients' are skipped
        unread."""
        for raw in raws:
            client_id, request_id = wire.verdict_ids(raw)
            if client_id == self._client_id:
                self._answered(request_id, partial(_verdicts_of, raw))

    def _on_loop_error(self, exc: Exception) -> None:
        self._node.get_logger().error(f"reading batch verdicts failed: {exc!r}")

    def _answered(self, request_id: int, read: Callable[[], Verdicts]) -> None:
        with self._lock:
            entry = self._in_flight.pop(request_id, None)
            if request_id in self._parts_out:
                self._parts_out.discard(request_id)
                self._part_answered.notify()
        if entry is None:
            return
        _, batch, index = entry
        if batch.future.done():
            return  # an earlier part failed to read
        try:
            verdicts = read()
        except Exception as exc:  # noqa: BLE001 - the caller learns why, not a timeout
            batch.future.set_exception(exc)
            return
        with self._lock:
            batch.parts[index] = verdicts
            batch.missing -= 1
            complete = batch.missing == 0
        if complete:
            parts = [part for part in batch.parts if part is not None]
            batch.future.set_result(parts[0] if len(parts) == 1
                                    else Verdicts.concatenate(parts))

    def close(self) -> list[Future]:
        """Stop sending parts and re-sending; the futures still unanswered (for the
        caller to cancel)."""
        self._closed = True
        self._parts.put(None)
        self._loop.stop()
        with self._lock:
            self._part_answered.notify_all()
            pending = {id(batch.future): batch.future
                       for _, batch, _ in self._in_flight.values()}
            self._in_flight.clear()
            self._parts_out.clear()
        return list(pending.values())


def split_batch(fields: BatchArrays, max_contacts: int) -> list[BatchArrays]:
    """``fields`` in parts of whole grasps, in order, each of at most ``max_contacts``
    contacts (a larger grasp alone in its part); ``[fields]`` if it fits in one, or if
    its arrays do not match its counts (the node then refuses it whole, saying why).

    Parameters
    ----------
    fields : BatchArrays
        A batch's arrays (:func:`~grasp_fc_ros.interface.conversions.batch_arrays`).
    max_contacts : int
        Contacts per part at most.

    Returns
    -------
    list of BatchArrays
        Views into ``fields``' arrays (no copies).
    """
    counts = fields.contact_counts.astype(np.int64)
    total = int(counts.sum())
    matching = (len(counts) == len(fields.ids) and len(fields.positions) == 3 * total
                and len(fields.normals) == 3 * total
                and all(len(values) in (0, total) for values in
                        (fields.friction_coefficients, fields.torsional_friction)))
    if total <= max_contacts or not matching:
        return [fields]
    ends = np.cumsum(counts)  # contacts up to and including grasp i
    parts = []
    for first, last in grasp_ranges(counts, max_contacts):
        base, end = (int(ends[first - 1]) if first else 0), int(ends[last - 1])
        per_contact = [values[base:end] if len(values) else values
                       for values in (fields.friction_coefficients, fields.torsional_friction)]
        parts.append(BatchArrays(fields.ids[first:last], fields.contact_counts[first:last],
                                 fields.positions[3 * base:3 * end],
                                 fields.normals[3 * base:3 * end], *per_contact))
    return parts


def grasp_ranges(counts: Sequence[int] | np.ndarray, max_contacts: int) -> list[tuple[int, int]]:
    """Where grasps of ``counts`` contacts split into parts: ``(first, last)``
    grasp ranges, in order, each of at most ``max_contacts`` contacts (a larger grasp
    alone in its range).

    Parameters
    ----------
    counts : sequence of int or ndarray
        Contacts of each grasp (N,).
    max_contacts : int
        Contacts per range at most.
    """
    ends = np.cumsum(counts)  # contacts up to and including grasp i
    parts, first = [], 0
    while first < len(counts):
        last = chunk_end(ends, first, max_contacts)
        parts.append((first, last))
        first = last
    return parts


def _verdicts_of(raw: bytes) -> Verdicts:
    """The verdicts of a serialized verdict array."""
    return wire.decode_verdict_array(raw)[2]


def n_grasps_of(positions: Any, counts: Any) -> int:
    """Grasps in a batch given as (N, n, 3) arrays or stacked with ``counts``."""
    return len(counts) if counts is not None else len(positions)
