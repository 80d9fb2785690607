"""Fixtures shared by the ROS tests (test_node*.py, test_client*.py).

rclpy is imported inside the fixtures only, so the core tests stay free of ROS.
"""

from __future__ import annotations

import atexit

import pytest


@pytest.fixture(scope="session")
def ros():
    """rclpy initialised once for the whole run, on this run's own ROS_DOMAIN_ID."""
    import rclpy

    import ros_fixtures  # noqa: F401 - sets ROS_DOMAIN_ID before rclpy starts

    if not rclpy.ok():
        rclpy.init()
        atexit.register(rclpy.try_shutdown)


@pytest.fixture
def own_node(ros):
    """Factory: make_node(namespace, pool=None, **parameters) -> (node, spinner, client).

    A ForceClosureNode of its own in ``namespace`` (so no other node answers), spun on
    its own thread, with a connected raw-protocol client; both torn down after the test
    (and ``pool``, the node's pool if given, closed).
    """
    from rclpy.parameter import Parameter

    from grasp_fc_ros.node import ForceClosureNode
    from ros_fixtures import Client, SpinThread

    made = []

    def make_node(namespace, pool=None, **parameters):
        node = ForceClosureNode(namespace=namespace, pool=pool, parameter_overrides=[
            Parameter(name, value=value) for name, value in parameters.items()])
        spinner = SpinThread(node)
        client = Client(f"{namespace.strip('/')}_client", namespace=namespace)
        made.append((spinner, client, pool))
        client.wait_connected(node=node)
        return node, spinner, client

    yield make_node
    for spinner, client, pool in made:
        client.close()
        spinner.stop()
        if pool is not None:
            pool.close()
