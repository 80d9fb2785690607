"""Where the node's topic answers go, and how they are encoded.

Single verdicts are ForceClosureVerdict messages (one per query), batch answers
ForceClosureVerdictArray messages (one per batch), both with
:data:`~grasp_fc_ros.interface.names.VERDICT_QOS`; serialized by
:mod:`grasp_fc_ros.interface.wire` where this rmw's layout is the one it writes.

An answer goes to its asker: to the reply topic of the query's ``client_id``
(:func:`~grasp_fc_ros.interface.names.reply_topic`: ``verdicts/c<16 hex digits>``,
``verdicts_batch/c<...>``), or, for a query without one (client_id 0), to the shared
``verdicts`` / ``verdicts_batch``. So a client reads only its own answers, and a slow
one cannot make the others lose theirs (docs/performance.md#reply-topics). A reply
publisher is made at a client's first answer, which waits (bounded) until the readers
of that topic the graph shows (the client's subscription) have matched it; it is
destroyed once nobody has read it for a while.
"""

from __future__ import annotations

import copy
import threading
import time
from dataclasses import dataclass

import numpy as np
from grasp_fc_msgs.msg import ContactArrayBatch, ForceClosureVerdict, ForceClosureVerdictArray
from rclpy.duration import Duration
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos_overriding_options import QoSOverridingOptions

from grasp_fc_ros.interface import wire
from grasp_fc_ros.interface.conversions import batch_ids, verdicts_to_array_msg
from grasp_fc_ros.interface.names import (
    VERDICT_QOS,
    VERDICTS_BATCH_TOPIC,
    VERDICTS_TOPIC,
    reply_topic,
)
from grasp_fc_ros.node.incompatible_qos import IncompatibleQoS
from grasp_fc_ros.node.lane import Refusal
from grasp_fc_ros.packed import Verdicts

# How long shutdown waits for readers to acknowledge the answers it publishes (s).
SHUTDOWN_ACK_TIMEOUT_S = 0.5
# How long a client's first answer waits for the client's subscription (known to the
# graph) to match its new reply publisher (s): a reliable, volatile publisher drops what
# it publishes before that. Discovery on one machine takes milliseconds; a client that
# never matches (it died meanwhile) costs this once. Tuned: docs/performance.md#reply-topics.
REPLY_MATCH_WAIT_S = 2.0
# A reply publisher without subscriptions and unused for this long is destroyed (its
# client is gone); a client that comes back gets a new one (s).
REPLY_IDLE_S = 30.0
# How often the node looks for such publishers (s).
REPLY_SWEEP_S = 5.0


@dataclass
class _ReplyPublisher:
    """A client's reply publisher and when it was last used (time.monotonic(), s)."""

    publisher: Publisher
    last_used: float
    matched: bool = False


class Replies:
    """The verdict publishers of a node, and the encoding of batch answers.

    Parameters
    ----------
    node : Node
    serialized : bool
        Publish batch answers as bytes written by :mod:`~grasp_fc_ros.interface.wire`
        (rclpy spends much longer converting a large one, holding the GIL:
        docs/performance.md#wire-format), else as messages.

    incompatible_qos : IncompatibleQoS, optional
        Counts the subscriptions whose QoS the publishers cannot match.

    Users may set history, depth and reliability of the shared topics from parameters
    (``qos_overrides.<topic>.publisher.<policy>``); the reply topics take
    :data:`~grasp_fc_ros.interface.names.VERDICT_QOS`.
    """

    def __init__(self, node: Node, serialized: bool,
                 incompatible_qos: IncompatibleQoS | None = None):
        self.serialized = serialized
        self._incompatible_qos = incompatible_qos
        # rclpy writes the overrides into the profile it is given: give it copies, or
        # one topic's override would change the module's profile for every later one.
        overridable = QoSOverridingOptions.with_default_policies()
        self._node = node
        self._verdicts = self._publisher(ForceClosureVerdict, VERDICTS_TOPIC, overridable)
        self._batches = self._publisher(ForceClosureVerdictArray, VERDICTS_BATCH_TOPIC,
                                        overridable)
        self._lock = threading.Lock()
        self._to_clients: dict[tuple[str, int], _ReplyPublisher] = {}
        self._sweeper = node.create_timer(REPLY_SWEEP_S, self.sweep)

    def _publisher(self, msg_type: type, topic: str,
                   overridable: QoSOverridingOptions | None = None) -> Publisher:
        """A publisher of ``topic`` with VERDICT_QOS (and the users' overrides, if
        ``overridable``); its incompatible subscriptions counted."""
        qos = copy.copy(VERDICT_QOS)
        events = (None if self._incompatible_qos is None else PublisherEventCallbacks(
            incompatible_qos=self._incompatible_qos.on_subscription(topic, qos)))
        return self._node.create_publisher(msg_type, topic, qos, event_callbacks=events,
                                           qos_overriding_options=overridable)

    def publish_verdict(self, reply: ForceClosureVerdict | bytes) -> None:
        """Publish the verdict answering one single query, to its asker."""
        client_id = wire.verdict_ids(reply)[0] if isinstance(reply, bytes) else reply.client_id
        if client_id:
            self._reply_publisher(VERDICTS_TOPIC, ForceClosureVerdict, client_id).publish(reply)
        else:
            self._verdicts.publish(reply)

    def publish_batch(self, answer: ForceClosureVerdictArray | bytes) -> None:
        """Publish the answer to one batch, to its asker."""
        client_id = wire.verdict_ids(answer)[0] if isinstance(answer, bytes) else answer.client_id
        if client_id:
            self._reply_publisher(VERDICTS_BATCH_TOPIC, ForceClosureVerdictArray,
                                  client_id).publish(answer)
        else:
            self._batches.publish(answer)

    def _reply_publisher(self, topic: str, msg_type: type, client_id: int) -> Publisher:
        """The publisher of ``client_id``'s answers on ``topic``'s reply topic: made
        (and waited for, :data:`REPLY_MATCH_WAIT_S`) at its first use."""
        key = (topic, client_id)
        now = time.monotonic()
        with self._lock:
            entry = self._to_clients.get(key)
            if entry is None:
                entry = self._to_clients[key] = _ReplyPublisher(
                    self._publisher(msg_type, reply_topic(topic, client_id)), now)
            entry.last_used = now
        if not entry.matched:
            # Only for the readers the graph knows: a query whose client_id nobody reads
            # (a plain subscriber of the shared topic set one) must not cost a wait.
            readers = self._node.count_subscribers(entry.publisher.topic_name)
            deadline = now + REPLY_MATCH_WAIT_S
            while (entry.publisher.get_subscription_count() < readers
                   and time.monotonic() < deadline):
                time.sleep(0.001)
            entry.matched = True
        return entry.publisher

    @property
    def reply_topics(self) -> int:
        """Reply publishers the node holds (about two per client)."""
        with self._lock:
            return len(self._to_clients)

    def sweep(self) -> None:
        """Destroy the reply publishers of clients gone for :data:`REPLY_IDLE_S`."""
        now = time.monotonic()
        with self._lock:
            gone = [key for key, entry in self._to_clients.items()
                    if now - entry.last_used > REPLY_IDLE_S
                    and not entry.publisher.get_subscription_count()]
            publishers = [self._to_clients.pop(key).publisher for key in gone]
        for publisher in publishers:
            self._node.destroy_publisher(publisher)

    def batch_answer(self, verdicts: Verdicts, query: ContactArrayBatch
                     ) -> ForceClosureVerdictArray | bytes:
        """The verdict array answering batch ``query``: its header and ids copied."""
        if self.serialized:
            return wire.encode_verdict_array(query.header, query.client_id, query.request_id,
                                             verdicts)
        return verdicts_to_array_msg(verdicts, query)

    def batch_refusal(self, query: ContactArrayBatch, refusal: Refusal
                      ) -> ForceClosureVerdictArray | bytes:
        """The answer refusing every grasp of batch ``query`` with ``refusal``."""
        return self.batch_answer(refused_verdicts(query, refusal), query)

    def wait_for_acks(self, timeout_s: float = SHUTDOWN_ACK_TIMEOUT_S) -> None:
        """Wait (bounded) until the readers have acknowledged what was published."""
        with self._lock:
            replies = [entry.publisher for entry in self._to_clients.values()]
        deadline = time.monotonic() + timeout_s
        for publisher in (self._verdicts, self._batches, *replies):
            publisher.wait_for_all_acked(
                Duration(seconds=max(deadline - time.monotonic(), 0.0)))


def refused_verdicts(query: ContactArrayBatch, refusal: Refusal) -> Verdicts:
    """Every grasp of batch ``query`` (by its ids) answered with ``refusal``, in bulk
    (one message shared by all).

    A batch with contact counts and no ids gets one verdict (id 0), so that the answer
    still carries the reason.
    """
    ids = batch_ids(query)
    if not len(ids) and len(query.contact_counts):
        ids = np.zeros(1, np.uint64)
    return Verdicts.failed(ids, refusal.status, refusal.message)
