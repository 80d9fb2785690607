"""Command-line remappings reach the service too (it is served by a helper node)."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from rclpy.parameter import Parameter

from grasp_fc_ros.core import Status
from grasp_fc_ros.interface.conversions import grasp_to_contact_array
from grasp_fc_ros.node import ForceClosureNode
from ros_fixtures import DISCOVERY_TIMEOUT_S, REPLY_TIMEOUT_S, SpinThread

# Four fingers on a unit sphere: force closure at mu 0.5.
POSITIONS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]], dtype=float)


def call(node, service_name: str):
    """Call ``service_name`` once with the grasp above from ``node``; its verdicts."""
    from grasp_fc_msgs.srv import CheckForceClosure

    client = node.create_client(CheckForceClosure, service_name)
    assert client.wait_for_service(timeout_sec=DISCOVERY_TIMEOUT_S), f"{service_name} not found"
    request = CheckForceClosure.Request(grasps=[grasp_to_contact_array(7, POSITIONS, -POSITIONS)])
    done = threading.Event()
    future = client.call_async(request)
    future.add_done_callback(lambda _: done.set())
    assert done.wait(REPLY_TIMEOUT_S), f"{service_name}: no response"
    return future.result().verdicts


@pytest.mark.parametrize("rules, expected", [
    (["__ns:=/remap_ns", "check_force_closure:=renamed_check"], "/remap_ns/renamed_check"),
    (["__ns:=/remap_node_ns", "force_closure:check_force_closure:=/absolute_check"],
     "/absolute_check"),
    (["__ns:=/remap_only_ns"], "/remap_only_ns/check_force_closure"),
])
def test_service_follows_the_nodes_remappings(ros, rules, expected):
    from rclpy.node import Node

    cli_args = ["--ros-args"] + [arg for rule in rules for arg in ("-r", rule)]
    node = ForceClosureNode(cli_args=cli_args, parameter_overrides=[Parameter("workers", value=0)])
    spinner = SpinThread(node)
    caller = SpinThread(Node("remap_test_caller"))
    try:
        verdicts = call(caller.node, expected)
        assert [(v.id, v.status) for v in verdicts] == [(7, Status.FORCE_CLOSURE)]
        # The unremapped name is not served (in the node's namespace or at the root).
        services = {name for name, _ in caller.node.get_service_names_and_types()}
        for stale in {node.get_namespace().rstrip("/") + "/check_force_closure",
                      "/check_force_closure"} - {expected}:
            assert stale not in services
    finally:
        caller.stop()
        spinner.stop()


def subscriptions_of(node, topic: str) -> list:
    """The graph's subscriptions to ``topic`` (TopicEndpointInfo), as :func:`known_endpoints`."""
    return known_endpoints(node.get_subscriptions_info_by_topic, topic)


def known_endpoints(info_by_topic, topic: str) -> list:
    """``info_by_topic(topic)`` (TopicEndpointInfo), once there is one and the graph knows
    the nodes of all (an endpoint can be seen before its participant's node names:
    "_NODE_NAME_UNKNOWN_")."""
    import time

    deadline = time.monotonic() + DISCOVERY_TIMEOUT_S
    while True:
        found = info_by_topic(topic)
        if found and not any(info.node_name.startswith("_NODE_NAME_UNKNOWN") for info in found):
            return found
        assert time.monotonic() < deadline, f"no known endpoint of {topic}: {found}"
        time.sleep(0.05)


@pytest.mark.parametrize("rules, expected", [
    (["__ns:=/batch_remap_ns", "contacts_batch:=renamed_batch"],
     "/batch_remap_ns/renamed_batch"),
    (["__ns:=/batch_only_ns"], "/batch_only_ns/contacts_batch"),
])
def test_batch_topic_and_action_are_on_a_participant_of_their_own(
        ros, rules, expected):
    """contacts_batch is subscribed by the helper force_closure_batches on another DDS
    participant than the node's other topics (an endpoint's gid begins with its
    participant's 12-byte GUID prefix), under the name the node resolves; the action
    is served on that participant too."""
    from rclpy.node import Node

    cli_args = ["--ros-args"] + [arg for rule in rules for arg in ("-r", rule)]
    node = ForceClosureNode(cli_args=cli_args, parameter_overrides=[Parameter("workers", value=0)])
    spinner = SpinThread(node)
    watcher = Node("batch_remap_watcher")
    try:
        [batch] = subscriptions_of(watcher, expected)
        [single] = subscriptions_of(watcher, f"{node.get_namespace()}/contacts")
        assert (batch.node_name, batch.node_namespace) == (
            "force_closure_batches", node.get_namespace())
        assert single.node_name == "force_closure"
        assert bytes(batch.endpoint_gid[:12]) != bytes(single.endpoint_gid[:12])
        # The action is served on the same participant as the batch topic.
        [status] = known_endpoints(
            watcher.get_publishers_info_by_topic,
            f"{node.get_namespace()}/label_grasps/_action/status")
        assert status.node_name == "force_closure_action"
        assert bytes(status.endpoint_gid[:12]) == bytes(batch.endpoint_gid[:12])
        if expected.endswith("renamed_batch"):
            assert not watcher.get_subscriptions_info_by_topic(
                f"{node.get_namespace()}/contacts_batch")
    finally:
        watcher.destroy_node()
        spinner.stop()
