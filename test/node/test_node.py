"""The force_closure node in-process, spun on its own executor thread.

A separate client node talks to it through real DDS topics and the service; the
verdicts are compared with grasp_fc_ros.core on the same grasps. The node here has no
worker processes (workers=0), so that tests can break the core by monkeypatching; the
worker processes are tested in test_node_load.py and test_node_process.py. A node can
be given a pool of its own (``ForceClosureNode(pool=...)``): :class:`StalledPool` holds
its lanes at their first decision.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest
from rclpy.parameter import Parameter

from grasp_fc_ros.core import Status, check_force_closure
from grasp_fc_ros.core.model.grasp_input import show_value
from grasp_fc_ros.engine import evaluation as evaluation_module
from grasp_fc_ros.engine.pool import EvaluationPool
from grasp_fc_ros.interface.conversions import (
    Verdicts,
    grasp_to_contact_array,
    grasps_to_batch_msg,
    verdict_array_to_numpy,
)
from grasp_fc_ros.node import ForceClosureNode
from grasp_fc_ros.node import services as services_module
from grasp_fc_ros.node.lane import SHUTDOWN_MESSAGE
from grasp_fc_ros.objects import make_object, sample_grasps
from ros_fixtures import REPLY_TIMEOUT_S, Client, SpinThread

pytestmark = pytest.mark.timeout(120)

DEFAULT_MU = 0.5
# The exact test's margin depends on which grasps share a solver call, to solver accuracy.
MARGIN_ABS_TOL = 1e-6
MARGIN_REL_TOL = 1e-4
# Time to make sure no second, unexpected verdict follows the expected ones.
QUIET_S = 0.5


@pytest.fixture(scope="module")
def system(ros):
    """(node, client): the node on its executor thread and a connected client."""
    node = ForceClosureNode(parameter_overrides=[Parameter("workers", value=0)])
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


class StalledPool(EvaluationPool):
    """A pool without workers whose decisions wait for release() (the first one sets
    ``entered``), then decide as usual: a cancel meanwhile still cancels."""

    def __init__(self):
        super().__init__(workers=0)
        self.entered = threading.Event()
        self._released = threading.Event()

    def decide(self, *args, **kwargs):
        self.entered.set()
        self._released.wait(REPLY_TIMEOUT_S)
        return super().decide(*args, **kwargs)

    def release(self):
        self._released.set()


def raise_once(monkeypatch, target, name, message):
    """Make ``target.name`` raise RuntimeError(message) on its first call only."""
    real = getattr(target, name)
    calls = []

    def flaky(*args, **kwargs):
        calls.append(1)
        if len(calls) == 1:
            raise RuntimeError(message)
        return real(*args, **kwargs)

    monkeypatch.setattr(target, name, flaky)
    return calls


@pytest.fixture(scope="module")
def grasps():
    """200 random 4-finger grasps on the box: positions, normals (200, 4, 3).

    Four fingers: few enough that the node's use_filter (the core's "auto") runs the
    filter, so every decision path shows up."""
    return sample_grasps(make_object("box"), 200, 4, np.random.default_rng(1))


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
    mu = np.full((8, 4), DEFAULT_MU)
    positions[1, 2, 0] = np.nan
    normals[3, 3] = 0.0
    positions[5, 0, 1] = np.inf
    mu[6, 1] = np.nan
    got = send_batch(client, grasps_to_batch_msg(np.arange(8) + 1000, positions, normals,
                                                 mu=mu))
    bad = [1, 3, 5, 6]
    assert (got.status[bad] == Status.INVALID_INPUT).all()
    assert not got.force_closure[bad].any()
    assert got.messages[1] == ("grasp 1 (id 1001), contact 2: position is not finite, got "
                               f"{show_value(positions[1, 2])}")
    assert got.messages[3] == ("grasp 3 (id 1003), contact 3: normal has zero length, "
                               "got (0, 0, 0)")
    assert got.messages[6].startswith("grasp 6 (id 1006), contact 1: ")
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
    assert got.messages[0].startswith("grasp 0 (id 7): 1 contacts")
    assert f"max_contacts={max_contacts}" in got.messages[2] and "(id 9)" in got.messages[2]
    assert got.status[3] != Status.INVALID_INPUT


@pytest.mark.parametrize("corrupt", ["counts_exceed_arrays", "fewer_counts_than_ids",
                                     "normals_shorter", "friction_length_wrong",
                                     "one_contact_too_many"])
def test_mis_packed_batch_is_invalid_as_a_whole(client, grasps, corrupt):
    positions, normals = (a[:5] for a in grasps)
    msg = grasps_to_batch_msg(np.arange(5), positions, normals)
    if corrupt == "counts_exceed_arrays":
        msg.contact_counts[4] = 7
    elif corrupt == "fewer_counts_than_ids":
        msg.contact_counts = msg.contact_counts[:3]
    elif corrupt == "normals_shorter":
        msg.normals = msg.normals[:-4]
    elif corrupt == "friction_length_wrong":
        msg.friction_coefficients = [0.5] * 13  # 30 contacts declared
    else:
        # The case: one contact more than the counts declare; reading it would
        # shift contacts between grasps.
        msg.positions.extend([0.0, 0.0, 1.0])
        msg.normals.extend([0.0, 0.0, -1.0])
    got = send_batch(client, msg)
    np.testing.assert_array_equal(got.ids, np.arange(5))
    assert (got.status == Status.INVALID_INPUT).all()
    assert not got.force_closure.any()
    assert got.messages[0].startswith("malformed batch: ")
    assert len(set(got.messages)) == 1


def test_oversized_batch_is_rejected_whole(client, fc_node, grasps):
    positions, normals = (a[:4] for a in grasps)
    fc_node.set_parameters([Parameter("max_batch", value=3)])
    try:
        got = send_batch(client, grasps_to_batch_msg(np.arange(4), positions, normals))
    finally:
        fc_node.set_parameters([Parameter("max_batch", value=100_000)])
    assert (got.status == Status.INVALID_INPUT).all()
    assert "max_batch=3" in got.messages[0]


def test_oversized_service_request_is_refused_before_conversion(client, fc_node, grasps,
                                                                monkeypatch):
    positions, normals = (a[:4] for a in grasps)

    def no_conversion(*args, **kwargs):
        raise AssertionError("an oversized request was converted")

    monkeypatch.setattr(services_module, "contact_arrays_to_packed", no_conversion)
    fc_node.set_parameters([Parameter("max_batch", value=3)])
    try:
        verdicts = client.call([grasp_to_contact_array(20 + i, positions[i], normals[i])
                                for i in range(4)])
    finally:
        fc_node.set_parameters([Parameter("max_batch", value=100_000)])
    assert [v.id for v in verdicts] == [20, 21, 22, 23]
    assert all(v.status == Status.INVALID_INPUT for v in verdicts)
    assert verdicts[0].message == "4 grasps exceed max_batch=3"


def test_service_request_of_more_contacts_than_max_message_contacts_is_refused_whole(
        client, fc_node, grasps, monkeypatch):
    """A raw client's request (GraspClient splits its calls below the limit): every
    grasp INVALID_INPUT naming the limit, none converted; the node goes on answering."""
    positions, normals = grasps  # 4 contacts each
    real_conversion = services_module.contact_arrays_to_packed

    def no_conversion(*args, **kwargs):
        raise AssertionError("an oversized request was converted")

    fc_node.set_parameters([Parameter("max_message_contacts", value=20)])
    try:
        monkeypatch.setattr(services_module, "contact_arrays_to_packed", no_conversion)
        refused = client.call([grasp_to_contact_array(30 + i, positions[i], normals[i])
                               for i in range(6)])  # 24 contacts
        monkeypatch.setattr(services_module, "contact_arrays_to_packed", real_conversion)
        within = client.call([grasp_to_contact_array(40 + i, positions[i], normals[i])
                              for i in range(5)])  # 20 contacts
    finally:
        fc_node.set_parameters([Parameter("max_message_contacts", value=491_520)])
    assert [v.id for v in refused] == list(range(30, 36))
    assert all(v.status == Status.INVALID_INPUT and not v.force_closure for v in refused)
    assert {v.message for v in refused} == {
        "24 contacts in one request exceed max_message_contacts=20: split it into "
        "requests of whole grasps (GraspClient does)"}
    assert all(math.isnan(v.margin) and math.isnan(v.epsilon_lower) for v in refused)
    assert [v.id for v in within] == list(range(40, 45))
    expected = check_force_closure(positions[:5], normals[:5], DEFAULT_MU)
    assert [v.status for v in within] == expected.status.tolist()


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
    assert verdicts[4].status == Status.INVALID_INPUT
    assert verdicts[4].message == ("grasp 4 (id 104), contact 0: normal has zero length, "
                                   f"got {show_value(normals[4, 0] * 0.0)}")
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
        msg = grasps_to_batch_msg(np.arange(50), positions, normals, mu=np.zeros((50, 4)))
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
    ("max_contacts", 1, "out of range"),
    ("max_batch", 0, "out of range"),
    ("workers", 1, "read-only"),
    ("worker_timeout_s", 60.0, "read-only"),
])
def test_bad_parameter_values_are_rejected_with_a_reason(fc_node, name, value, why):
    before = fc_node.get_parameter(name).value
    result = fc_node.set_parameters([Parameter(name, value=value)])[0]
    assert not result.successful
    assert why in result.reason
    assert fc_node.get_parameter(name).value == before


def test_worker_timeout_reaches_the_pool_and_is_checked_at_start(ros):
    node = ForceClosureNode(parameter_overrides=[Parameter("workers", value=1),
                                                 Parameter("worker_timeout_s", value=5.0)])
    try:
        assert node.pool.worker_timeout_s == 5.0
    finally:
        node.destroy_node()
    with pytest.raises(Exception, match="worker_timeout_s"):
        ForceClosureNode(parameter_overrides=[Parameter("workers", value=0),
                                              Parameter("worker_timeout_s", value=0.5)])


def test_good_parameter_values_are_accepted_and_used(client, fc_node, grasps):
    positions, normals = grasps
    result = fc_node.set_parameters([Parameter("filter_origins", value="all")])[0]
    try:
        got = send_batch(client, grasps_to_batch_msg(np.arange(len(positions)), positions,
                                                     normals))
    finally:
        fc_node.set_parameters([Parameter("filter_origins", value="seed")])
    assert result.successful
    expected = check_force_closure(positions, normals, DEFAULT_MU, origins="all")
    np.testing.assert_array_equal(got.status, expected.status)
    # The origins must matter on this sample, or the test could not fail.
    seed = check_force_closure(positions, normals, DEFAULT_MU, origins="seed")
    assert (seed.status != expected.status).any()


def test_core_exception_becomes_solver_failure_and_node_survives(client, grasps, monkeypatch):
    positions, normals = (a[:3] for a in grasps)

    def broken(*args, **kwargs):
        raise RuntimeError("solver exploded")

    monkeypatch.setattr(evaluation_module, "check_force_closure", broken)
    got = send_batch(client, grasps_to_batch_msg([1, 2, 3], positions, normals))
    assert (got.status == Status.SOLVER_FAILURE).all()
    assert "solver exploded" in got.messages[0]
    [verdict] = client.call([grasp_to_contact_array(4, positions[0], normals[0])])
    assert verdict.status == Status.SOLVER_FAILURE
    monkeypatch.undo()
    client.clear()
    got = send_batch(client, grasps_to_batch_msg([5], positions[:1], normals[:1]))
    assert got.status[0] != Status.SOLVER_FAILURE


def diagnostics_change(before: dict, after: dict) -> dict:
    """after - before for the integer counters of two diagnostics readings."""
    return {k: int(after[k]) - int(before[k]) for k in before if before[k].isdigit()}


def test_diagnostics_report_exact_counter_changes(client, grasps):
    positions, normals = (a[:20].copy() for a in grasps)
    normals[3] *= np.nan
    expected = check_force_closure(positions[4:], normals[4:], DEFAULT_MU).status
    before = client.diagnostics_after(time.time())
    send_batch(client, grasps_to_batch_msg(np.arange(4, 20), positions[4:], normals[4:]))
    client.call([grasp_to_contact_array(i, positions[i], normals[i]) for i in range(3)])
    client.contacts_pub.publish(grasp_to_contact_array(3, positions[3], normals[3]))
    client.wait_for("verdicts", 1)
    after = client.diagnostics_after(time.time())

    keys = {"received", "answered", "queries", "force_closure", "rejected_by_filter",
            "decided_by_exact_test", "invalid_input", "solver_failures", "callback_errors",
            "overloaded",
            "pending_single_queries", "pending_batch_grasps", "conversion_time_total_s",
            "validation_time_total_s", "filter_time_total_s", "exact_time_total_s",
            "processing_time_mean_ms", "processing_time_p99_ms",
            "markers_published", "markers_dropped", "worker_restarts", "messages_lost"}
    # The label_grasps action's goal counters (test_action.py checks their values).
    keys |= {"action_goals_received", "action_goals_succeeded", "action_goals_canceled",
             "action_goals_aborted", "action_goals_queued", "action_goals_running",
             "action_grasps_undecided"}
    assert set(after) == keys
    served = check_force_closure(positions[:3], normals[:3], DEFAULT_MU).status
    statuses = np.concatenate([expected, served])
    assert diagnostics_change(before, after) == {
        "received": 20,
        "answered": 20,
        "queries": 20,
        "force_closure": int((statuses == Status.FORCE_CLOSURE).sum()),
        "rejected_by_filter": int((statuses == Status.FILTERED_OUT).sum()),
        "decided_by_exact_test": int(np.isin(statuses, [Status.FORCE_CLOSURE,
                                                   Status.NOT_FORCE_CLOSURE]).sum()),
        "invalid_input": 1,
        "solver_failures": 0,
        "callback_errors": 0,
        "overloaded": 0,
        "pending_single_queries": 0,
        "pending_batch_grasps": 0,
        **{key: 0 for key in keys if key.startswith("action_")},  # no goal was sent
        "markers_published": 0,  # publish_markers is off by default
        "markers_dropped": 0,
        "worker_restarts": 0,
        "messages_lost": 0,
    }
    for key in ("conversion_time_total_s", "validation_time_total_s", "filter_time_total_s",
                "exact_time_total_s"):
        assert float(after[key]) >= float(before[key])
    assert float(after["exact_time_total_s"]) > float(before["exact_time_total_s"])
    assert float(after["processing_time_mean_ms"]) > 0
    assert float(after["processing_time_p99_ms"]) > 0


def test_single_query_message_names_its_id_and_contact(client, grasps):
    positions, normals = (a[0].copy() for a in grasps)
    normals[2] = 0.0
    client.contacts_pub.publish(grasp_to_contact_array(4242, positions, normals))
    [verdict] = client.wait_for("verdicts", 1)
    assert verdict.id == 4242 and verdict.status == Status.INVALID_INPUT
    assert verdict.message == "query id 4242, contact 2: normal has zero length, got (0, 0, 0)"


@pytest.mark.parametrize("bad_mu", [-math.inf, math.inf, math.nan])
def test_non_finite_contact_friction_is_invalid_not_default(client, grasps, bad_mu):
    positions, normals = (a[:2] for a in grasps)
    mu = np.full(4, 0.0)  # 0: the node's friction_coefficient
    mu[3] = bad_mu
    verdicts = client.call([grasp_to_contact_array(1, positions[0], normals[0], mu=mu),
                            grasp_to_contact_array(2, positions[1], normals[1], mu=0.0)])
    assert verdicts[0].status == Status.INVALID_INPUT
    assert verdicts[0].message == ("grasp 0 (id 1), contact 3: friction coefficient is not "
                                   f"finite, got {bad_mu}")
    assert verdicts[1].status == check_force_closure(positions[1], normals[1], DEFAULT_MU).status


def test_negative_contact_friction_is_invalid_input_and_zero_is_the_default(client, grasps):
    """Interface 1.0: 0 means the node's friction_coefficient, a negative value is refused
    with its value and contact, on the service, the batch topic and the single topic."""
    positions, normals = (a[:3] for a in grasps)
    mu = np.zeros((3, 4))
    mu[1, 2] = -0.3
    expected_message = ("contact 2: friction coefficient must be > 0, got -0.3 (0 uses the "
                        f"node's friction_coefficient, {DEFAULT_MU:g})")
    client.clear()
    served = client.call([grasp_to_contact_array(i, positions[i], normals[i], mu=mu[i])
                          for i in range(3)])
    batch = send_batch(client, grasps_to_batch_msg(np.arange(3), positions, normals, mu=mu))
    client.contacts_pub.publish(grasp_to_contact_array(77, positions[1], normals[1], mu=mu[1]))
    [single] = client.wait_for("verdicts", 1)
    core = check_force_closure(positions, normals, DEFAULT_MU).status
    for status in ([v.status for v in served], batch.status.tolist()):
        assert status == [core[0], Status.INVALID_INPUT, core[2]]
    assert served[1].message == f"grasp 1 (id 1), {expected_message}"
    assert batch.messages[1] == f"grasp 1 (id 1), {expected_message}"
    assert not served[1].force_closure and not batch.force_closure[1]
    assert single.id == 77 and single.status == Status.INVALID_INPUT
    assert single.message == f"query id 77, {expected_message}"


def test_single_queries_beyond_max_batch_are_refused_at_once(own_node, grasps):
    stall = StalledPool()
    node, _, client = own_node("overload_test", pool=stall, max_batch=5)
    positions, normals = (a[:12] for a in grasps)
    client.contacts_pub.publish(grasp_to_contact_array(0, positions[0], normals[0]))
    assert stall.entered.wait(REPLY_TIMEOUT_S), "worker never took query 0"
    before = client.diagnostics_after(time.time(), "/overload_test/force_closure")
    for i in range(1, 12):  # 1..5 fill the queue, 6..11 overflow it
        client.contacts_pub.publish(grasp_to_contact_array(i, positions[i], normals[i]))
    refused = client.wait_for("verdicts", 6)  # while the worker is still held
    assert [v.id for v in refused] == list(range(6, 12))
    for v in refused:
        assert v.status == Status.SOLVER_FAILURE and not v.force_closure
        assert v.message == "node overloaded: 5 single-grasp queries pending"
    stall.release()
    client.wait_for("verdicts", 12)
    time.sleep(QUIET_S)
    received = client.wait_for("verdicts", 12)
    assert len(received) == 12, "a query got more than one verdict"
    answered = received[6:]
    assert [v.id for v in answered] == list(range(6))
    expected = check_force_closure(positions[:6], normals[:6], DEFAULT_MU)
    assert [v.status for v in answered] == expected.status.tolist()
    after = client.diagnostics_after(time.time(), "/overload_test/force_closure")
    change = diagnostics_change(before, after)
    assert change["overloaded"] == 6 and change["solver_failures"] == 6
    assert change["queries"] == 12  # query 0 is counted once answered


def test_core_failure_in_one_drain_fails_those_queries_only(client, grasps, monkeypatch):
    positions, normals = (a[:2] for a in grasps)
    raise_once(monkeypatch, evaluation_module, "check_force_closure", "solver exploded once")
    client.contacts_pub.publish(grasp_to_contact_array(31, positions[0], normals[0]))
    [failed] = client.wait_for("verdicts", 1)
    assert failed.id == 31 and failed.status == Status.SOLVER_FAILURE
    assert "solver exploded once" in failed.message
    client.contacts_pub.publish(grasp_to_contact_array(32, positions[1], normals[1]))
    later = client.wait_for("verdicts", 2)[1]
    assert later.id == 32
    assert later.status == check_force_closure(positions[1], normals[1], DEFAULT_MU).status


def test_worker_survives_failed_publishing(client, fc_node, grasps, monkeypatch):
    positions, normals = (a[:3] for a in grasps)
    publish = fc_node.replies.publish_verdict
    failures_left = [0]

    def flaky(msg):
        if failures_left[0]:
            failures_left[0] -= 1
            raise RuntimeError("publisher hiccup")
        publish(msg)

    monkeypatch.setattr(fc_node.replies, "publish_verdict", flaky)
    before = client.diagnostics_after(time.time())
    # One failure: the query is answered with SOLVER_FAILURE instead of its verdict.
    failures_left[0] = 1
    client.contacts_pub.publish(grasp_to_contact_array(41, positions[0], normals[0]))
    [first] = client.wait_for("verdicts", 1)
    assert first.id == 41 and first.status == Status.SOLVER_FAILURE
    assert "publisher hiccup" in first.message
    # Two failures: even the failure verdict cannot be sent; the worker must go on.
    failures_left[0] = 2
    client.contacts_pub.publish(grasp_to_contact_array(42, positions[1], normals[1]))
    deadline = time.monotonic() + REPLY_TIMEOUT_S
    while failures_left[0] and time.monotonic() < deadline:
        time.sleep(0.01)
    client.contacts_pub.publish(grasp_to_contact_array(43, positions[2], normals[2]))
    received = client.wait_for("verdicts", 2)
    time.sleep(QUIET_S)
    assert [v.id for v in client.wait_for("verdicts", 2)] == [41, 43]
    assert received[1].status == check_force_closure(positions[2], normals[2], DEFAULT_MU).status
    change = diagnostics_change(before, client.diagnostics_after(time.time()))
    assert change["callback_errors"] == 3


def test_service_failure_while_building_the_response_is_answered(client, grasps, monkeypatch):
    positions, normals = (a[:2] for a in grasps)
    raise_once(monkeypatch, services_module, "verdicts_to_msgs", "cannot build verdicts")
    verdicts = client.call([grasp_to_contact_array(51 + i, positions[i], normals[i])
                            for i in range(2)])
    assert [v.id for v in verdicts] == [51, 52]
    assert all(v.status == Status.SOLVER_FAILURE for v in verdicts)
    assert "cannot build verdicts" in verdicts[0].message
    [again] = client.call([grasp_to_contact_array(53, positions[0], normals[0])])
    assert again.status == check_force_closure(positions[0], normals[0], DEFAULT_MU).status


def test_failed_batch_reply_is_counted_once_and_not_timed(client, fc_node, grasps,
                                                          monkeypatch):
    positions, normals = (a[:3] for a in grasps)
    before = client.diagnostics_after(time.time())
    raise_once(monkeypatch, fc_node.replies, "batch_answer", "cannot pack verdicts")
    got = send_batch(client, grasps_to_batch_msg([61, 62, 63], positions, normals))
    np.testing.assert_array_equal(got.ids, [61, 62, 63])
    assert (got.status == Status.SOLVER_FAILURE).all()
    assert "cannot pack verdicts" in got.messages[0]
    after = client.diagnostics_after(time.time())
    change = diagnostics_change(before, after)
    assert change["queries"] == 3 and change["solver_failures"] == 3
    assert change["callback_errors"] == 1
    assert change["force_closure"] == change["rejected_by_filter"] == 0
    # A failure adds no processing time sample: mean and p99 stay as they were.
    assert after["processing_time_mean_ms"] == before["processing_time_mean_ms"]
    assert after["processing_time_p99_ms"] == before["processing_time_p99_ms"]


def test_parameters_are_read_once_per_message(client, fc_node, grasps, monkeypatch):
    rng = np.random.default_rng(7)
    box = make_object("box")
    sizes = np.array([4, 6, 4, 6])
    positions = np.concatenate([sample_grasps(box, 1, int(n), rng)[0][0] for n in sizes])
    calls = []
    real = evaluation_module.check_force_closure

    def changing_parameters(*args, **kwargs):
        calls.append(kwargs["use_filter"])
        # A parameter change (from another thread in real life) while one batch is decided.
        fc_node.set_parameters([Parameter("use_filter", value=False)])
        return real(*args, **kwargs)

    monkeypatch.setattr(evaluation_module, "check_force_closure", changing_parameters)
    try:
        send_batch(client, grasps_to_batch_msg(np.arange(4), positions, -positions,
                                               counts=sizes))
    finally:
        fc_node.set_parameters([Parameter("use_filter", value=True)])
    assert calls == ["auto", "auto"]  # one core call per contact count, same settings


def test_queued_single_queries_are_answered_at_shutdown(own_node, grasps):
    stall = StalledPool()
    node, spinner, client = own_node("shutdown_test", pool=stall)
    positions, normals = (a[:4] for a in grasps)
    client.contacts_pub.publish(grasp_to_contact_array(0, positions[0], normals[0]))
    assert stall.entered.wait(REPLY_TIMEOUT_S), "worker never took query 0"
    for i in range(1, 4):
        client.contacts_pub.publish(grasp_to_contact_array(i, positions[i], normals[i]))
    deadline = time.monotonic() + REPLY_TIMEOUT_S
    while node.single_queries.pending < 3 and time.monotonic() < deadline:
        time.sleep(0.01)
    stopper = threading.Thread(target=spinner.stop)
    stopper.start()
    while not node.single_queries.stopping() and time.monotonic() < deadline:
        time.sleep(0.01)
    stall.release()
    stopper.join(REPLY_TIMEOUT_S)
    received = client.wait_for("verdicts", 4)
    # Query 0 was being decided: that work is abandoned, and it is answered like the rest.
    assert [v.id for v in received] == [0, 1, 2, 3]
    for v in received:
        assert v.status == Status.SOLVER_FAILURE and v.message == SHUTDOWN_MESSAGE
    time.sleep(QUIET_S)
    assert len(client.wait_for("verdicts", 4)) == 4, "a query got two verdicts"


def test_stacked_contacts_without_counts_are_refused():
    positions = np.ones((12, 3))
    with pytest.raises(ValueError, match="counts"):
        grasps_to_batch_msg([1, 2], positions, positions)
    msg = grasps_to_batch_msg([1, 2], positions, positions, counts=[5, 7])
    assert list(msg.contact_counts) == [5, 7]


def test_a_second_node_with_the_same_name_is_logged(own_node, capfd):
    own_node("/duplicate_test", workers=0)
    twin = ForceClosureNode(namespace="/duplicate_test",
                            parameter_overrides=[Parameter("workers", value=0)])
    spinner = SpinThread(twin)
    try:
        deadline = time.monotonic() + REPLY_TIMEOUT_S
        logged = ""
        while "another node is named /duplicate_test/force_closure" not in logged:
            assert time.monotonic() < deadline, "the twin was never reported"
            time.sleep(0.2)
            logged += capfd.readouterr().err
    finally:
        spinner.stop()
