"""The ``force_closure`` ROS 2 node (``grasp-fc-node``, ``python -m grasp_fc_ros.node``).

Where to look:

* :mod:`.force_closure_node` -- the node: its interfaces, the wiring of its lanes;
  to add a lane, make it here (a class with ``stop``, ``drain`` and ``counts``,
  :class:`.lane.Lane`);
* :mod:`.single_queries`, :mod:`.batches`, :mod:`.services`, :mod:`.label_action`
  (goals: :mod:`.label_goal`), :mod:`.marker_lane` -- one lane per interface; to change
  how the services answer, open :mod:`.services`;
* :mod:`.lane` -- what the lanes share: their context, refusals, their threads;
* :mod:`.replies` -- where the topic answers go;
* :mod:`.parameters` -- the parameters, with descriptors, checks and live values;
* :mod:`.diagnostics`, :mod:`.statistics` -- what the node reports on /diagnostics;
* :mod:`.cli` -- the command line and the spin loop.

A new contact model is not the node's business: it goes in :mod:`grasp_fc_ros.core`,
its message fields through :mod:`grasp_fc_ros.interface.conversions`.
"""

from .cli import main, shutdown_rclpy
from .force_closure_node import ForceClosureNode
from .parameters import PARAMETERS, check_parameter

__all__ = ["PARAMETERS", "ForceClosureNode", "check_parameter", "main", "shutdown_rclpy"]
