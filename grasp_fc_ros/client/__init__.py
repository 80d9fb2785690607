"""Talk to a running ``force_closure`` node from Python: :class:`GraspClient`.

Imports only :mod:`grasp_fc_ros.interface` (names, QoS, conversions) and the data types
of :mod:`grasp_fc_ros.engine.evaluation`: never the node, its worker pool or its markers.
"""

from .grasp_client import GraspClient, request_on_spin_thread

__all__ = ["GraspClient", "request_on_spin_thread"]
