"""The node's label_grasps action through DDS: feedback rate, cancel, prefixes, side by side.

Every verdict is checked against grasp_fc_ros.core.check_force_closure on the same
grasps. Timing bounds are generous (a shared 2-core machine); the real figures are
measured by benchmarks/bench_action.py.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from action_msgs.msg import GoalStatus

from grasp_fc_ros.core import Status, check_force_closure
from grasp_fc_ros.objects import make_object, sample_grasps

pytestmark = pytest.mark.timeout(240)

N_UNIQUE = 3000
N_FINGERS = 6
# A long goal should take about this long on the node's one worker (s); its size is
# measured per run (the rate varies several-fold with the machine and its load).
LONG_GOAL_S = 5.0
LONG_GOAL_RANGE = (20 * N_UNIQUE, 480_000)
WAIT_S = 60.0
# Bounds asserted here; the action aims at 1 s between feedbacks and 0.1 s per cancel.
FEEDBACK_GAP_BOUND_S = 1.5
CANCEL_BOUND_S = 1.0


@pytest.fixture(scope="module")
def grasps():
    positions, normals = sample_grasps(make_object("box"), N_UNIQUE, N_FINGERS,
                                       np.random.default_rng(7))
    expected = check_force_closure(positions, normals, 0.5).status
    return positions, normals, np.asarray(expected, dtype=np.uint8)


def tiled(grasps, n_grasps):
    """The first n_grasps of the unique grasps repeated: (positions, normals, statuses)."""
    positions, normals, expected = grasps
    reps = -(-n_grasps // len(positions))
    return tuple(np.concatenate([a] * reps)[:n_grasps] for a in (positions, normals, expected))


@pytest.fixture(scope="module")
def served(ros):
    """A node with one worker in a namespace of its own, and a GraspClient of it; it takes
    raw goals of any number of contacts (these tests send long goals as one message)."""
    from rclpy.parameter import Parameter

    from grasp_fc_ros.client import GraspClient
    from grasp_fc_ros.node import ForceClosureNode
    from ros_fixtures import SpinThread

    namespace = "/action_test"
    node = ForceClosureNode(namespace=namespace, parameter_overrides=[
        Parameter("workers", value=1), Parameter("max_batch", value=500_000),
        Parameter("max_message_contacts", value=0)])
    spinner = SpinThread(node)
    client = GraspClient(f"{namespace}/force_closure")
    assert client.wait_for_node(timeout=30.0)
    yield node, client
    client.close()
    spinner.stop()


class Goal:
    """One goal sent with a raw ActionClient: feedback with arrival times, result.

    ``action``: (ActionClient, the node it is on, spun by another thread). Requests are
    made on that thread (``request_on_spin_thread``: rclpy's ActionClient loses a
    response taken between sending a request and registering its future).
    """

    def __init__(self, action, batch):
        from grasp_fc_msgs.action import LabelGrasps

        from grasp_fc_ros.client import request_on_spin_thread

        action_client, node = action
        self._request = lambda request: request_on_spin_thread(node, request)
        self.feedback: list[tuple[float, object]] = []
        self.sent_at = time.monotonic()
        self.accepted_at = None  # when the goal response came (the goal crossed DDS)
        accepted = threading.Event()
        future = self._request(lambda: action_client.send_goal_async(
            LabelGrasps.Goal(grasps=batch), feedback_callback=self._on_feedback))
        future.add_done_callback(lambda _: self._on_accepted(accepted))
        assert accepted.wait(WAIT_S), "goal not accepted in time"
        self.handle = future.result()
        assert self.handle.accepted
        self.done = threading.Event()
        self.result_future = self._request(self.handle.get_result_async)
        self.result_future.add_done_callback(self._on_result)
        self.ended_at = None

    def cancel(self):
        self._request(self.handle.cancel_goal_async)

    def _on_accepted(self, accepted: threading.Event):
        self.accepted_at = time.monotonic()
        accepted.set()

    def _on_feedback(self, msg):
        self.feedback.append((time.monotonic(), msg.feedback))

    def _on_result(self, _):
        self.ended_at = time.monotonic()
        self.done.set()

    def result(self, timeout=WAIT_S):
        assert self.done.wait(timeout), "no result in time"
        response = self.result_future.result()
        return response.status, response.result.verdicts

    def wait_for_progress(self, timeout=WAIT_S):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.feedback and self.feedback[-1][1].done > 0:
                return self.feedback[-1][1].done
            time.sleep(0.01)
        raise AssertionError("no progress reported")


@pytest.fixture(scope="module")
def action_client(served):
    from grasp_fc_msgs.action import LabelGrasps
    from rclpy.action import ActionClient

    _, client = served
    action = ActionClient(client.node, LabelGrasps, "/action_test/label_grasps")
    assert action.wait_for_server(timeout_sec=30.0)
    return action, client.node


@pytest.fixture(scope="module")
def long_goal(grasps, action_client):
    """Grasps in a goal that takes about LONG_GOAL_S here, from measured goals: the
    fastest of three, since the first goals of a fresh checkout are slowed by one-off
    work (numba loading or compiling in the worker; a cold CI run sized the goal 1.4 s)."""
    positions, normals, _ = grasps
    rates = []
    for _ in range(3):
        goal = Goal(action_client, batch_msg(positions, normals))
        goal.result()
        rates.append(len(positions) / (goal.ended_at - goal.sent_at))
    return int(np.clip(max(rates) * LONG_GOAL_S, *LONG_GOAL_RANGE))


def batch_msg(positions, normals, ids=None):
    from grasp_fc_ros.interface.conversions import grasps_to_batch_msg

    ids = np.arange(len(positions)) if ids is None else ids
    return grasps_to_batch_msg(ids, positions, normals)


def assert_prefix(verdicts, expected, n=None):
    from grasp_fc_ros.interface.conversions import verdict_array_to_numpy

    got = verdict_array_to_numpy(verdicts)
    n = len(got) if n is None else n
    assert len(got) == n
    np.testing.assert_array_equal(got.ids, np.arange(n))
    np.testing.assert_array_equal(got.status, expected[:n])
    return got


def test_feedback_comes_at_least_once_a_second_and_verdicts_equal_the_core(
        grasps, action_client, long_goal):
    positions, normals, expected = tiled(grasps, long_goal)
    goal = Goal(action_client, batch_msg(positions, normals))
    status, verdicts = goal.result()
    assert status == GoalStatus.STATUS_SUCCEEDED
    assert_prefix(verdicts, expected, long_goal)
    # From the goal's acceptance: before it, the goal (~100 MB at ~300,000 grasps) is
    # crossing DDS, 1.3-1.7 s here, which is not the node deciding it.
    duration = goal.ended_at - goal.accepted_at
    assert duration > 2.0, f"goal took only {duration:.2f} s: too short to judge the rate"
    times = [goal.accepted_at] + [t for t, _ in goal.feedback] + [goal.ended_at]
    assert max(np.diff(times)) < FEEDBACK_GAP_BOUND_S
    assert len(goal.feedback) >= duration - 1
    done = [f.done for _, f in goal.feedback]
    assert done == sorted(done) and done[-1] <= long_goal
    for _, f in goal.feedback:
        assert f.total == long_goal
        assert (f.force_closure + f.not_force_closure + f.filtered_out + f.invalid_input
                + f.solver_failure) == f.done
    last = goal.feedback[-1][1]
    part = expected[:last.done]
    assert last.force_closure == np.sum(part == Status.FORCE_CLOSURE)
    assert last.filtered_out == np.sum(part == Status.FILTERED_OUT)
    assert last.grasps_per_second > 0


def test_cancel_returns_the_decided_prefix_within_a_second(grasps, action_client,
                                                           long_goal):
    positions, normals, expected = tiled(grasps, long_goal)
    goal = Goal(action_client, batch_msg(positions, normals))
    reported = goal.wait_for_progress()
    cancel_at = time.monotonic()
    goal.cancel()
    status, verdicts = goal.result()
    latency = goal.ended_at - cancel_at
    assert status == GoalStatus.STATUS_CANCELED
    assert latency < CANCEL_BOUND_S, f"cancel took {latency:.3f} s"
    got = assert_prefix(verdicts, expected)  # nothing lost, nothing out of order
    assert reported <= len(got) < long_goal


def test_two_goals_side_by_side_while_the_topic_and_the_service_answer(
        grasps, served, action_client, long_goal):
    _, client = served
    positions, normals, expected = tiled(grasps, long_goal // 2)
    goals = [Goal(action_client, batch_msg(positions, normals)) for _ in range(2)]
    for goal in goals:
        goal.wait_for_progress()  # both run: the second does not wait for the first
    single_at = time.monotonic()
    single = client.submit(positions[5], normals[5], query_id=5).result(timeout=WAIT_S)
    single_s = time.monotonic() - single_at
    served_at = time.monotonic()
    answer = client.call(positions[:3], normals[:3], timeout=WAIT_S)
    service_s = time.monotonic() - served_at
    batch_at = time.monotonic()
    batch = client.check_batch(positions[:10], normals[:10], timeout=WAIT_S)
    batch_s = time.monotonic() - batch_at
    # Published about once a second whatever the goals do.
    diagnostics = client.next_diagnostics(timeout=2.5)
    assert not any(goal.done.is_set() for goal in goals), "goals too short for this test"
    assert single.status == expected[5] and list(answer.status) == list(expected[:3])
    assert list(batch.status) == list(expected[:10])
    assert single_s < 1.0 and service_s < 1.0 and batch_s < 2.0, (single_s, service_s, batch_s)
    assert diagnostics["action_goals_running"] == "2"
    for goal in goals:
        status, verdicts = goal.result()
        assert status == GoalStatus.STATUS_SUCCEEDED
        assert_prefix(verdicts, expected, long_goal // 2)


def test_malformed_and_oversized_goals_get_invalid_input_verdicts(grasps, served,
                                                                   action_client):
    positions, normals, _ = grasps
    malformed = batch_msg(positions[:4], normals[:4])
    malformed.contact_counts = malformed.contact_counts[:3]
    status, verdicts = Goal(action_client, malformed).result()
    assert status == GoalStatus.STATUS_SUCCEEDED
    assert list(verdicts.status) == [Status.INVALID_INPUT] * 4
    assert all(m.startswith("malformed batch: 3 contact counts for 4 ids")
               for m in verdicts.messages)

    from rclpy.parameter import Parameter

    node, _ = served
    node.set_parameters([Parameter("max_batch", value=1000)])
    try:
        oversized = batch_msg(np.ones((1001, 2, 3)), np.ones((1001, 2, 3)))
        status, verdicts = Goal(action_client, oversized).result()
    finally:
        node.set_parameters([Parameter("max_batch", value=500_000)])
    assert status == GoalStatus.STATUS_SUCCEEDED and len(verdicts.status) == 1001
    assert set(verdicts.status) == {Status.INVALID_INPUT}
    assert verdicts.messages[0] == "1001 grasps exceed max_batch=1000"

    node.set_parameters([Parameter("max_message_contacts", value=20)])
    try:
        too_big = Goal(action_client, batch_msg(positions[:4], normals[:4]))
        status, verdicts = too_big.result()
    finally:
        node.set_parameters([Parameter("max_message_contacts", value=0)])
    assert status == GoalStatus.STATUS_SUCCEEDED and too_big.feedback == []  # (docs/node.rst)
    assert list(verdicts.status) == [Status.INVALID_INPUT] * 4
    assert verdicts.messages[0] == ("24 contacts in one message exceed "
                                    "max_message_contacts=20: split it into messages of "
                                    "whole grasps (GraspClient does)")

    zero_normal = normals[:3].copy()
    zero_normal[1, 0] = 0.0  # grasp 1, contact 0
    bad = batch_msg(positions[:3], zero_normal)
    status, verdicts = Goal(action_client, bad).result()
    assert [s == Status.INVALID_INPUT for s in verdicts.status] == [False, True, False]
    assert verdicts.messages[1] == ("grasp 1 (id 1), contact 0: normal has zero length, "
                                    "got (0, 0, 0)")


def test_diagnostics_count_the_goals(grasps, served, action_client):
    _, client = served
    before = client.next_diagnostics(timeout=10.0)
    positions, normals, _ = grasps
    Goal(action_client, batch_msg(positions[:50], normals[:50])).result()
    time.sleep(0.1)
    after = client.next_diagnostics(timeout=10.0)
    for key in ("received", "succeeded"):
        key = f"action_goals_{key}"
        assert int(after[key]) == int(before[key]) + 1, key
    assert int(after["answered"]) >= int(before["answered"]) + 50
    assert after["action_goals_running"] == "0" and after["action_goals_queued"] == "0"


def test_client_label_grasps_returns_all_verdicts_in_order(grasps, served):
    _, client = served
    positions, normals, expected = grasps
    verdicts = client.label_grasps(positions, normals, ids=np.arange(1000, 1000 + N_UNIQUE),
                                   progress=False, timeout=WAIT_S)
    assert client.last_goal_status == GoalStatus.STATUS_SUCCEEDED
    np.testing.assert_array_equal(verdicts.ids, np.arange(1000, 1000 + N_UNIQUE))
    np.testing.assert_array_equal(verdicts.status, expected)


def test_client_makes_its_action_requests_on_its_spin_thread(grasps, served, monkeypatch):
    # rclpy's ActionClient registers a request's future only after sending it: a response
    # that the spin thread takes in between is dropped and the goal never resolves (a CI
    # run lost a goal so). Sent from the spin thread, nothing is taken in between.
    _, client = served
    action = client.label_action.action_client
    callers = []

    def recording(real):
        def record(*args, **kwargs):
            callers.append(threading.current_thread())
            return real(*args, **kwargs)
        return record

    for name in ("send_goal_async", "_get_result_async", "_cancel_goal_async"):
        monkeypatch.setattr(action, name, recording(getattr(action, name)))
    positions, normals, expected = grasps
    verdicts = client.label_grasps(positions, normals, progress=False, timeout=WAIT_S)
    np.testing.assert_array_equal(verdicts.status, expected)
    assert len(callers) == 2 * n_parts(positions)  # each part's goal and its result
    assert threading.current_thread() not in callers
    assert all(caller.name == "grasp_client" for caller in callers)  # the spin thread


def test_client_progress_bar_ends_on_the_verdicts_counts(grasps, served, capsys):
    # A short goal is done before a feedback after its first: the bar's last line must
    # still show how many grasps are force closure.
    _, client = served
    positions, normals, expected = grasps
    verdicts = client.label_grasps(positions, normals, progress=True, timeout=WAIT_S)
    assert len(verdicts) == N_UNIQUE
    last_line = capsys.readouterr().err.replace("\r", "\n").strip().splitlines()[-1]
    assert f"{N_UNIQUE}/{N_UNIQUE}" in last_line
    assert f"force_closure={np.count_nonzero(expected == Status.FORCE_CLOSURE)}" in last_line


def test_client_ctrl_c_cancels_the_job_sends_no_more_parts_and_returns_the_prefix(
        grasps, served, long_goal, monkeypatch):
    import grasp_fc_ros.client.label_action as client_module

    _, client = served
    positions, normals, expected = tiled(grasps, long_goal)
    assert n_parts(positions) > 10
    sent_at_cancel = []

    def interrupted(job, bar, started, deadline):
        # Ctrl-C once some verdicts were reported (the real steps, then the interrupt).
        while job.progress().done == 0 or job.sent < 3:
            assert not job.ended(), "job ended before it could be interrupted"
            job.step(0.01)
        sent_at_cancel.append(job.sent)
        raise KeyboardInterrupt

    sent = []
    real_send = client_module.LabelJob._send_next

    def counting_send(job):
        real_send(job)
        sent.append(job.sent)

    monkeypatch.setattr(client_module, "follow_job", interrupted)
    monkeypatch.setattr(client_module.LabelJob, "_send_next", counting_send)
    verdicts = client.label_grasps(positions, normals, progress=True, timeout=WAIT_S)
    assert client.last_goal_status == GoalStatus.STATUS_CANCELED
    assert max(sent) == sent_at_cancel[0] < n_parts(positions)  # none sent after Ctrl-C
    assert 0 < len(verdicts) < long_goal
    np.testing.assert_array_equal(verdicts.ids, np.arange(len(verdicts)))
    np.testing.assert_array_equal(verdicts.status, expected[:len(verdicts)])


def test_client_sends_a_big_job_in_parts_of_whole_grasps_answered_in_order(grasps, served,
                                                                          capsys):
    # Grasps of 4 to 16 contacts, mixed: the parts end between grasps of any size.
    from grasp_fc_ros.interface.names import MAX_MESSAGE_CONTACTS

    _, client = served
    rng = np.random.default_rng(3)
    counts = rng.choice([4, 7, 16], size=2500)
    surface = make_object("ellipsoid")
    groups = {n: sample_grasps(surface, int(np.sum(counts == n)), int(n), rng)
              for n in np.unique(counts)}
    expected = np.empty(len(counts), np.uint8)
    for n, group in groups.items():
        expected[counts == n] = check_force_closure(*group, 0.5).status
    taken = dict.fromkeys(groups, 0)
    grasp_list = []
    for n in counts:
        grasp_list.append((groups[n][0][taken[n]], groups[n][1][taken[n]]))
        taken[n] += 1
    positions = np.concatenate([grasp[0] for grasp in grasp_list])
    normals = np.concatenate([grasp[1] for grasp in grasp_list])
    assert len(positions) > 3 * MAX_MESSAGE_CONTACTS
    parts = n_parts(positions, counts)
    before = client.next_diagnostics(timeout=10.0)
    ids = np.arange(len(counts)) + 10
    verdicts = client.label_grasps(positions, normals, mu=0.5, counts=counts, ids=ids,
                                   progress=True, timeout=WAIT_S)
    assert client.last_goal_status == GoalStatus.STATUS_SUCCEEDED
    np.testing.assert_array_equal(verdicts.ids, ids)
    np.testing.assert_array_equal(verdicts.status, expected)
    # The progress bar counts the whole job, not a part.
    last_line = capsys.readouterr().err.replace("\r", "\n").strip().splitlines()[-1]
    assert f"{len(counts)}/{len(counts)}" in last_line
    assert f"force_closure={np.count_nonzero(expected == Status.FORCE_CLOSURE)}" in last_line
    time.sleep(0.1)
    after = client.next_diagnostics(timeout=10.0)
    assert int(after["action_goals_received"]) - int(before["action_goals_received"]) == parts


def n_parts(positions, counts=None):
    """Goals that GraspClient.label_grasps sends for these grasps."""
    from grasp_fc_ros.client.batches import split_batch
    from grasp_fc_ros.interface.conversions import batch_arrays
    from grasp_fc_ros.interface.names import MAX_MESSAGE_CONTACTS

    n_grasps = len(positions) if counts is None else len(counts)
    fields = batch_arrays(np.arange(n_grasps), positions, normals=positions, counts=counts)
    return len(split_batch(fields, MAX_MESSAGE_CONTACTS))


def test_destroying_the_node_aborts_its_goals_with_their_prefixes(grasps, ros):
    from grasp_fc_msgs.action import LabelGrasps
    from rclpy.action import ActionClient
    from rclpy.parameter import Parameter

    from grasp_fc_ros.client import GraspClient
    from grasp_fc_ros.node import ForceClosureNode
    from grasp_fc_ros.node.label_action import ACTION_THREADS
    from ros_fixtures import SpinThread

    namespace = "/action_shutdown_test"
    node = ForceClosureNode(namespace=namespace, parameter_overrides=[
        Parameter("workers", value=1)])
    spinner = SpinThread(node)
    client = GraspClient(f"{namespace}/force_closure")
    try:
        action = ActionClient(client.node, LabelGrasps, f"{namespace}/label_grasps")
        assert action.wait_for_server(timeout_sec=30.0)
        action = (action, client.node)
        positions, normals, expected = tiled(grasps, 60_000)
        # More goals than goal threads: the last one is still queued at shutdown.
        goals = [Goal(action, batch_msg(positions, normals)) for _ in range(ACTION_THREADS + 1)]
        goals[0].wait_for_progress()
        stop_at = time.monotonic()
        spinner.stop()
        stop_s = time.monotonic() - stop_at
        results = [goal.result(timeout=10.0) for goal in goals]
    finally:
        client.close()
        spinner.stop()
    assert stop_s < 1.5, f"node took {stop_s:.2f} s to stop"
    assert all(status == GoalStatus.STATUS_ABORTED for status, _ in results)
    lengths = [len(assert_prefix(verdicts, expected)) for _, verdicts in results]
    assert lengths[0] > 0 and lengths[-1] == 0 and max(lengths) < 60_000


def test_label_grasps_without_a_node_times_out(ros):
    from grasp_fc_ros.client import GraspClient

    with GraspClient("/nobody_here/force_closure") as lonely:
        start = time.monotonic()
        with pytest.raises(TimeoutError, match="no label_grasps action server"):
            lonely.label_grasps(np.ones((1, 4, 3)), np.ones((1, 4, 3)), timeout=0.5)
        assert time.monotonic() - start < 3.0


def test_sigterm_aborts_a_running_goal_with_its_prefix_and_the_node_exits(grasps, ros,
                                                                          long_goal):
    import os
    import signal

    from grasp_fc_msgs.action import LabelGrasps
    from rclpy.action import ActionClient

    from grasp_fc_ros.client import GraspClient
    from ros_fixtures import NodeProcess, node_command

    namespace = f"/action_sigterm_{os.getpid()}"
    process = NodeProcess(node_command() + ["--ros-args", "-r", f"__ns:={namespace}",
                                            "-p", "workers:=1",
                                            "-p", "max_message_contacts:=0"])
    client = GraspClient(f"{namespace}/force_closure")
    try:
        action = ActionClient(client.node, LabelGrasps, f"{namespace}/label_grasps")
        assert action.wait_for_server(timeout_sec=30.0)
        action = (action, client.node)
        n_grasps = min(long_goal, 100_000)  # the node's default max_batch
        positions, normals, expected = tiled(grasps, n_grasps)
        goal = Goal(action, batch_msg(positions, normals))
        goal.wait_for_progress()
        stop_at = time.monotonic()
        code, _, err = process.stop(signal.SIGTERM)
        exit_s = time.monotonic() - stop_at
        status, verdicts = goal.result(timeout=10.0)
    finally:
        client.close()
        if process.proc.poll() is None:
            process.proc.kill()
    assert code == 0 and "Traceback" not in err, err
    assert "not sent" not in err and "not ended" not in err, err
    # The aim is about 1 s; measured up to 2.15 s at a load average of 10 on the 2
    # cores (the node's own destroy_node took 0.24 s of it).
    assert exit_s < 3.0, f"node took {exit_s:.2f} s to exit"
    assert status == GoalStatus.STATUS_ABORTED
    assert 0 < len(assert_prefix(verdicts, expected)) < n_grasps
