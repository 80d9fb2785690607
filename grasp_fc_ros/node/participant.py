"""A DDS participant of its own for the node's batch topic and action.

A batch message of tens of MB, published as one message by a plain rclpy publisher (or
a goal that large from a plain action client), overflowed Fast DDS's shared-memory port
of the participant it was sent to; service requests queued on the same port were lost
with it and repaired by reliability seconds later
(docs/performance.md#raw-one-message-batches). rmw_fastrtps makes one participant per
rclpy context, with its own shared-memory port, so the node subscribes to
``contacts_batch`` from a second context and a helper node on it, ``<name>_batches``
in the node's (possibly remapped) namespace, and serves ``label_grasps`` from that
context too (:mod:`.label_action`): a big batch or goal floods that port only, and the
services' and single queries' requests keep theirs.

To users the subscription is the node's: its topic name is resolved by the node (its
remappings and namespace apply as to the other topics), and its QoS overrides are the
node's parameters (``qos_overrides./<ns>/contacts_batch.subscription.<policy>``). The
second context takes the node's domain id and no command-line arguments (no
``--enclave``: security settings reach it through the environment only).
"""

from __future__ import annotations

from rclpy.context import Context
from rclpy.node import Node
from rclpy.qos import QoSProfile

# _declare_qos_parameters: rclpy declares a subscription's QoS override parameters with it
# on the node that creates the subscription; here it is called on the force_closure node,
# whose parameters users set, for a subscription the helper node creates (rclpy is
# pinned in requirements.txt).
from rclpy.qos_overriding_options import QoSOverridingOptions, _declare_qos_parameters
from rclpy.subscription import Subscription


class BatchParticipant:
    """A second rclpy context, i.e. a second DDS participant, and a helper node on it,
    for the batch topic and the action.

    Parameters
    ----------
    node : Node
        The force_closure node: its name, namespace, domain id, remappings and
        parameters.

    Attributes
    ----------
    context : rclpy.context.Context
        The second context (shut down by :meth:`close`).
    node : Node
        The helper node, which no executor spins (its subscriptions are taken by loops of
        their own, :class:`~grasp_fc_ros.interface.wait_sets.SubscriptionLoop`).
    """

    def __init__(self, node: Node):
        self._owner = node
        self._closed = False
        self.context = Context()
        self.context.init([], initialize_logging=False,
                           domain_id=node.context.get_domain_id())
        try:
            self.node = Node(f"{node.get_name()}_batches", namespace=node.get_namespace(),
                             context=self.context, use_global_arguments=False,
                             start_parameter_services=False, enable_rosout=False)
        except BaseException:
            self.context.try_shutdown()
            raise

    def subscription_topic(self, topic: str, qos: QoSProfile,
                           options: QoSOverridingOptions) -> tuple[str, QoSProfile]:
        """The node's name for ``topic`` and ``qos`` with the node's QoS overrides for a
        subscription to it (declared as the node's parameters), to subscribe with from
        :attr:`node`.

        ``qos`` is changed in place (as ``Node.create_subscription`` does) and returned.

        Raises
        ------
        rclpy.qos_overriding_options.InvalidQosOverridesError, ParameterException
            For overrides rclpy refuses, as it would for the node's own subscription.
        """
        resolved = self._owner.resolve_topic_name(topic)
        _declare_qos_parameters(Subscription, self._owner, resolved, qos, options)
        return resolved, qos

    def close(self) -> None:
        """Destroy the helper node (its subscriptions with it) and shut its context down
        (a second call does nothing)."""
        if self._closed:
            return
        self._closed = True
        self.node.destroy_node()
        self.context.try_shutdown()
