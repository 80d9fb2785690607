"""The client's service calls: ``check_force_closure``, ``compute_contact_forces`` and
``assess_robustness``.

The service clients live on a small node of their own that no executor spins: each
call waits for its response in the caller's thread
(:class:`~grasp_fc_ros.interface.wait_sets.ServiceCaller`), which answers a one-grasp
call faster than an executor thread that also serves the topics and the action
(docs/performance.md#service-latency). A call of more than
:data:`~grasp_fc_ros.interface.names.MAX_REQUEST_CONTACTS` contacts goes as several
requests of whole grasps, one after the other, so that it stays under the node's
``max_message_contacts`` and other clients' calls are served between its requests;
likewise an assessment of many grasps (:mod:`.assessment`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from grasp_fc_msgs.srv import AssessRobustness, CheckForceClosure, ComputeContactForces
from numpy.typing import ArrayLike
from rclpy.node import Node

from grasp_fc_ros.client.assessment import assessment_requests
from grasp_fc_ros.client.batches import grasp_ranges
from grasp_fc_ros.interface.conversions import (
    assessment_to_numpy,
    grasp_to_contact_array,
    verdict_msgs_to_numpy,
)
from grasp_fc_ros.interface.names import (
    ASSESS_SERVICE,
    CHECK_SERVICE,
    CONTACT_FORCES_SERVICE,
    MAX_REQUEST_CONTACTS,
    resolve,
)
from grasp_fc_ros.interface.wait_sets import ServiceCaller
from grasp_fc_ros.packed import ContactForces, RobustnessQuery, Verdicts


class ServiceCalls:
    """Call the node's services, each call waiting in the calling thread.

    Parameters
    ----------
    client_node_name : str
        Name of the client's own node; the service node is ``<it>_service``.
    node_name : str
        The force_closure node's full name.
    """

    def __init__(self, client_node_name: str, node_name: str):
        self.node = Node(f"{client_node_name}_service", start_parameter_services=False)
        self.check_client = self.node.create_client(CheckForceClosure,
                                                    resolve(node_name, CHECK_SERVICE))
        self._forces_client = self.node.create_client(
            ComputeContactForces, resolve(node_name, CONTACT_FORCES_SERVICE))
        self._assess_client = self.node.create_client(
            AssessRobustness, resolve(node_name, ASSESS_SERVICE))
        self._check = ServiceCaller(self.check_client)
        self._forces = ServiceCaller(self._forces_client)
        self._assess = ServiceCaller(self._assess_client)

    def call(self, positions: ArrayLike, normals: ArrayLike, mu: ArrayLike,
             ids: ArrayLike | None, timeout: float) -> Verdicts:
        """See :meth:`grasp_fc_ros.client.GraspClient.call`."""
        positions = np.asarray(positions, dtype=np.float64)
        normals = np.asarray(normals, dtype=np.float64)
        ids = np.arange(len(positions)) if ids is None else np.asarray(ids)
        mu = np.broadcast_to(np.asarray(mu, dtype=np.float64), positions.shape[:2])
        request = CheckForceClosure.Request(grasps=[
            grasp_to_contact_array(i, p, n, m)
            for i, p, n, m in zip(ids, positions, normals, mu, strict=True)])
        return self.call_request(request, timeout)

    def call_request(self, request: Any, timeout: float) -> Verdicts:
        """Send a prepared CheckForceClosure request; its Verdicts in order.

        A request of more than MAX_REQUEST_CONTACTS contacts goes as several (see
        :func:`~.batches.grasp_ranges`), within ``timeout`` for them all.
        """
        grasps = request.grasps
        counts = [len(grasp.contacts) for grasp in grasps]
        if sum(counts) <= MAX_REQUEST_CONTACTS:
            replies = self._check.call(request, timeout).verdicts
        else:
            parts = [CheckForceClosure.Request(grasps=grasps[first:last])
                     for first, last in grasp_ranges(counts, MAX_REQUEST_CONTACTS)]
            replies = [verdict for response in self._check.call_each(parts, timeout)
                       for verdict in response.verdicts]
        return verdict_msgs_to_numpy(replies, counts)

    def compute_contact_forces(self, positions: ArrayLike, normals: ArrayLike,
                               wrench: ArrayLike, mu: ArrayLike,
                               max_normal_forces: ArrayLike | None, frame_id: str,
                               timeout: float, torsional_friction: ArrayLike) -> ContactForces:
        """See :meth:`grasp_fc_ros.client.GraspClient.compute_contact_forces`."""
        request = ComputeContactForces.Request(
            grasp=grasp_to_contact_array(0, positions, normals, mu,
                                         torsional_friction=torsional_friction))
        request.grasp.header.frame_id = frame_id
        w = np.asarray(wrench, dtype=np.float64).reshape(6).tolist()
        force, torque = request.wrench.force, request.wrench.torque
        force.x, force.y, force.z, torque.x, torque.y, torque.z = w
        if max_normal_forces is not None:
            request.max_normal_forces = np.broadcast_to(
                np.asarray(max_normal_forces, dtype=np.float64),
                (len(request.grasp.contacts),)).tolist()
        # wait_for_node waits for check_force_closure only; this service may be
        # discovered a moment later, and a request sent before would go unanswered.
        if not self._forces_client.wait_for_service(timeout_sec=timeout):
            raise TimeoutError(f"service {self._forces_client.srv_name} not found within "
                               f"{timeout} s: its node may be down")
        response = self._forces.call(request, timeout)
        forces = np.array([(v.x, v.y, v.z) for v in response.contact_forces],
                          dtype=np.float64).reshape(-1, 3)
        return ContactForces(bool(response.feasible), float(response.max_normal_force),
                             forces, np.array(response.contact_torques, dtype=np.float64),
                             response.message)

    def assess_robustness(self, positions: ArrayLike, normals: ArrayLike, mu: ArrayLike | None,
                          torsional_friction: ArrayLike | None, ids: ArrayLike | None,
                          question: RobustnessQuery, frame_id: str, timeout: float) -> Verdicts:
        """See :meth:`grasp_fc_ros.client.GraspClient.assess_robustness`."""
        requests = assessment_requests(positions, normals, mu, torsional_friction, ids,
                                       question, frame_id)
        # As for compute_contact_forces: wait_for_node waits for check_force_closure only.
        if not self._assess_client.wait_for_service(timeout_sec=timeout):
            raise TimeoutError(f"service {self._assess_client.srv_name} not found within "
                               f"{timeout} s: its node may be down")
        parts = [assessment_to_numpy(response)
                 for response in self._assess.call_each(requests, timeout)]
        return Verdicts.concatenate(parts)

    def close(self) -> None:
        self.node.destroy_node()

