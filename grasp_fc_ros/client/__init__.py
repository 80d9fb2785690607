"""Talk to a running ``force_closure`` node from Python: :class:`GraspClient`.

Imports only :mod:`grasp_fc_ros.interface` (names, QoS, conversions) and the data types
of :mod:`grasp_fc_ros.packed` (:class:`Verdicts`, :class:`ContactForces`, which its
methods return, and :class:`RobustnessQuery`, what ``assess_robustness`` asks): never
the node, its engine (worker pool, long jobs, evaluation) or its markers
(test/client/test_client_imports.py checks).
"""

from grasp_fc_ros.packed import ContactForces, RobustnessQuery, Verdicts

from .grasp_client import GraspClient
from .label_action import NodeGoneError
from .label_job import request_on_spin_thread

__all__ = ["ContactForces", "GraspClient", "NodeGoneError", "RobustnessQuery", "Verdicts",
           "request_on_spin_thread"]
