"""The node's /diagnostics: its statistics and its lanes' counts, once a second.

One ``diagnostic_msgs/DiagnosticStatus`` named ``<node's full name>: force-closure
queries``: WARN while any solver failure or internal error has been counted, while a
peer with incompatible QoS is there, or while the node reports a warning (fewer worker
processes running than configured), else OK;
its key values are :meth:`~grasp_fc_ros.node.statistics.Statistics.key_values` plus
every lane's :meth:`~grasp_fc_ros.node.lane.Lane.counts` and the node's own counts
(worker processes replaced, messages lost at its subscriptions), and the peers whose QoS
cannot match the node's (:mod:`.incompatible_qos`). The same timer warns once when
another node has this node's name.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node

from grasp_fc_ros.interface.names import DIAGNOSTICS_TOPIC
from grasp_fc_ros.node.incompatible_qos import IncompatibleQoS
from grasp_fc_ros.node.lane import Lane
from grasp_fc_ros.node.statistics import Statistics

DIAGNOSTICS_PERIOD_S = 1.0


class Diagnostics:
    """Publishes the node's diagnostics from a timer on the node's executor.

    Parameters
    ----------
    node : Node
    statistics : Statistics
    lanes : callable () -> sequence of Lane
        The lanes whose counts are reported (read at each publication).
    on_error : callable(what, exception)
        Told about a publication that failed (diagnostics never stop the node).
    node_counts : callable () -> dict of str to int, optional
        Counts of the node itself, beside the lanes' (read at each publication).
    incompatible_qos : IncompatibleQoS, optional
        The peers whose QoS cannot match the node's endpoints.
    node_warnings : callable () -> list of str, optional
        What is wrong with the node now, one phrase each (read at each publication):
        the status is WARN and its message says them while any.
    """

    def __init__(self, node: Node, statistics: Statistics, lanes: Callable[[], Sequence[Lane]],
                 on_error: Callable[[str, Exception], None],
                 node_counts: Callable[[], dict[str, int]] = dict,
                 incompatible_qos: IncompatibleQoS | None = None,
                 node_warnings: Callable[[], list[str]] = list):
        self._node = node
        self._incompatible_qos = incompatible_qos
        self._statistics = statistics
        self._lanes = lanes
        self._node_counts = node_counts
        self._node_warnings = node_warnings
        self._on_error = on_error
        self._duplicate_warned = False
        self._publisher = node.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, 10)
        self._timer = node.create_timer(DIAGNOSTICS_PERIOD_S, self._on_timer)

    def _on_timer(self) -> None:
        self.publish()
        self._check_duplicate_name()

    def status(self) -> DiagnosticStatus:
        """The node's diagnostic status now."""
        failures = self._statistics.failures()
        counts: dict[str, int] = {}
        for lane in self._lanes():
            counts.update(lane.counts())
        counts.update(self._node_counts())
        values = self._statistics.key_values(counts)
        problems = [f"{failures} solver failures or internal errors"] if failures else []
        if self._incompatible_qos is not None:
            values += [KeyValue(key=key, value=value)
                       for key, value in self._incompatible_qos.key_values().items()]
            problems += self._incompatible_qos.problems()
        problems += self._node_warnings()
        return DiagnosticStatus(
            level=DiagnosticStatus.WARN if problems else DiagnosticStatus.OK,
            name=f"{self._node.get_fully_qualified_name()}: force-closure queries",
            message="; ".join(problems) or "ok", hardware_id="none", values=values)

    def publish(self) -> None:
        try:
            msg = DiagnosticArray(status=[self.status()])
            msg.header.stamp = self._node.get_clock().now().to_msg()
            self._publisher.publish(msg)
        except Exception as exc:  # noqa: BLE001 - diagnostics must never stop the node
            self._on_error("diagnostics", exc)

    def _check_duplicate_name(self) -> None:
        """Warn (once) when another node has this node's name and namespace."""
        if self._duplicate_warned:
            return
        node = self._node
        me = (node.get_name(), node.get_namespace())
        if node.get_node_names_and_namespaces().count(me) > 1:
            self._duplicate_warned = True
            node.get_logger().warning(
                f"another node is named {node.get_fully_qualified_name()}: both answer every "
                "query; give one another name or namespace (--ros-args -r __ns:=/other)")
