"""Certificates, minimum friction and contact forces for a load through the node.

Every certificate received over DDS is checked with grasp_fc_ros.core.verify_certificates
on the arrays as received; min_friction against check_force_closure just above and below
it; compute_contact_forces against the core and the equilibrium it claims. The worker
processes' share (chunks put back together) is tested without DDS.
"""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest
from rclpy.parameter import Parameter

from grasp_fc_ros.client import GraspClient
from grasp_fc_ros.core import (
    Status,
    check_force_closure,
    optimal_contact_forces,
    verify_certificates,
)
from grasp_fc_ros.engine.evaluation import evaluate
from grasp_fc_ros.engine.pool import EvaluationPool
from grasp_fc_ros.interface.conversions import batch_to_packed, grasps_to_batch_msg
from grasp_fc_ros.objects import make_object, sample_grasps
from grasp_fc_ros.packed import Settings
from ros_fixtures import REPLY_TIMEOUT_S

pytestmark = pytest.mark.timeout(180)

DEFAULT_MU = 0.5
# min_friction is checked this far (relative) above and below: far outside its 1e-6
# certification, and wide enough that the exact test's MARGIN_TOL does not matter.
MU_STEP = 1e-3
# compute_contact_forces: the core certifies s* to 1e-6 relative (OPTIMALITY_TOL); the
# residual of the returned forces is rounding on top of FORCE_TOL-feasible forces.
S_STAR_RTOL = 1e-5
BALANCE_ATOL = 1e-6


@pytest.fixture(scope="module")
def grasps():
    """60 random 4-finger grasps on the box (positions, normals (60, 4, 3)): four fingers
    so that the filter runs and FILTERED_OUT verdicts carry its wrenches too."""
    return sample_grasps(make_object("box"), 60, 4, np.random.default_rng(11))


@pytest.fixture
def certifying(own_node):
    """A GraspClient of a node with certificates and compute_min_friction on."""
    node, _, _ = own_node("/certifying", certificates=True, compute_min_friction=True,
                          workers=0)
    with GraspClient("/certifying/force_closure") as client:
        assert client.wait_for_node(timeout=REPLY_TIMEOUT_S)
        yield node, client


def assert_certificates_verify(status, positions, normals, forces, wrenches):
    """Forces verify exactly for FORCE_CLOSURE, wrenches for every rejected grasp."""
    forces_ok, wrench_ok = verify_certificates(positions, normals, DEFAULT_MU, forces,
                                               wrenches)
    np.testing.assert_array_equal(forces_ok, status == Status.FORCE_CLOSURE)
    rejected = (status == Status.NOT_FORCE_CLOSURE) | (status == Status.FILTERED_OUT)
    np.testing.assert_array_equal(wrench_ok, rejected)  # no marginal grasp in the sample
    # Every kind of verdict must occur, or the checks above prove little.
    assert {Status.FORCE_CLOSURE, Status.NOT_FORCE_CLOSURE, Status.FILTERED_OUT} <= set(
        status.tolist())


def assert_min_friction_brackets(min_friction, positions, normals):
    """check_force_closure says yes just above mu*, no just below (equal friction)."""
    finite = np.isfinite(min_friction) & (min_friction > 0)
    assert finite.sum() >= len(min_friction) // 2
    mu_star = min_friction[finite]
    above = check_force_closure(positions[finite], normals[finite],
                                (mu_star * (1 + MU_STEP))[:, None])
    below = check_force_closure(positions[finite], normals[finite],
                                (mu_star * (1 - MU_STEP))[:, None])
    assert above.force_closure.all() and not below.force_closure.any()
    # Consistent with the verdict at the node's friction too.
    verdict = check_force_closure(positions[finite], normals[finite], DEFAULT_MU)
    np.testing.assert_array_equal(verdict.force_closure[mu_star < DEFAULT_MU * (1 - MU_STEP)],
                                  True)
    np.testing.assert_array_equal(verdict.force_closure[mu_star > DEFAULT_MU * (1 + MU_STEP)],
                                  False)


def test_batch_topic_carries_verified_certificates_and_min_friction(certifying, grasps):
    positions, normals = grasps
    _, client = certifying
    got = client.check_batch(positions, normals)
    assert got.contact_forces.shape == (positions.size // 3, 3)
    forces = got.contact_forces.reshape(positions.shape)
    assert_certificates_verify(got.status, positions, normals, forces, got.separating_wrench)
    assert np.isnan(forces[got.status != Status.FORCE_CLOSURE]).all()
    assert_min_friction_brackets(got.min_friction, positions, normals)


def test_single_topic_verdicts_carry_verified_certificates(certifying, grasps):
    positions, normals = (a[:12] for a in grasps)
    _, client = certifying
    futures = [client.submit(p, q) for p, q in zip(positions, normals, strict=True)]
    replies = [f.result(timeout=REPLY_TIMEOUT_S) for f in futures]
    status = np.array([r.status for r in replies])
    forces = np.full(positions.shape, np.nan)
    for k, reply in enumerate(replies):
        if reply.contact_forces:
            forces[k] = [(v.x, v.y, v.z) for v in reply.contact_forces]
    wrenches = np.array([(r.separating_wrench.force.x, r.separating_wrench.force.y,
                          r.separating_wrench.force.z, r.separating_wrench.torque.x,
                          r.separating_wrench.torque.y, r.separating_wrench.torque.z)
                         for r in replies])
    forces_ok, wrench_ok = verify_certificates(positions, normals, DEFAULT_MU, forces,
                                               wrenches)
    np.testing.assert_array_equal(forces_ok, status == Status.FORCE_CLOSURE)
    np.testing.assert_array_equal(wrench_ok, status != Status.FORCE_CLOSURE)
    assert forces_ok.any() and wrench_ok.any()
    # Computed (NaN would also be legitimate for a grasp the core cannot certify, ~0.1%).
    assert sum(math.isfinite(r.min_friction) for r in replies) >= len(replies) // 2


def test_service_verdicts_carry_verified_certificates(certifying, grasps):
    positions, normals = grasps
    _, client = certifying
    got = client.call(positions, normals)
    assert_certificates_verify(got.status, positions, normals,
                               got.contact_forces.reshape(positions.shape),
                               got.separating_wrench)
    assert_min_friction_brackets(got.min_friction, positions, normals)


def test_parameters_off_send_no_certificates_and_can_be_switched_on(own_node, grasps):
    positions, normals = (a[:10] for a in grasps)
    node, _, _ = own_node("/plain", workers=0)
    with GraspClient("/plain/force_closure") as client:
        assert client.wait_for_node(timeout=REPLY_TIMEOUT_S)
        batch = client.check_batch(positions, normals)
        assert batch.contact_forces is None and batch.separating_wrench is None
        assert batch.min_friction is None
        served = client.call(positions, normals)
        assert np.isnan(served.contact_forces).all()
        assert np.isnan(served.separating_wrench).all() and np.isnan(served.min_friction).all()
        single = client.submit(positions[0], normals[0]).result(timeout=REPLY_TIMEOUT_S)
        assert single.contact_forces == [] and math.isnan(single.separating_wrench.torque.z)
        assert math.isnan(single.min_friction)
        assert node.set_parameters_atomically([
            Parameter(name, value=True)
            for name in ("certificates", "compute_min_friction")]).successful
        switched = client.check_batch(positions, normals)
    assert switched.contact_forces.shape == (positions.size // 3, 3)
    assert np.isfinite(switched.min_friction).any()
    np.testing.assert_array_equal(switched.status, batch.status)


def test_worker_chunks_return_certificates_in_order(grasps):
    """Chunks decided in a worker process come back with their certificates in place."""
    positions, normals = grasps
    packed = batch_to_packed(grasps_to_batch_msg(np.arange(len(positions)), positions,
                                                 normals, DEFAULT_MU))
    settings = Settings(certificates=True, compute_min_friction=True)
    pool = EvaluationPool(1, chunk_contacts=50)  # 12 grasps a chunk: 5 chunks
    try:
        pooled, _ = pool.decide(packed, settings)
    finally:
        pool.close()
    inline, _ = evaluate(packed, settings)
    np.testing.assert_array_equal(pooled.status, inline.status)
    np.testing.assert_allclose(pooled.min_friction, inline.min_friction, rtol=2e-6)
    assert_certificates_verify(pooled.status, positions, normals,
                               pooled.contact_forces.reshape(positions.shape),
                               pooled.separating_wrench)


# --- compute_contact_forces --------------------------------------------------------------

def box_grasp_and_load():
    """A force-closure 4-finger box grasp and gravity on a 1 kg object off its centre."""
    positions, normals = sample_grasps(make_object("box"), 40, 4, np.random.default_rng(12))
    fc = check_force_closure(positions, normals, DEFAULT_MU).force_closure
    k = int(np.flatnonzero(fc)[0])
    centre = np.array([0.01, -0.005, 0.0])
    force = np.array([0.0, 0.0, -9.81])
    return positions[k], normals[k], np.concatenate([force, np.cross(centre, force)])


def test_compute_contact_forces_balances_the_load_and_matches_the_core(certifying):
    positions, normals, wrench = box_grasp_and_load()
    _, client = certifying
    got = client.compute_contact_forces(positions, normals, wrench)  # mu: node default
    assert got.feasible and got.message == ""
    s_star, _, _ = optimal_contact_forces(positions, normals, DEFAULT_MU, wrench)
    assert got.max_normal_force == pytest.approx(float(s_star), rel=S_STAR_RTOL)
    f = got.contact_forces
    assert f.shape == (4, 3)
    np.testing.assert_allclose(f.sum(axis=0) + wrench[:3], 0, atol=BALANCE_ATOL)
    np.testing.assert_allclose(np.cross(positions, f).sum(axis=0) + wrench[3:], 0,
                               atol=BALANCE_ATOL)
    unit = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    f_n = (f * unit).sum(axis=1)
    f_t = np.linalg.norm(f - f_n[:, None] * unit, axis=1)
    assert (f_t <= DEFAULT_MU * f_n + 1e-6 * got.max_normal_force).all()
    assert f_n.max() == pytest.approx(got.max_normal_force, rel=S_STAR_RTOL)
    # Limits below s* at every contact make the load impossible to hold.
    limited = client.compute_contact_forces(positions, normals, wrench,
                                            max_normal_forces=[0.5 * s_star] * 4)
    assert not limited.feasible and limited.max_normal_force == math.inf
    assert limited.contact_forces.shape == (0, 3) and limited.message == ""


def test_compute_contact_forces_infeasible_load(certifying):
    # Three fingers on the top face can only push down: gravity cannot be held.
    positions = np.array([[0.01, 0, 0.05], [-0.01, 0.01, 0.05], [0, -0.01, 0.05]])
    normals = np.tile([0.0, 0.0, -1.0], (3, 1))
    _, client = certifying
    got = client.compute_contact_forces(positions, normals, [0, 0, -9.81, 0, 0, 0], mu=0.8)
    assert not got.feasible and got.max_normal_force == math.inf
    assert got.contact_forces.shape == (0, 3)


@pytest.mark.parametrize("change, message", [
    (lambda p, n, w, m: n.__setitem__(2, 0.0),
     "query id 0, contact 2: normal has zero length, got (0, 0, 0)"),
    (lambda p, n, w, m: p.__setitem__((1, 0), math.nan),
     "query id 0, contact 1: position is not finite"),
    (lambda p, n, w, m: w.__setitem__(4, math.inf),
     "query id 0: wrench torque.y is not finite (inf)"),
    (lambda p, n, w, m: m.__setitem__(3, -1.0),
     "query id 0, contact 3: max_normal_force must be >= 0 (inf: no limit), got -1.0"),
])
def test_compute_contact_forces_invalid_request_names_the_contact(certifying, change,
                                                                   message):
    positions, normals, wrench = (a.copy() for a in box_grasp_and_load())
    limits = [100.0] * 4
    change(positions, normals, wrench, limits)
    _, client = certifying
    got = client.compute_contact_forces(positions, normals, wrench, max_normal_forces=limits)
    assert not got.feasible and math.isnan(got.max_normal_force)
    assert got.message.startswith(message), got.message
    assert got.contact_forces.shape == (0, 3)


def test_compute_contact_forces_refuses_limits_not_one_per_contact(certifying):
    """A raw request: GraspClient refuses such limits before sending
    (test/client/test_client_shapes.py)."""
    from grasp_fc_msgs.srv import ComputeContactForces
    from rclpy.node import Node

    from grasp_fc_ros.interface.conversions import grasp_to_contact_array
    from ros_fixtures import SpinThread

    positions, normals, wrench = box_grasp_and_load()
    request = ComputeContactForces.Request(grasp=grasp_to_contact_array(0, positions, normals),
                                           max_normal_forces=[100.0] * 3)
    force, torque = request.wrench.force, request.wrench.torque
    force.x, force.y, force.z, torque.x, torque.y, torque.z = wrench.tolist()
    node = Node("raw_forces_client")
    service = node.create_client(ComputeContactForces, "/certifying/compute_contact_forces")
    spinner = SpinThread(node)
    try:
        assert service.wait_for_service(timeout_sec=REPLY_TIMEOUT_S)
        answered = threading.Event()
        future = service.call_async(request)
        future.add_done_callback(lambda _: answered.set())
        assert answered.wait(REPLY_TIMEOUT_S), "compute_contact_forces did not answer"
        got = future.result()
    finally:
        spinner.stop()
    assert not got.feasible and math.isnan(got.max_normal_force)
    assert got.message.startswith("query id 0: 3 max_normal_forces for 4 contacts"), got.message
    assert len(got.contact_forces) == 0


def test_compute_contact_forces_soft_fingers_twist(certifying):
    # Two soft fingers squeezing along x resist a twist about x only by torsional
    # friction: each carries half the torque, so s* = T / (2 gamma), and the torques
    # come back with the forces.
    positions = np.array([[0.03, 0.0, 0.0], [-0.03, 0.0, 0.0]])
    normals = np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    gamma, torque = 0.005, 0.02
    _, client = certifying
    got = client.compute_contact_forces(positions, normals, [0, 0, 0, torque, 0, 0],
                                        torsional_friction=gamma)
    assert got.feasible and got.message == ""
    assert got.max_normal_force == pytest.approx(torque / (2 * gamma), rel=S_STAR_RTOL)
    # the moments about the normals (along -x and +x) cancel the load's torque
    moments = got.contact_torques[:, None] * normals
    np.testing.assert_allclose(moments.sum(axis=0) + [torque, 0, 0], 0, atol=BALANCE_ATOL)
    hard = client.compute_contact_forces(positions, normals, [0, 0, 0, torque, 0, 0])
    assert not hard.feasible and hard.max_normal_force == math.inf
