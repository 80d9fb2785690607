"""The node's side of its RViz markers: offers of answered queries, ``clear_markers``.

The markers are built and published by a process of its own
(:mod:`grasp_fc_ros.markers.publisher`), started when ``publish_markers`` turns on; the
lanes offer every answered message here *after* its verdicts are out. An offer only
queues a reference; one that fails is logged and counted, never a lost verdict.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from grasp_fc_msgs.msg import ContactArray, ContactArrayBatch
from rclpy.node import Node
from std_srvs.srv import Empty

from grasp_fc_ros.interface.names import CLEAR_MARKERS_SERVICE
from grasp_fc_ros.markers.publisher import (
    MarkerProcess,
    MarkerPublisher,
    MarkerSettings,
    MarkerSink,
)
from grasp_fc_ros.node.lane import Drained
from grasp_fc_ros.node.parameters import LiveParameters
from grasp_fc_ros.packed import Verdicts


class MarkerLane:
    """Offers answered messages to a :class:`~grasp_fc_ros.markers.publisher.MarkerPublisher`
    while ``publish_markers`` is on, and serves ``clear_markers``.

    Parameters
    ----------
    node : Node
    parameters : LiveParameters
        The marker settings and the node's default friction, read per offer.
    on_error : callable(what, exception)
        Told about marker work that failed.
    sink : MarkerSink, optional
        Where the markers are built (default: the marker process, a node
        ``<name>_markers`` in the node's namespace).
    """

    def __init__(self, node: Node, parameters: LiveParameters,
                 on_error: Callable[[str, Exception], None], sink: MarkerSink | None = None):
        self._parameters = parameters
        self._on_error = on_error
        self._logger = node.get_logger()
        self.publisher = MarkerPublisher(
            sink or MarkerProcess(node.get_namespace(), f"{node.get_name()}_markers"), on_error)
        node.create_service(Empty, CLEAR_MARKERS_SERVICE, self._on_clear)
        parameters.on_marker_settings(self._settings_changed)
        self._settings_changed(parameters.markers)

    @property
    def enabled(self) -> bool:
        return self._parameters.markers.enabled

    def offer_singles(self, queries: Sequence[ContactArray], replies: Sequence[Any]) -> None:
        """Answered single queries (messages) and their verdict messages."""
        self._offer(self.publisher.offer_singles, queries, replies)

    def offer_serialized_singles(self, raws: Sequence[bytes], verdicts: Verdicts) -> None:
        """Answered single queries taken serialized, and their verdicts."""
        self._offer(self.publisher.offer_serialized_singles, raws, verdicts)

    def offer_service(self, grasps: Sequence[ContactArray], replies: Sequence[Any]) -> None:
        """An answered service request and its verdict messages."""
        self._offer(self.publisher.offer_service, grasps, replies)

    def offer_batch(self, query: ContactArrayBatch, verdicts: Verdicts) -> None:
        """An answered batch and its verdicts."""
        self._offer(self.publisher.offer_batch, query, verdicts)

    def _offer(self, offer: Callable[..., None], queries: Any, answers: Any) -> None:
        settings = self._parameters.markers
        if not settings.enabled:
            return
        try:
            offer(queries, answers, settings, self._parameters.settings.friction_coefficient)
        except Exception as exc:  # noqa: BLE001 - its verdicts are out and counted already
            self._on_error("markers", exc)

    def _settings_changed(self, settings: MarkerSettings) -> None:
        if settings.enabled:
            try:
                self.publisher.start()
            except Exception as exc:  # noqa: BLE001 - the parameter stays set
                self._on_error("markers (marker process not started)", exc)

    def wait_ready(self, timeout_s: float) -> None:
        """With ``publish_markers`` on, wait (at most ``timeout_s``) until the marker
        process can draw: the node does before it says it is ready, so that the markers
        of its first answers do not wait for that process to start (issue 28's target:
        markers within 1 s of an answer). Not ready in time: said in the log; the
        markers follow once it is."""
        if not self.enabled:
            return
        try:
            ready = self.publisher.wait_ready(timeout_s)
        except Exception as exc:  # noqa: BLE001 - the node serves verdicts anyway
            self._on_error("markers (marker process not started)", exc)
            return
        if not ready:
            self._logger.warning(f"the marker process is not ready after {timeout_s:g} s; "
                                 "markers follow once it is")

    def _on_clear(self, request: Empty.Request, response: Empty.Response) -> Empty.Response:
        """std_srvs/Empty: publish a DELETEALL on ``markers`` (queued marker work goes)."""
        self.publisher.clear()
        return response

    def counts(self) -> dict[str, int]:
        return self.publisher.counts()

    def stop(self) -> None:
        """Stop the marker thread and process (queued marker work is discarded)."""
        self.publisher.close()

    def drain(self) -> Drained:
        return Drained()  # markers are best effort: nothing to answer
