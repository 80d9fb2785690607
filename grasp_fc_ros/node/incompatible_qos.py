"""Peers whose QoS cannot match the node's: counted for /diagnostics, not only logged.

A publisher of queries whose QoS the node's subscription cannot accept (e.g.
BEST_EFFORT on ``contacts``, where the node requires RELIABLE), or a subscriber of
answers asking more than the node's publisher offers (e.g. TRANSIENT_LOCAL on
``verdicts``), is never matched: its queries get no answer, or it hears none. DDS
reports each such peer once, when it is discovered (rclpy's incompatible-QoS events),
and never when it goes; so an event only marks a topic to watch, and the count is
taken from the ROS graph at each diagnostics publication: the endpoints on that topic
whose QoS :func:`rclpy.qos.qos_check_compatible` finds incompatible with the node's.
A topic with none for :data:`FORGET_AFTER_S` since its last event is no longer watched,
so the count falls back to 0, and /diagnostics to OK, once the peer has gone.
"""

from __future__ import annotations

import copy
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from rclpy.duration import Duration, Infinite
from rclpy.event_handler import QoSOfferedIncompatibleQoSInfo, QoSRequestedIncompatibleQoSInfo
from rclpy.node import Node
from rclpy.qos import (
    LivelinessPolicy,
    QoSCompatibility,
    QoSProfile,
    qos_check_compatible,
    qos_policy_name_from_kind,
)

from grasp_fc_ros.node.statistics import Throttle

# How long a topic stays watched after its last incompatible-QoS event while the graph
# shows no incompatible peer on it (s): the event and the graph's record of the peer
# come from DDS discovery separately, in either order.
FORGET_AFTER_S = 10.0
# The peers counted: publishers of a topic the node subscribes, subscriptions of a
# topic it publishes.
PUBLISHERS = "publishers"
SUBSCRIPTIONS = "subscribers"


@dataclass
class _Watched:
    """A topic of the node with an incompatible peer seen: the node's QoS on it, the
    policies its events named, when the last came."""

    qos: QoSProfile
    policies: set[str] = field(default_factory=set)
    last_event: float = 0.0
    peers: int = 0  # incompatible peers at the last count


class IncompatibleQoS:
    """Incompatible-QoS peers of the node's endpoints: event callbacks and the count.

    Parameters
    ----------
    node : Node
        The node whose graph is read and whose logger warns.
    may_log : Throttle
        Decides whether a warning of a given key may be logged now.
    """

    def __init__(self, node: Node, may_log: Throttle):
        self._node = node
        self._may_log = may_log
        self._lock = threading.Lock()
        self._watched: dict[tuple[str, str], _Watched] = {}

    def on_publisher(self, topic: str, qos: QoSProfile
                     ) -> Callable[[QoSRequestedIncompatibleQoSInfo], None]:
        """The ``incompatible_qos`` callback of the node's subscription to ``topic``
        with ``qos`` (the profile object it is created with: overrides are written
        into it)."""
        return self._callback(PUBLISHERS, topic, qos)

    def on_subscription(self, topic: str, qos: QoSProfile
                        ) -> Callable[[QoSOfferedIncompatibleQoSInfo], None]:
        """The ``incompatible_qos`` callback of the node's publisher on ``topic``."""
        return self._callback(SUBSCRIPTIONS, topic, qos)

    def _callback(self, kind: str, topic: str, qos: QoSProfile) -> Callable[[object], None]:
        resolved = self._node.resolve_topic_name(topic)

        def on_incompatible(info: object) -> None:
            policy = qos_policy_name_from_kind(getattr(info, "last_policy_kind", 0))
            with self._lock:
                watched = self._watched.setdefault((kind, resolved), _Watched(qos))
                watched.policies.add(policy)
                watched.last_event = time.monotonic()
            if self._may_log(f"incompatible {kind} {resolved}"):
                peer = "publisher" if kind == PUBLISHERS else "subscription"
                self._node.get_logger().warning(
                    f"a {peer} on {resolved} has QoS incompatible with the node's "
                    f"({policy}): it is not matched, so it "
                    f"{'gets no answer' if kind == PUBLISHERS else 'hears nothing'} "
                    "(counted on /diagnostics; the node's QoS: docs/node.rst)")

        return on_incompatible

    def key_values(self) -> dict[str, str]:
        """``incompatible_qos_publishers`` and ``incompatible_qos_subscribers``: how many
        such peers the graph shows now, with the policies named, e.g. ``"1
        (RELIABILITY)"``; ``"0"`` when none."""
        self._count()
        with self._lock:
            values = {}
            for kind in (PUBLISHERS, SUBSCRIPTIONS):
                found = [w for (k, _), w in self._watched.items() if k == kind and w.peers]
                peers = sum(w.peers for w in found)
                policies = sorted({policy for w in found for policy in w.policies})
                values[f"incompatible_qos_{kind}"] = (
                    f"{peers} ({', '.join(policies)})" if peers else "0")
        return values

    def problems(self) -> list[str]:
        """One line per topic with incompatible peers now (from the last count), for the
        diagnostics message."""
        with self._lock:
            return [f"{kind} with incompatible QoS on {topic}: {w.peers} "
                    f"({', '.join(sorted(w.policies))})"
                    for (kind, topic), w in sorted(self._watched.items()) if w.peers]

    def _count(self) -> None:
        """Count the incompatible peers of every watched topic in the graph; forget the
        topics with none for FORGET_AFTER_S."""
        with self._lock:
            watched = list(self._watched.items())
        now = time.monotonic()
        for (kind, topic), entry in watched:
            if kind == PUBLISHERS:
                peers = [info.qos_profile
                         for info in self._node.get_publishers_info_by_topic(topic)]
                pairs = [(peer, entry.qos) for peer in peers]
            else:
                peers = [info.qos_profile
                         for info in self._node.get_subscriptions_info_by_topic(topic)]
                pairs = [(entry.qos, peer) for peer in peers]
            count = sum(qos_check_compatible(as_discovered(publisher),
                                             as_discovered(subscription))[0]
                        == QoSCompatibility.ERROR for publisher, subscription in pairs)
            with self._lock:
                entry.peers = count
                if not count and now - entry.last_event > FORGET_AFTER_S:
                    self._watched.pop((kind, topic), None)


def as_discovered(qos: QoSProfile) -> QoSProfile:
    """``qos`` as the ROS graph shows an endpoint made with it: durations left unset
    are infinite there and liveliness left to the system is automatic (the DDS
    defaults). Compared unset, :func:`qos_check_compatible` finds every discovered peer
    incompatible ("subscription has a deadline, but publisher does not")."""
    shown = copy.copy(qos)
    for policy in ("deadline", "lifespan", "liveliness_lease_duration"):
        if getattr(shown, policy) == Duration():
            setattr(shown, policy, Infinite)
    if shown.liveliness == LivelinessPolicy.SYSTEM_DEFAULT:
        shown.liveliness = LivelinessPolicy.AUTOMATIC
    return shown
