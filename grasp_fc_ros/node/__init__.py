"""The ``force_closure`` ROS 2 node (``grasp-fc-node``, ``python -m grasp_fc_ros.node``).

* :mod:`.force_closure_node` -- the node: wiring of its interfaces to its lanes;
* :mod:`.parameters` -- its parameters, with descriptors and checks;
* :mod:`.statistics` -- what it counts for /diagnostics;
* :mod:`.cli` -- the command line and the spin loop.
"""

from .cli import main, shutdown_rclpy
from .force_closure_node import ForceClosureNode
from .parameters import PARAMETERS, check_parameter

__all__ = ["PARAMETERS", "ForceClosureNode", "check_parameter", "main", "shutdown_rclpy"]
