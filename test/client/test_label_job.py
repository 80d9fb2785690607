"""LabelJob's parts across a node that went away, against a scripted action client (no
node, no DDS): each part's verdicts come from its latest goal, once, in order; what
earlier goals send late is ignored, or cancelled if it was an acceptance."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from action_msgs.msg import GoalStatus
from grasp_fc_msgs.action import LabelGrasps
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.task import Future

import grasp_fc_ros.client.label_job as label_job
from grasp_fc_ros.client.label_job import LabelJob
from grasp_fc_ros.core import Status
from grasp_fc_ros.interface.conversions import grasps_to_batch_msg, verdicts_to_array_msg
from grasp_fc_ros.packed import Verdicts

pytestmark = pytest.mark.timeout(60)

GRASPS_PER_PART = 3
WAIT_S = 10.0


def complete(future: Future, value, node: Node) -> None:
    """Resolve ``future`` as the action client would on ``node``'s spin thread, and wake
    that executor (a task awaiting the future resumes when it wakes)."""
    future.set_result(value)
    node.executor.wake()


class Handle:
    """A goal handle the scripted client gave out: its result future, cancel requests."""

    def __init__(self, query, node: Node):
        self.query = query  # the goal's grasps
        self.node = node
        self.accepted = True
        self.result = Future()
        self.cancels = 0

    def get_result_async(self) -> Future:
        return self.result

    def cancel_goal_async(self) -> Future:
        self.cancels += 1
        return Future()

    def end(self, status: int, verdict: Status) -> None:
        """End the goal with ``status``, every grasp of it answered ``verdict``."""
        verdicts = Verdicts.failed(np.asarray(self.query.ids, np.uint64), verdict, "")
        response = LabelGrasps.Impl.GetResultService.Response(
            status=status, result=LabelGrasps.Result(
                verdicts=verdicts_to_array_msg(verdicts, self.query)))
        complete(self.result, response, self.node)


class ScriptedActionClient:
    """Records every goal request; the test accepts and ends them."""

    def __init__(self, node: Node):
        self.node = node
        # (part, its grasps, the future of its goal handle)
        self.requests: list[tuple[int, object, Future]] = []
        self.lock = threading.Lock()

    def send_goal_async(self, goal, feedback_callback=None) -> Future:
        future = Future()
        with self.lock:
            self.requests.append((int(goal.grasps.ids[0]) // GRASPS_PER_PART, goal.grasps,
                                  future))
        return future


class FakeWatch:
    """A graph the test changes: ``new`` makes the next poll report a new server."""

    def __init__(self):
        self.new = False
        self.gone_since = None

    def poll(self) -> bool:
        new, self.new = self.new, False
        return new


@pytest.fixture
def spun_node(ros):
    node = Node("label_job_test")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    yield node
    executor.shutdown()
    thread.join(timeout=5.0)
    node.destroy_node()


def parts_of(n_parts: int):
    """Parts of GRASPS_PER_PART 4-contact grasps each, ids counting from 0."""
    rng = np.random.default_rng(0)
    return [grasps_to_batch_msg(np.arange(i * GRASPS_PER_PART, (i + 1) * GRASPS_PER_PART),
                                rng.normal(size=(GRASPS_PER_PART, 4, 3)),
                                rng.normal(size=(GRASPS_PER_PART, 4, 3)))
            for i in range(n_parts)]


def run_until(job: LabelJob, condition, timeout: float = WAIT_S) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "condition not reached"
        job.step(0.01)


def requests_of(action: ScriptedActionClient, part: int) -> list[tuple[object, Future]]:
    """(grasps, future of the goal handle) of each goal request of ``part``."""
    with action.lock:
        return [(query, future) for index, query, future in action.requests if index == part]


def accept(action: ScriptedActionClient, part: int, attempt: int = -1) -> Handle:
    query, future = requests_of(action, part)[attempt]
    handle = Handle(query, action.node)
    complete(future, handle, action.node)
    return handle


def job_of_three_parts(node: Node) -> tuple[LabelJob, ScriptedActionClient, FakeWatch, Handle]:
    """A job of three parts on a scripted client: its first goal sent and accepted."""
    action, watch = ScriptedActionClient(node), FakeWatch()
    job = LabelJob(node, action, parts_of(3), watch)
    run_until(job, lambda: requests_of(action, 0))
    return job, action, watch, accept(action, 0)


def test_a_new_server_gets_the_unfinished_parts_and_late_answers_are_ignored(spun_node):
    job, action, watch, first = job_of_three_parts(spun_node)
    run_until(job, lambda: requests_of(action, 1))
    second = accept(action, 1)
    run_until(job, lambda: len(job._handles) == 2)  # both parts in flight
    watch.new = True  # the node was killed and restarted
    run_until(job, lambda: len(requests_of(action, 0)) == 2)
    assert job.resent == 2
    # The dead node's goals end late (say, a node that was not dead after all): ignored.
    first.end(GoalStatus.STATUS_SUCCEEDED, Status.INVALID_INPUT)
    second.end(GoalStatus.STATUS_ABORTED, Status.INVALID_INPUT)
    again = accept(action, 0)
    run_until(job, lambda: len(requests_of(action, 1)) == 2)  # one at a time, in order
    again_second = accept(action, 1)
    # Before part 0's: results come in any order.
    again_second.end(GoalStatus.STATUS_SUCCEEDED, Status.FORCE_CLOSURE)
    run_until(job, lambda: requests_of(action, 2))
    third = accept(action, 2)
    for handle in (third, again):
        handle.end(GoalStatus.STATUS_SUCCEEDED, Status.FORCE_CLOSURE)
    run_until(job, job.ended)
    verdicts = job.verdicts()
    np.testing.assert_array_equal(verdicts.ids, np.arange(3 * GRASPS_PER_PART))
    assert (verdicts.status == Status.FORCE_CLOSURE).all()
    assert job.status() == GoalStatus.STATUS_SUCCEEDED
    assert len(action.requests) == 5


def test_an_unanswered_goal_request_goes_again_and_its_late_acceptance_is_cancelled(
        spun_node, monkeypatch):
    monkeypatch.setattr(label_job, "RESEND_AFTER_S", 0.2)
    parts = parts_of(1)
    action = ScriptedActionClient(spun_node)
    job = LabelJob(spun_node, action, parts, FakeWatch())
    run_until(job, lambda: len(requests_of(action, 0)) == 2)
    assert job.resent == 1
    late = accept(action, 0, attempt=0)  # the first request's answer comes after all
    run_until(job, lambda: late.cancels == 1)
    current = accept(action, 0, attempt=1)
    current.end(GoalStatus.STATUS_SUCCEEDED, Status.FORCE_CLOSURE)
    run_until(job, job.ended)
    assert len(job.verdicts()) == GRASPS_PER_PART and current.cancels == 0


def test_a_cancelled_job_whose_node_restarted_ends_with_its_prefix(spun_node):
    job, action, watch, first = job_of_three_parts(spun_node)
    first.end(GoalStatus.STATUS_SUCCEEDED, Status.FORCE_CLOSURE)
    run_until(job, lambda: requests_of(action, 1))
    accept(action, 1)
    run_until(job, lambda: 0 in job._ended and 1 in job._handles)
    job.cancel()  # Ctrl-C; the node dies before answering the cancel
    watch.new = True
    run_until(job, job.ended)  # the part in flight ended with its node: not sent again
    assert len(action.requests) == 2
    np.testing.assert_array_equal(job.verdicts().ids, np.arange(GRASPS_PER_PART))
    assert job.status() == GoalStatus.STATUS_CANCELED
