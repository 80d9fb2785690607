"""The client's watch on its node: is it there, did it restart, what does it report.

:class:`NodeWatch` looks for the node on the query topics every :data:`WATCH_PERIOD_S`
and, when a node newly subscribes to them (a restarted node has not seen what was sent
to its predecessor), has every unanswered query published again; otherwise, while a
node is there, the queries that are due (unanswered for their bound, or whose publish
failed: :mod:`.pending`). A duplicate answer (both nodes saw it) is ignored by id.
:class:`ActionServerWatch` tells a label_grasps job when a new action server appears (the
node restarted) and since when none is there (it went away).
:class:`DiagnosticsReader` keeps the node's latest /diagnostics key values.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.client import Client
from rclpy.node import Node
from rclpy.publisher import Publisher

from grasp_fc_ros.interface.names import DIAGNOSTICS_TOPIC, resolve

# How often the client looks for a (re)started node on the query topics (s).
WATCH_PERIOD_S = 0.25
# Grace period after matching: DDS matches the two directions at different moments.
MATCH_GRACE_S = 0.3


class NodeWatch:
    """Wait for the node; publish the unanswered queries again when it (re)appears.

    Parameters
    ----------
    node : Node
        The client's node (its timer runs on the client's executor).
    publishers : list of Publisher
        The query publishers: the node is there when each has a subscription.
    verdict_topics : list of str
        The node's answer topics: the node is there when each has a publisher.
    service : rclpy.client.Client
        The check_force_closure client, looked for first.
    resend : callable (everything: bool) -> int
        Publishes again every unanswered query (True) or those due (False); returns
        how many grasps it sent.
    """

    def __init__(self, node: Node, publishers: list[Publisher], verdict_topics: list[str],
                 service: Client, resend: Callable[[bool], int]):
        self._node = node
        self._publishers = publishers
        self._verdict_topics = verdict_topics
        self._service = service
        self._resend = resend
        self._lock = threading.Lock()
        self._matched = 0
        self.resubmitted = 0
        self._timer = node.create_timer(WATCH_PERIOD_S, self._watch)

    def wait(self, timeout: float) -> bool:
        """Wait until the node's service and both directions of its topics are matched."""
        deadline = time.monotonic() + timeout
        if not self._service.wait_for_service(timeout_sec=timeout):
            return False
        while time.monotonic() < deadline:
            if (all(p.get_subscription_count() for p in self._publishers)
                    and all(self._node.count_publishers(t) for t in self._verdict_topics)):
                # This node is known now: only a later one is a (re)appearance.
                self._seen(self._publishers[0].get_subscription_count())
                time.sleep(MATCH_GRACE_S)
                return True
            time.sleep(0.02)
        return False

    def _seen(self, matched: int) -> bool:
        """Record that ``matched`` nodes subscribe to the queries; True if more than
        before."""
        with self._lock:
            grew, self._matched = matched > self._matched, matched
            return grew

    def _watch(self) -> None:
        matched = self._publishers[0].get_subscription_count()
        if self._seen(matched):
            time.sleep(MATCH_GRACE_S)
            self.resubmitted += self._resend(True)
        elif matched:
            self.resubmitted += self._resend(False)


class ActionServerWatch:
    """The label_grasps action servers in the ROS graph: a new one, or none at all.

    A server is known by the endpoint GID of its status publisher
    (``<action>/_action/status``), which a restarted node gets anew. A SIGKILLed node's
    server stays in the graph until its DDS participant's lease runs out (Fast DDS:
    20 s), so a node restarted within that time shows as a new server beside the old
    one, and one that is not shows as none at all.

    Parameters
    ----------
    node : Node
        The client's node (its graph is read from the calling thread).
    action_name : str
        The action's full name.
    """

    def __init__(self, node: Node, action_name: str):
        self._node = node
        self._topic = f"{action_name}/_action/status"
        self._seen = self._servers()
        self._polled = time.monotonic()
        self.gone_since: float | None = None if self._seen else self._polled

    def _servers(self) -> set[tuple[int, ...]]:
        return {tuple(info.endpoint_gid)
                for info in self._node.get_publishers_info_by_topic(self._topic)}

    def poll(self) -> bool:
        """Look at the graph (at most once a :data:`WATCH_PERIOD_S`); whether a server
        not seen before has appeared. :attr:`gone_since` is then when the last server
        left the graph (``time.monotonic()``), or None while one is there."""
        now = time.monotonic()
        if now - self._polled < WATCH_PERIOD_S:
            return False
        self._polled = now
        servers = self._servers()
        new = bool(servers - self._seen)
        self._seen |= servers
        if servers:
            self.gone_since = None
        elif self.gone_since is None:
            self.gone_since = now
        return new


class DiagnosticsReader:
    """The key values of the node's latest /diagnostics status.

    Parameters
    ----------
    node : Node
    node_name : str
        The force_closure node's full name: its status's name starts with it.
    """

    def __init__(self, node: Node, node_name: str):
        self._prefix = resolve(node_name, node_name.rpartition("/")[2]) + ":"
        self._latest: dict[str, str] = {}
        self._ready = threading.Condition()
        node.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, self._on_diagnostics, 10)

    @property
    def latest(self) -> dict[str, str]:
        with self._ready:
            return dict(self._latest)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.startswith(self._prefix):
                with self._ready:
                    self._latest = {kv.key: kv.value for kv in status.values}
                    self._ready.notify_all()

    def next(self, timeout: float) -> dict[str, str]:
        """The node's next /diagnostics key values (it publishes about once a second)."""
        with self._ready:
            self._latest = {}
            if not self._ready.wait_for(lambda: self._latest, timeout):
                raise TimeoutError(f"no diagnostics of {self._prefix[:-1]} within {timeout} s")
            return dict(self._latest)
