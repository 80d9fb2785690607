"""The node's `compute_epsilon` parameter: certified Ferrari-Canny epsilon bounds in the
verdicts of every lane (batch topic, single topic, service), equal to the core's
epsilon_quality on the same grasps; NaN or absent without it. The worker processes'
share is tested without DDS."""

from __future__ import annotations

import math

import numpy as np
import pytest
from grasp_fc_msgs.msg import ForceClosureVerdict, ForceClosureVerdictArray

from grasp_fc_ros.client import GraspClient
from grasp_fc_ros.core import Status, epsilon_quality
from grasp_fc_ros.engine.evaluation import evaluate
from grasp_fc_ros.engine.pool import EvaluationPool
from grasp_fc_ros.interface.conversions import batch_to_packed, grasps_to_batch_msg
from grasp_fc_ros.objects import make_object, sample_grasps
from grasp_fc_ros.packed import Settings
from ros_fixtures import REPLY_TIMEOUT_S

# A cold start compiles the epsilon kernels (docs/epsilon.md#cost) in the node's
# process and in the worker: far more than a verdict.
pytestmark = pytest.mark.timeout(600)

DEFAULT_MU = 0.5
# The node and the core search the same grasps with the same settings; the bounds are
# compared to rounding only, not to the search's rtol.
SAME_RTOL = 1e-9
# The upper bound of a grasp that is not force closure: the core's ZERO_UPPER_TOL of the
# wrench scale (order 1 for these grasps), twice.
NOT_FC_UPPER_ATOL = 2e-6


@pytest.fixture(scope="module")
def grasps():
    """30 random 5-finger grasps on the box: a mix of force closure and not."""
    return sample_grasps(make_object("box"), 30, 5, np.random.default_rng(5))


def assert_bounds_match_the_core(lower, upper, status, positions, normals):
    """lower <= upper everywhere, lower > 0 exactly for FORCE_CLOSURE, and the core's
    epsilon_quality gives the same bounds."""
    lower, upper, status = np.asarray(lower), np.asarray(upper), np.asarray(status)
    assert np.isfinite(lower).all() and np.isfinite(upper).all()
    assert (lower <= upper).all()
    force_closure = status == Status.FORCE_CLOSURE
    assert force_closure.any() and (~force_closure).any(), "need both kinds of grasp"
    np.testing.assert_array_equal(lower > 0, force_closure)
    assert (upper[force_closure] > 0).all()
    core = epsilon_quality(positions, normals, DEFAULT_MU)
    np.testing.assert_allclose(lower, core.lower, rtol=SAME_RTOL, atol=0)
    np.testing.assert_allclose(upper[force_closure], core.upper[force_closure],
                               rtol=SAME_RTOL, atol=0)
    # Not force closure: upper is h(separating wrench), which depends on the grasps
    # solved alongside; it is 0 up to the core's ZERO_UPPER_TOL either way.
    np.testing.assert_allclose(upper[~force_closure], core.upper[~force_closure],
                               rtol=0, atol=NOT_FC_UPPER_ATOL)


def test_messages_default_to_no_epsilon_fields_set():
    verdict, array_ = ForceClosureVerdict(), ForceClosureVerdictArray()
    assert list(array_.epsilon_lower) == list(array_.epsilon_upper) == []
    # A zero-initialised single verdict reads UNKNOWN, so its 0.0 bounds mean nothing.
    assert verdict.status == ForceClosureVerdict.UNKNOWN


def test_every_lane_carries_epsilon_bounds_with_compute_epsilon(own_node, grasps):
    positions, normals = grasps
    own_node("/epsilon", compute_epsilon=True, workers=0)
    with GraspClient("/epsilon/force_closure") as client:
        assert client.wait_for_node(timeout=REPLY_TIMEOUT_S)
        batch = client.check_batch(positions, normals, timeout=300.0)
        served = client.call(positions, normals, timeout=300.0)
        singles = [client.submit(p, q).result(timeout=300.0)
                   for p, q in zip(positions[:8], normals[:8], strict=True)]
    assert_bounds_match_the_core(batch.epsilon_lower, batch.epsilon_upper, batch.status,
                                 positions, normals)
    assert_bounds_match_the_core(served.epsilon_lower, served.epsilon_upper, served.status,
                                 positions, normals)
    np.testing.assert_array_equal(served.status, batch.status)
    single_lower = np.array([v.epsilon_lower for v in singles])
    single_upper = np.array([v.epsilon_upper for v in singles])
    np.testing.assert_allclose(single_lower, batch.epsilon_lower[:8], rtol=SAME_RTOL)
    np.testing.assert_allclose(single_upper, batch.epsilon_upper[:8], rtol=SAME_RTOL,
                               atol=NOT_FC_UPPER_ATOL)


def test_without_compute_epsilon_the_bounds_are_nan_or_absent(own_node, grasps):
    positions, normals = (a[:6] for a in grasps)
    own_node("/no_epsilon", workers=0)
    with GraspClient("/no_epsilon/force_closure") as client:
        assert client.wait_for_node(timeout=REPLY_TIMEOUT_S)
        batch = client.check_batch(positions, normals)
        served = client.call(positions, normals)
        single = client.submit(positions[0], normals[0]).result(timeout=REPLY_TIMEOUT_S)
    assert batch.epsilon_lower is None and batch.epsilon_upper is None
    assert np.isnan(served.epsilon_lower).all() and np.isnan(served.epsilon_upper).all()
    assert math.isnan(single.epsilon_lower) and math.isnan(single.epsilon_upper)


def test_invalid_grasps_get_nan_bounds_and_spare_the_others(grasps):
    positions, normals = (a[:6].copy() for a in grasps)
    normals[2, 1] = 0.0
    packed = batch_to_packed(grasps_to_batch_msg(np.arange(6), positions, normals))
    verdicts, seconds = evaluate(packed, Settings(compute_epsilon=True))
    assert verdicts.status[2] == Status.INVALID_INPUT
    assert math.isnan(verdicts.epsilon_lower[2]) and math.isnan(verdicts.epsilon_upper[2])
    good = [0, 1, 3, 4, 5]
    assert np.isfinite(verdicts.epsilon_upper[good]).all()
    assert seconds["epsilon_s"] > 0


@pytest.mark.parametrize("warm_epsilon", [False, True])
def test_worker_chunks_return_epsilon_in_order(grasps, warm_epsilon):
    """Chunks decided in a worker process (which warms the epsilon kernels at start, or
    on its first such chunk within its allowance) come back with their bounds in place."""
    positions, normals = grasps
    packed = batch_to_packed(grasps_to_batch_msg(np.arange(len(positions)), positions,
                                                 normals, DEFAULT_MU))
    settings = Settings(compute_epsilon=True)
    # 8 grasps a chunk: 4 chunks.
    pool = EvaluationPool(1, chunk_contacts=40, warm_epsilon=warm_epsilon)
    try:
        pooled, _ = pool.decide(packed, settings)
    finally:
        pool.close()
    assert_bounds_match_the_core(pooled.epsilon_lower, pooled.epsilon_upper, pooled.status,
                                 positions, normals)
