"""The client's single queries: one ContactArray on ``contacts`` per grasp, a Future of
its ForceClosureVerdict from the client's reply topic ``verdicts/c<client id>``."""

from __future__ import annotations

import threading
import time
from concurrent.futures import Future
from typing import Any

import numpy as np
from grasp_fc_msgs.msg import ContactArray, ForceClosureVerdict
from numpy.typing import ArrayLike
from rclpy.clock import Clock, ROSClock
from rclpy.node import Node
from rclpy.serialization import deserialize_message

from grasp_fc_ros.client.pending import (
    RESEND_AFTER_S,
    Pending,
    publish,
    publish_again,
    resend_after,
)
from grasp_fc_ros.interface import wire
from grasp_fc_ros.interface.conversions import grasp_to_contact_array
from grasp_fc_ros.interface.names import (
    CONTACTS_TOPIC,
    QUERY_QOS,
    VERDICTS_TOPIC,
    reply_topic,
    resolve,
)
from grasp_fc_ros.interface.wait_sets import SubscriptionLoop

# Single queries unanswered at most (more submit() calls wait): well inside what the
# node's KEEP_ALL reader takes without pushing back for long.
DEFAULT_IN_FLIGHT = 2_000
DEFAULT_TIMEOUT_S = 60.0
# Verdicts taken per wake-up of the verdicts loop at most (one wake-up costs about as
# much as a verdict).
MAX_TAKE = 2_000


def stamp(clock: Clock) -> tuple[int, int]:
    """``clock``'s time now, (sec, nanosec): read from the system clock as rcl does
    unless ROS time is active (use_sim_time), without rclpy's Time objects (cheaper per
    query: docs/performance.md#single-topic)."""
    if isinstance(clock, ROSClock) and clock.ros_time_is_active:
        return clock.now().seconds_nanoseconds()
    sec, nanosec = divmod(time.time_ns(), 1_000_000_000)
    return sec, nanosec


class SingleQueries:
    """Send single-grasp queries and resolve their futures from the verdicts.

    Parameters
    ----------
    node : Node
        The client's node.
    node_name : str
        The force_closure node's full name (its topics are looked up next to it).
    client_id : int
        Carried by every query; names the reply topic the verdicts come on.
    max_in_flight : int
        Largest number of queries sent but not answered.
    serialized : bool
        Send queries and take verdicts as bytes (:mod:`grasp_fc_ros.interface.wire`).
    resend_s : float
        Seconds without an answer after which a query is sent again
        (:mod:`grasp_fc_ros.client.pending`).
    """

    def __init__(self, node: Node, node_name: str, client_id: int, max_in_flight: int,
                 serialized: bool, resend_s: float = RESEND_AFTER_S):
        self._node = node
        self._client_id = client_id
        self._max_in_flight = max_in_flight
        self._serialized = serialized
        self._lock = threading.Condition()
        self._resend_s = resend_s
        self._closed = False
        self._in_flight: dict[int, Pending] = {}
        self._next_id = 1
        self.publisher = node.create_publisher(ContactArray, resolve(node_name, CONTACTS_TOPIC),
                                               QUERY_QOS)
        self.verdict_topic = resolve(node_name, reply_topic(VERDICTS_TOPIC, client_id))
        # Verdicts come in many at a time: taken by a loop of their own, every verdict
        # the subscription holds at each wake-up (see SubscriptionLoop).
        self._loop = SubscriptionLoop(
            node, ForceClosureVerdict, self.verdict_topic, QUERY_QOS,
            self._on_serialized if serialized else self._on_messages, self._on_loop_error,
            raw=serialized, max_take=MAX_TAKE, name="grasp_client_verdicts")

    @property
    def in_flight(self) -> int:
        with self._lock:
            return len(self._in_flight)

    def submit(self, positions: ArrayLike, normals: ArrayLike, mu: ArrayLike,
               query_id: int | None, frame_id: str, timeout: float) -> Future:
        """See :meth:`grasp_fc_ros.client.GraspClient.submit`."""
        with self._lock:
            if query_id is None:
                query_id, self._next_id = self._next_id, self._next_id + 1
            if query_id in self._in_flight:
                raise ValueError(f"query id {query_id} is already in flight")
            if not self._lock.wait_for(lambda: len(self._in_flight) < self._max_in_flight,
                                       timeout):
                raise TimeoutError(f"{len(self._in_flight)} queries unanswered for {timeout} s")
            msg = self._query(query_id, positions, normals, mu, frame_id)
            pending = Pending.new(msg, resend_after(1, self._resend_s))
            self._in_flight[query_id] = pending
        # A failed publish (no node) leaves it due: sent when a node is there.
        publish(self.publisher, pending)
        return pending.future

    def resend(self, everything: bool) -> int:
        """Publish again the unanswered queries: all of them, or those due
        (:mod:`grasp_fc_ros.client.pending`); how many."""
        with self._lock:
            pendings = list(self._in_flight.values())
        sent = publish_again(self.publisher, pendings, everything, lambda: self._closed)
        return len(sent)

    def _query(self, query_id: int, positions: ArrayLike, normals: ArrayLike, mu: ArrayLike,
               frame_id: str) -> Any:
        """The ContactArray of one query: serialized bytes, or a message without wire."""
        if not self._serialized:
            msg = grasp_to_contact_array(query_id, positions, normals, mu,
                                         client_id=self._client_id)
            msg.header.frame_id = frame_id
            msg.header.stamp = self._node.get_clock().now().to_msg()
            return msg
        points = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        contacts = np.zeros((len(points), wire.CONTACT_VALUES))
        contacts[:, 0:3] = points
        contacts[:, 3:6] = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
        contacts[:, 6] = mu
        return wire.encode_contact_array(query_id, self._client_id, contacts, frame_id,
                                         stamp(self._node.get_clock()))

    def _on_serialized(self, raws: list[bytes]) -> None:
        """Resolve the futures of serialized verdicts of this client."""
        mine = []
        for data in raws:
            if data[:len(wire.CDR_LE)] == wire.CDR_LE:
                client_id, query_id = wire.verdict_ids(data)
                if client_id == self._client_id:  # a stray publisher's are not decoded
                    mine.append((query_id, data))
            else:
                msg = deserialize_message(data, ForceClosureVerdict)
                if msg.client_id == self._client_id:
                    mine.append((msg.id, data))
        with self._lock:
            entries = [(self._in_flight.pop(query_id, None), data) for query_id, data in mine]
            self._lock.notify_all()
        for entry, data in entries:
            if entry is not None:
                entry.future.set_result(wire.decode_verdict(data) if data[:4] == wire.CDR_LE
                                        else deserialize_message(data, ForceClosureVerdict))

    def _on_messages(self, msgs: list[ForceClosureVerdict]) -> None:
        with self._lock:
            entries = [(self._in_flight.pop(msg.id, None), msg) for msg in msgs
                       if msg.client_id == self._client_id]  # not a stray publisher's
            self._lock.notify_all()
        for entry, msg in entries:
            if entry is not None:
                entry.future.set_result(msg)

    def _on_loop_error(self, exc: Exception) -> None:
        self._node.get_logger().error(f"reading verdicts failed: {exc!r}")

    def close(self) -> list[Future]:
        """Stop reading verdicts; the futures still unanswered (for the caller to
        cancel)."""
        self._closed = True
        self._loop.stop()
        with self._lock:
            pending = [entry.future for entry in self._in_flight.values()]
            self._in_flight.clear()
            self._lock.notify_all()
        return pending
