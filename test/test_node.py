"""The force_closure node in-process, spun on its own executor thread.

A separate client node talks to it through real DDS topics and the service; the
verdicts are compared with grasp_fc_ros.core on the same grasps.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from rclpy.parameter import Parameter

from ros_fixtures import Client, SpinThread, ros  # noqa: F401 - ros is a fixture

from grasp_fc_ros import node as node_module
from grasp_fc_ros.conversions import (
    Verdicts,
    grasp_to_contact_array,
    grasps_to_batch_msg,
    verdict_array_to_numpy,
)
from grasp_fc_ros.core import Status, check_force_closure
from grasp_fc_ros.node import ForceClosureNode
from grasp_fc_ros.objects import make_object, sample_grasps

pytestmark = pytest.mark.timeout(120)

DEFAULT_MU = 0.5
# The exact test's margin depends on which grasps share a solver call, to solver accuracy.
MARGIN_ABS_TOL = 1e-6
MARGIN_REL_TOL = 1e-4


@pytest.fixture(scope="module")
def system(ros):  # noqa: F811
    """(node, client): the node on its executor thread and a connected client."""
    node = ForceClosureNode()
    spinner = SpinThread(node)
    client = Client()
    client.wait_connected()
    yield node, client
    client.close()
    spinner.stop()


@pytest.fixture
def client(system):
    system[1].clear()
    return system[1]


@pytest.fixture
def fc_node(system):
    return system[0]


@pytest.fixture(scope="module")
def grasps():
    """200 random 6-finger grasps on the box: positions, normals (200, 6, 3)."""
    return sample_grasps(make_object("box"), 200, 6, np.random.default_rng(1))


def assert_matches_core(verdicts, positions, normals, mu):
    """Verdict arrays equal the core's result on the same grasps."""
    expected = check_force_closure(positions, normals, mu)
    np.testing.assert_array_equal(verdicts.status, expected.status)
    np.testing.assert_array_equal(verdicts.force_closure, expected.force_closure)
    np.testing.assert_allclose(verdicts.margin, expected.margin, rtol=MARGIN_REL_TOL,
                               atol=MARGIN_ABS_TOL, equal_nan=True)


def subset(verdicts, index):
    """The verdicts of grasps ``index`` only."""
    return Verdicts(ids=verdicts.ids[index], force_closure=verdicts.force_closure[index],
                    status=verdicts.status[index], margin=verdicts.margin[index],
                    messages=[verdicts.messages[i] for i in index])


def send_batch(client, msg):
    return verdict_array_to_numpy(client.request_batch(msg))


def test_batch_verdicts_match_core_with_ids_in_order(client, grasps):
    positions, normals = grasps
    ids = np.random.default_rng(2).integers(0, 2**64 - 1, size=len(positions), dtype=np.uint64)
    got = send_batch(client, grasps_to_batch_msg(ids, positions, normals))
    np.testing.assert_array_equal(got.ids, ids)
    assert_matches_core(got, positions, normals, DEFAULT_MU)
    # The sample must exercise every decision path, or the comparison proves little.
    assert {Status.FORCE_CLOSURE, Status.FILTERED_OUT} <= set(got.status.tolist())


def test_batch_with_mixed_contact_counts(client):
    rng = np.random.default_rng(3)
    box = make_object("box")
    sizes = rng.choice([3, 4, 6, 8], size=60)
    grasp_list = [sample_grasps(box, 1, int(n), rng) for n in sizes]
    positions = np.concatenate([p[0] for p, _ in grasp_list])
    normals = np.concatenate([q[0] for _, q in grasp_list])
    mu = rng.uniform(0.2, 1.0, size=len(positions))
    got = send_batch(client, grasps_to_batch_msg(np.arange(60) + 100, positions, normals,
                                                 mu=mu, counts=sizes))
    np.testing.assert_array_equal(got.ids, np.arange(60) + 100)
    start = 0
    for i, (p, q) in enumerate(grasp_list):
        n = len(p[0])
        expected = check_force_closure(p[0], q[0], mu[start:start + n])
        start += n
        assert got.status[i] == expected.status, f"grasp {i}"
        assert got.force_closure[i] == expected.force_closure
        assert got.margin[i] == pytest.approx(float(expected.margin), rel=MARGIN_REL_TOL,
                                             abs=MARGIN_ABS_TOL, nan_ok=True)


def test_bad_grasps_get_invalid_input_and_spare_the_others(client, grasps):
    positions, normals = (a[:8].copy() for a in grasps)
    mu = np.full((8, 6), DEFAULT_MU)
    positions[1, 2, 0] = np.nan
    normals[3, 4] = 0.0
    positions[5, 0, 1] = np.inf
    mu[6, 1] = np.nan
    got = send_batch(client, grasps_to_batch_msg(np.arange(8), positions, normals, mu=mu))
    bad = [1, 3, 5, 6]
    assert (got.status[bad] == Status.INVALID_INPUT).all()
    assert not got.force_closure[bad].any()
    assert "contact 2" in got.messages[1] and "grasp 1" in got.messages[1]
    assert "contact 4" in got.messages[3]
    assert "contact 1" in got.messages[6]
    good = [0, 2, 4, 7]
    assert all(got.messages[i] == "" for i in good)
    assert_matches_core(
        subset(got, good), positions[good], normals[good], DEFAULT_MU)


def test_too_few_and_too_many_contacts(client, fc_node):
    rng = np.random.default_rng(4)
    box = make_object("box")
    max_contacts = fc_node.get_parameter("max_contacts").value
    sizes = np.array([1, 0, max_contacts + 1, 4])
    positions = np.concatenate([sample_grasps(box, 1, max(int(n), 1), rng)[0][0][:n]
                                for n in sizes])
    normals = np.ones_like(positions)
    got = send_batch(client, grasps_to_batch_msg([7, 8, 9, 10], positions, normals,
                                                 counts=sizes))
    np.testing.assert_array_equal(got.status[:3], Status.INVALID_INPUT)
    assert "1 contacts" in got.messages[0]
    assert f"max_contacts={max_contacts}" in got.messages[2]
    assert got.status[3] != Status.INVALID_INPUT


@pytest.mark.parametrize("corrupt", ["counts_exceed_arrays", "fewer_counts_than_ids",
                                     "normals_shorter", "friction_length_wrong"])
def test_malformed_batch_is_answered_not_fatal(client, grasps, corrupt):
    positions, normals = (a[:5] for a in grasps)
    msg = grasps_to_batch_msg(np.arange(5), positions, normals)
    if corrupt == "counts_exceed_arrays":
        msg.contact_counts[4] = 7
        unreadable = [4]
    elif corrupt == "fewer_counts_than_ids":
        msg.contact_counts = msg.contact_counts[:3]
        unreadable = [3, 4]
    elif corrupt == "normals_shorter":
        msg.normals = msg.normals[:-4]
        unreadable = [4]
    else:
        msg.friction_coefficients = [0.5] * 13  # 30 contacts declared
        unreadable = [2, 3, 4]
    got = send_batch(client, msg)
    np.testing.assert_array_equal(got.ids, np.arange(5))
    readable = [i for i in range(5) if i not in unreadable]
    assert (got.status[unreadable] == Status.INVALID_INPUT).all()
    assert all(got.messages[i] for i in unreadable)
    assert_matches_core(subset(got, readable), positions[readable],
                        normals[readable], DEFAULT_MU)


def test_oversized_batch_is_rejected_whole(client, fc_node, grasps):
    positions, normals = (a[:4] for a in grasps)
    fc_node.set_parameters([Parameter("max_batch", value=3)])
    try:
        got = send_batch(client, grasps_to_batch_msg(np.arange(4), positions, normals))
    finally:
        fc_node.set_parameters([Parameter("max_batch", value=100_000)])
    assert (got.status == Status.INVALID_INPUT).all()
    assert "max_batch=3" in got.messages[0]


def test_empty_batch_gets_empty_answer(client):
    got = send_batch(client, grasps_to_batch_msg([], np.empty((0, 6, 3)), np.empty((0, 6, 3))))
    assert len(got.ids) == 0 and len(got.status) == 0


def test_single_topic_one_verdict_per_query_in_order(client, grasps):
    positions, normals = (a[:40] for a in grasps)
    ids = np.arange(40) * 3 + 11
    for i in range(40):
        client.contacts_pub.publish(grasp_to_contact_array(ids[i], positions[i], normals[i]))
    bad = grasp_to_contact_array(999, positions[0][:1], normals[0][:1])
    client.contacts_pub.publish(bad)
    received = client.wait_for("verdicts", 41)
    assert [v.id for v in received] == ids.tolist() + [999]
    expected = check_force_closure(positions, normals, DEFAULT_MU)
    assert [v.status for v in received[:40]] == expected.status.tolist()
    assert [v.force_closure for v in received[:40]] == expected.force_closure.tolist()
    assert received[40].status == Status.INVALID_INPUT and received[40].message


def test_service_answers_every_grasp_in_order(client, grasps):
    positions, normals = (a[:10] for a in grasps)
    requests = [grasp_to_contact_array(100 + i, positions[i], normals[i]) for i in range(10)]
    requests[4] = grasp_to_contact_array(104, positions[4], normals[4] * 0.0)
    verdicts = client.call(requests)
    assert [v.id for v in verdicts] == list(range(100, 110))
    assert verdicts[4].status == Status.INVALID_INPUT and "contact 0" in verdicts[4].message
    expected = check_force_closure(positions, normals, DEFAULT_MU)
    for i in (0, 1, 2, 3, 5, 6, 7, 8, 9):
        assert verdicts[i].status == expected.status[i]
        assert verdicts[i].force_closure == expected.force_closure[i]


def test_service_with_no_grasps(client):
    assert client.call([]) == []


def test_contact_friction_le_zero_uses_parameter(client, fc_node, grasps):
    positions, normals = (a[:50] for a in grasps)
    fc_node.set_parameters([Parameter("friction_coefficient", value=0.9)])
    try:
        msg = grasps_to_batch_msg(np.arange(50), positions, normals, mu=np.zeros((50, 6)))
        got = send_batch(client, msg)
    finally:
        fc_node.set_parameters([Parameter("friction_coefficient", value=DEFAULT_MU)])
    assert_matches_core(got, positions, normals, 0.9)
    # The parameter must matter on this sample, or the test could not fail.
    assert (check_force_closure(positions, normals, DEFAULT_MU).status != got.status).any()


def test_without_filter_nothing_is_filtered_and_verdicts_agree(client, fc_node, grasps):
    positions, normals = (a[:60] for a in grasps)
    fc_node.set_parameters([Parameter("use_filter", value=False)])
    try:
        got = send_batch(client, grasps_to_batch_msg(np.arange(60), positions, normals))
    finally:
        fc_node.set_parameters([Parameter("use_filter", value=True)])
    assert Status.FILTERED_OUT not in got.status.tolist()
    np.testing.assert_array_equal(
        got.force_closure, check_force_closure(positions, normals, DEFAULT_MU).force_closure)


@pytest.mark.parametrize("name, value, why", [
    ("friction_coefficient", -0.1, "> 0"),
    ("friction_coefficient", math.inf, "finite"),
    ("filter_origins", "everywhere", "one of"),
    ("max_contacts", 1, ""),
    ("max_batch", 0, ""),
    ("qos_depth", 5, "read-only"),
])
def test_bad_parameter_values_are_rejected_with_a_reason(fc_node, name, value, why):
    before = fc_node.get_parameter(name).value
    result = fc_node.set_parameters([Parameter(name, value=value)])[0]
    assert not result.successful
    assert why in result.reason and result.reason
    assert fc_node.get_parameter(name).value == before


def test_good_parameter_values_are_accepted(fc_node):
    result = fc_node.set_parameters([Parameter("filter_origins", value="all")])[0]
    fc_node.set_parameters([Parameter("filter_origins", value="seed")])
    assert result.successful


def test_core_exception_becomes_solver_failure_and_node_survives(client, grasps, monkeypatch):
    positions, normals = (a[:3] for a in grasps)

    def broken(*args, **kwargs):
        raise RuntimeError("solver exploded")

    monkeypatch.setattr(node_module, "check_force_closure", broken)
    got = send_batch(client, grasps_to_batch_msg([1, 2, 3], positions, normals))
    assert (got.status == Status.SOLVER_FAILURE).all()
    assert "solver exploded" in got.messages[0]
    [verdict] = client.call([grasp_to_contact_array(4, positions[0], normals[0])])
    assert verdict.status == Status.SOLVER_FAILURE
    monkeypatch.undo()
    client.clear()
    got = send_batch(client, grasps_to_batch_msg([5], positions[:1], normals[:1]))
    assert got.status[0] != Status.SOLVER_FAILURE


def test_diagnostics_report_counters(client, grasps):
    positions, normals = (a[:2] for a in grasps)
    send_batch(client, grasps_to_batch_msg([1, 2], positions, normals * np.nan))
    client.clear()
    diagnostics = client.wait_for("diagnostics", 2, timeout=5.0)
    status = diagnostics[-1].status[0]
    values = {kv.key: kv.value for kv in status.values}
    assert "force_closure" in status.name
    for key in ("queries", "rejected_by_filter", "decided_by_exact_test", "invalid_input",
                "solver_failures", "processing_time_mean_ms", "processing_time_p99_ms"):
        assert key in values
    assert int(values["queries"]) > 0
    assert int(values["invalid_input"]) > 0
