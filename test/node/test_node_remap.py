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
