"""The client's batches: one ContactArrayBatch on ``contacts_batch``, a Future of its
:class:`~grasp_fc_ros.engine.packed.Verdicts` from the client's reply topic
``verdicts_batch/c<client id>``."""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

import numpy as np
from grasp_fc_msgs.msg import ContactArrayBatch, ForceClosureVerdictArray
from numpy.typing import ArrayLike
from rclpy.node import Node

from grasp_fc_ros.client.pending import (
    RESEND_AFTER_S,
    Pending,
    publish,
    publish_again,
    resend_after,
)
from grasp_fc_ros.engine.packed import Verdicts
from grasp_fc_ros.interface import wire
from grasp_fc_ros.interface.conversions import grasps_to_batch_msg, verdict_array_to_numpy
from grasp_fc_ros.interface.names import (
    CONTACTS_BATCH_TOPIC,
    QUERY_QOS,
    VERDICTS_BATCH_TOPIC,
    reply_topic,
    resolve,
)


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
        self._in_flight: dict[int, Pending] = {}
        self._next_request = 1
        self.publisher = node.create_publisher(
            ContactArrayBatch, resolve(node_name, CONTACTS_BATCH_TOPIC), QUERY_QOS)
        self.verdict_topic = resolve(node_name, reply_topic(VERDICTS_BATCH_TOPIC, client_id))
        node.create_subscription(ForceClosureVerdictArray, self.verdict_topic,
                                 self._on_serialized if serialized else self._on_message,
                                 QUERY_QOS, raw=serialized)

    @property
    def in_flight(self) -> int:
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

    def submit(self, msg: ContactArrayBatch) -> Future:
        """Publish a batch made by :meth:`message`; a Future of its Verdicts (a failed
        publish, with no node up, leaves it due: sent when a node is there)."""
        pending = Pending.new(msg, resend_after(len(msg.ids), self._resend_s))
        with self._lock:
            self._in_flight[msg.request_id] = pending
        publish(self.publisher, pending)
        return pending.future

    def resend(self, everything: bool) -> int:
        """Publish again the unanswered batches: all of them, or those due
        (:mod:`grasp_fc_ros.client.pending`); how many grasps."""
        with self._lock:
            pendings = list(self._in_flight.values())
        sent = publish_again(self.publisher, pendings, everything, lambda: self._closed)
        return sum(len(pending.msg.ids) for pending in sent)

    def _on_message(self, msg: ForceClosureVerdictArray) -> None:
        if msg.client_id == self._client_id:
            self._answered(msg.request_id, lambda: verdict_array_to_numpy(msg))

    def _on_serialized(self, raw: bytes) -> None:
        """A serialized verdict array: read with numpy; other clients' are skipped
        unread."""
        client_id, request_id = wire.verdict_ids(raw)
        if client_id == self._client_id:
            self._answered(request_id, lambda: wire.decode_verdict_array(raw)[2])

    def _answered(self, request_id: int, read: Callable[[], Verdicts]) -> None:
        with self._lock:
            entry = self._in_flight.pop(request_id, None)
        if entry is None:
            return
        try:
            entry.future.set_result(read())
        except Exception as exc:  # noqa: BLE001 - the caller learns why, not a timeout
            entry.future.set_exception(exc)

    def close(self) -> list[Future]:
        """Stop re-sending; the futures still unanswered (for the caller to cancel)."""
        self._closed = True
        with self._lock:
            pending = [entry.future for entry in self._in_flight.values()]
            self._in_flight.clear()
        return pending


def n_grasps_of(positions: Any, counts: Any) -> int:
    """Grasps in a batch given as (N, n, 3) arrays or stacked with ``counts``."""
    return len(counts) if counts is not None else len(positions)
