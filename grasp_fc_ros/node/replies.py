"""Where the node's topic answers go, and how they are encoded.

Single verdicts go out on ``verdicts`` (one ForceClosureVerdict per query), batch
answers on ``verdicts_batch`` (one ForceClosureVerdictArray per batch), both with
:data:`~grasp_fc_ros.interface.names.VERDICT_QOS`; serialized by
:mod:`grasp_fc_ros.interface.wire` where this rmw's layout is the one it writes.
"""

from __future__ import annotations

import copy

from grasp_fc_msgs.msg import ContactArrayBatch, ForceClosureVerdict, ForceClosureVerdictArray
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos_overriding_options import QoSOverridingOptions

from grasp_fc_ros.engine.packed import Verdicts
from grasp_fc_ros.interface import wire
from grasp_fc_ros.interface.conversions import batch_ids, verdicts_to_array_msg
from grasp_fc_ros.interface.names import VERDICT_QOS, VERDICTS_BATCH_TOPIC, VERDICTS_TOPIC
from grasp_fc_ros.node.lane import Refusal

# How long shutdown waits for readers to acknowledge the answers it publishes (s).
SHUTDOWN_ACK_TIMEOUT_S = 0.5


class Replies:
    """The verdict publishers of a node, and the encoding of batch answers.

    Parameters
    ----------
    node : Node
    serialized : bool
        Publish batch answers as bytes written by :mod:`~grasp_fc_ros.interface.wire`
        (rclpy spends much longer converting a large one, holding the GIL:
        docs/performance.md#wire-format), else as messages.

    Users may set history, depth and reliability of both topics from parameters
    (``qos_overrides.<topic>.publisher.<policy>``).
    """

    def __init__(self, node: Node, serialized: bool):
        self.serialized = serialized
        # rclpy writes the overrides into the profile it is given: give it copies, or
        # one topic's override would change the module's profile for every later one.
        overridable = QoSOverridingOptions.with_default_policies()
        self._verdicts = node.create_publisher(ForceClosureVerdict, VERDICTS_TOPIC,
                                               copy.copy(VERDICT_QOS),
                                               qos_overriding_options=overridable)
        self._batches = node.create_publisher(ForceClosureVerdictArray, VERDICTS_BATCH_TOPIC,
                                              copy.copy(VERDICT_QOS),
                                              qos_overriding_options=overridable)

    def publish_verdict(self, reply: ForceClosureVerdict | bytes) -> None:
        """Publish the verdict answering one single query."""
        self._verdicts.publish(reply)

    def publish_batch(self, answer: ForceClosureVerdictArray | bytes) -> None:
        """Publish the answer to one batch."""
        self._batches.publish(answer)

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
        for publisher in (self._verdicts, self._batches):
            publisher.wait_for_all_acked(Duration(seconds=timeout_s))


def refused_verdicts(query: ContactArrayBatch, refusal: Refusal) -> Verdicts:
    """Every grasp of batch ``query`` (by its ids) answered with ``refusal``."""
    return Verdicts.failed(batch_ids(query), refusal.status, refusal.message)
