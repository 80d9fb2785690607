"""Talk to a running ``force_closure`` node from Python: :class:`GraspClient`.

Imports only :mod:`grasp_fc_ros.interface` (names, QoS, conversions) and the data types
of the engine (:class:`Verdicts`, :class:`ContactForces`, which its methods return):
never the node, its worker pool or its markers.
"""

from grasp_fc_ros.engine.contact_forces import ContactForces
from grasp_fc_ros.engine.packed import Verdicts

from .grasp_client import GraspClient, request_on_spin_thread

__all__ = ["ContactForces", "GraspClient", "Verdicts", "request_on_spin_thread"]
