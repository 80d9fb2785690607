"""Talk to a running ``force_closure`` node from Python: :class:`GraspClient`.

Imports only :mod:`grasp_fc_ros.interface` (names, QoS, conversions) and the data types
of :mod:`grasp_fc_ros.engine.packed` and :mod:`grasp_fc_ros.engine.contact_forces`
(:class:`Verdicts`, :class:`ContactForces`, which its methods return): never the node,
its worker pool, its long jobs or its markers (test/client/test_client_imports.py checks).
"""

from grasp_fc_ros.engine.contact_forces import ContactForces
from grasp_fc_ros.engine.packed import Verdicts

from .grasp_client import GraspClient
from .label_job import request_on_spin_thread

__all__ = ["ContactForces", "GraspClient", "Verdicts", "request_on_spin_thread"]
