"""An ended label_grasps goal's result is answered long after rclpy's action server
forgot the goal (which it does after a few seconds, to keep its status list short), to a
plain ActionClient that asks late; the kept results are bounded by age, count and
bytes."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from action_msgs.msg import GoalStatus

from grasp_fc_ros.node.kept_results import KeptResults

pytestmark = pytest.mark.timeout(180)

WAIT_S = 30.0
# The node's own keep of ended goals in the status list, shortened for the test (s).
STATUS_KEEP_S = 1


def test_a_plain_action_client_asking_late_gets_the_result(ros, own_node, monkeypatch):
    from grasp_fc_msgs.action import LabelGrasps
    from rclpy.action import ActionClient

    from grasp_fc_ros.client import request_on_spin_thread
    from grasp_fc_ros.core import check_force_closure
    from grasp_fc_ros.interface.conversions import (
        grasps_to_batch_msg,
        verdict_array_to_numpy,
    )
    from grasp_fc_ros.node import label_action
    from grasp_fc_ros.objects import make_object, sample_grasps

    monkeypatch.setattr(label_action, "ACTION_RESULT_TIMEOUT_S", STATUS_KEEP_S)
    node, _spinner, client = own_node("/late_result", workers=0)
    server = node.label_action._server
    action = ActionClient(client.node, LabelGrasps, "/late_result/label_grasps")
    assert action.wait_for_server(timeout_sec=WAIT_S)
    positions, normals = sample_grasps(make_object("box", 500), 40, 4,
                                       np.random.default_rng(5))
    goal = LabelGrasps.Goal(grasps=grasps_to_batch_msg(np.arange(40), positions, normals))

    def send() -> object:
        accepted = threading.Event()
        future = request_on_spin_thread(client.node, lambda: action.send_goal_async(goal))
        future.add_done_callback(lambda _: accepted.set())
        assert accepted.wait(WAIT_S)
        handle = future.result()
        assert handle.accepted
        return handle

    def result_of(handle: object) -> object:
        got = threading.Event()
        future = request_on_spin_thread(client.node, handle.get_result_async)
        future.add_done_callback(lambda _: got.set())
        assert got.wait(WAIT_S)
        return future.result()

    handle = send()
    # Not asked for its result: wait until the server has forgotten the ended goal.
    deadline = time.monotonic() + WAIT_S
    while server._goal_handles or len(server.kept_results) == 0:
        assert time.monotonic() < deadline, "the goal did not end and expire"
        time.sleep(0.05)
    late = result_of(handle)
    assert late.status == GoalStatus.STATUS_SUCCEEDED
    verdicts = verdict_array_to_numpy(late.result.verdicts)
    np.testing.assert_array_equal(verdicts.ids, np.arange(40))
    np.testing.assert_array_equal(verdicts.status,
                                  check_force_closure(positions, normals, 0.5).status)
    # A goal id the server never had is still UNKNOWN.
    handle.goal_id.uuid = np.frombuffer(b"\x01" * 16, dtype=np.uint8)
    assert result_of(handle).status == GoalStatus.STATUS_UNKNOWN


class _Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_kept_results_are_bounded_by_age_count_and_bytes():
    clock = _Clock()
    kept = KeptResults(keep_s=10.0, max_count=3, max_bytes=100, clock=clock)
    for k in range(4):  # the fourth drops the first (count)
        clock.now = float(k)
        kept.keep(bytes([k]), bytes(10))
    assert kept.get(bytes([0])) is None and kept.get(bytes([1])) == bytes(10)
    assert len(kept) == 3 and kept.bytes == 30
    clock.now = 5.0
    kept.keep(b"big", b"b" * 75)  # over the bytes: the oldest go until it fits
    assert kept.get(bytes([1])) is None and kept.get(bytes([2])) == bytes(10)
    assert kept.bytes == 95
    clock.now = 13.5  # results 2 and 3 (kept at 2 and 3 s) are older than keep_s
    assert kept.get(bytes([3])) is None and kept.get(b"big") == b"b" * 75
    assert len(kept) == 1 and kept.bytes == 75
    kept.keep(b"huge", bytes(101))  # larger than the bound alone: not kept
    assert len(kept) == 0 and kept.bytes == 0


def test_kept_results_give_the_garbage_collector_nothing_to_walk(ros, own_node,
                                                                 monkeypatch):
    """Kept as bytes, thousands of results add no objects the collector tracks (as
    messages, their bool and string lists made each full collection walk millions of
    references)."""
    import gc

    from grasp_fc_msgs.action import LabelGrasps
    from rclpy.serialization import serialize_message

    from grasp_fc_ros.interface.conversions import verdicts_to_array_msg
    from grasp_fc_ros.packed import Verdicts

    n = 512
    verdicts = Verdicts(ids=np.arange(n, dtype=np.uint64), force_closure=np.zeros(n, bool),
                        status=np.full(n, 1, np.uint8), margin=np.zeros(n),
                        messages=[""] * n)
    response = LabelGrasps.Impl.GetResultService.Response(
        status=GoalStatus.STATUS_SUCCEEDED,
        result=LabelGrasps.Result(verdicts=verdicts_to_array_msg(verdicts)))
    kept = KeptResults()
    before = len(gc.get_objects())
    for k in range(2000):
        kept.keep(k.to_bytes(16, "little"), serialize_message(response))
    assert len(gc.get_objects()) - before < 100  # the dict's entries are not tracked
    assert len(kept) == 2000 and kept.bytes == 2000 * len(serialize_message(response))
