"""Soft-finger contacts through the messages, the evaluation, the workers and the node."""

from __future__ import annotations

import numpy as np
import pytest
from rclpy.parameter import Parameter

from grasp_fc_ros.core import Status, check_force_closure
from grasp_fc_ros.engine.chunking import SOFT_CHUNK_DIVISOR
from grasp_fc_ros.engine.evaluation import evaluate
from grasp_fc_ros.engine.pool import EvaluationPool
from grasp_fc_ros.interface.conversions import (
    MalformedBatch,
    batch_to_packed,
    contact_arrays_to_packed,
    grasp_to_contact_array,
    grasps_to_batch_msg,
    verdict_array_to_numpy,
)
from grasp_fc_ros.node import ForceClosureNode
from grasp_fc_ros.packed import Settings
from ros_fixtures import REPLY_TIMEOUT_S, Client, SpinThread

pytestmark = pytest.mark.timeout(120)

GAMMA = 0.01   # m: a 1 cm torsional friction coefficient


def antipodal(n_grasps, seed=0):
    """Two contacts on opposite sides of a 5 cm sphere, normals inward: (N, 2, 3) twice."""
    rng = np.random.default_rng(seed)
    direction = rng.normal(size=(n_grasps, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    positions = 0.05 * np.stack([direction, -direction], axis=1)
    return positions, -positions


def test_messages_carry_torsional_friction_into_packed_grasps():
    positions, normals = antipodal(3)
    packed = batch_to_packed(grasps_to_batch_msg(np.arange(3), positions, normals,
                                                 torsional_friction=GAMMA))
    np.testing.assert_array_equal(packed.torsional, np.full(6, GAMMA))
    assert batch_to_packed(grasps_to_batch_msg([0], positions[:1], normals[:1])).torsional is None
    single = contact_arrays_to_packed(
        [grasp_to_contact_array(7, positions[0], normals[0], torsional_friction=[GAMMA, 0.0])])
    np.testing.assert_array_equal(single.torsional, [GAMMA, 0.0])
    assert contact_arrays_to_packed(
        [grasp_to_contact_array(7, positions[0], normals[0])]).torsional is None
    msg = grasps_to_batch_msg(np.arange(3), positions, normals, torsional_friction=GAMMA)
    msg.torsional_friction = msg.torsional_friction[:-1]
    with pytest.raises(MalformedBatch, match="torsional_friction has 5 values"):
        batch_to_packed(msg)
    assert packed.slice(1, 3).torsional.tolist() == [GAMMA] * 4


def test_evaluation_decides_soft_grasps_and_names_bad_gamma():
    positions, normals = antipodal(6)
    gamma = np.full((6, 2), GAMMA)
    gamma[4, 1] = -1.0
    packed = batch_to_packed(grasps_to_batch_msg(np.arange(6) + 100, positions, normals,
                                                 torsional_friction=gamma))
    verdicts, _ = evaluate(packed, Settings())
    assert verdicts.status.tolist() == [Status.FORCE_CLOSURE] * 4 + [
        Status.INVALID_INPUT, Status.FORCE_CLOSURE]
    assert verdicts.messages[4] == (
        "grasp 4 (id 104), contact 1: torsional friction must be >= 0 (0: a hard contact), "
        "got -1")
    hard, _ = evaluate(batch_to_packed(grasps_to_batch_msg(np.arange(6), positions, normals)),
                       Settings())
    assert not hard.force_closure.any()


def test_worker_processes_decide_soft_batches_like_the_core():
    rng = np.random.default_rng(4)
    positions, normals = antipodal(60)
    positions = positions + rng.normal(scale=0.005, size=positions.shape)
    gamma = rng.uniform(0.0, 0.02, size=(60, 2))
    gamma[::3] = 0.0                                    # hard pairs: never force closure
    packed = batch_to_packed(grasps_to_batch_msg(np.arange(60), positions, normals,
                                                 torsional_friction=gamma))
    expected = check_force_closure(positions, normals, 0.5, torsional_friction=gamma)
    pool = EvaluationPool(1, chunk_contacts=SOFT_CHUNK_DIVISOR * 20)  # soft chunks: 20 contacts
    try:
        pooled, _ = pool.decide(packed, Settings())
    finally:
        pool.close()
    np.testing.assert_array_equal(pooled.status, expected.status)
    assert expected.force_closure.any() and (~expected.force_closure).any()


@pytest.fixture(scope="module")
def system(ros):
    node = ForceClosureNode(parameter_overrides=[Parameter("workers", value=0)])
    spinner = SpinThread(node)
    client = Client("grasp_fc_soft_test_client")
    client.wait_connected(node=node)
    yield node, client
    client.close()
    spinner.stop()


def test_node_decides_a_soft_antipodal_grasp_on_both_topics(system):
    _, client = system
    client.clear()
    positions, normals = antipodal(4, seed=1)
    client.contacts_pub.publish(grasp_to_contact_array(1, positions[0], normals[0]))
    client.contacts_pub.publish(grasp_to_contact_array(2, positions[0], normals[0],
                                                       torsional_friction=GAMMA))
    single = client.wait_for("verdicts", 2)
    assert [(v.id, v.force_closure) for v in single] == [(1, False), (2, True)]
    assert single[1].status == Status.FORCE_CLOSURE
    gamma = np.array([[GAMMA, GAMMA], [0, 0], [GAMMA, 0], [-GAMMA, GAMMA]])
    got = verdict_array_to_numpy(client.request_batch(
        grasps_to_batch_msg(np.arange(4), positions, normals, torsional_friction=gamma)))
    assert got.status.tolist() == [Status.FORCE_CLOSURE, Status.FILTERED_OUT,
                                   Status.FORCE_CLOSURE, Status.INVALID_INPUT]
    assert got.messages[3] == ("grasp 3 (id 3), contact 0: torsional friction must be >= 0 "
                               f"(0: a hard contact), got {-GAMMA:g}")
    verdicts = client.call([grasp_to_contact_array(5, positions[1], normals[1],
                                                   torsional_friction=GAMMA)])
    assert verdicts[0].force_closure


def test_client_batch_of_soft_pairs_with_certificates(own_node):
    """GraspClient.check_batch sends gamma; the node's certificates verify with torques."""
    from grasp_fc_ros.client import GraspClient
    from grasp_fc_ros.core import verify_certificates

    axis = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.6, 0.8, 0.0]])
    positions = 0.03 * np.stack([axis, -axis], axis=1)
    normals = -positions
    gamma = np.array([[0.004, 0.004], [0.0, 0.0], [0.004, 0.004]])
    own_node("/soft_client", certificates=True, workers=0)
    with GraspClient("/soft_client/force_closure") as client:
        assert client.wait_for_node(timeout=REPLY_TIMEOUT_S)
        got = client.check_batch(positions, normals, 0.5, torsional_friction=gamma)
    assert got.force_closure.tolist() == [True, False, True]  # two hard fingers never
    forces_ok, _ = verify_certificates(positions, normals, 0.5,
                                       got.contact_forces.reshape(3, 2, 3), None, gamma,
                                       got.contact_torques.reshape(3, 2))
    assert forces_ok.tolist() == [True, False, True]
