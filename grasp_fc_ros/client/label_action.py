"""The client's side of the ``label_grasps`` action: a long job with a progress bar,
Ctrl-C cancelling it."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from action_msgs.msg import GoalStatus
from grasp_fc_msgs.action import LabelGrasps
from grasp_fc_msgs.msg import ContactArrayBatch
from rclpy.action import ActionClient
from rclpy.node import Node
from rclpy.task import Future as RclpyFuture
from tqdm import tqdm

from grasp_fc_ros.interface.conversions import verdict_array_to_numpy
from grasp_fc_ros.interface.names import LABEL_ACTION, resolve
from grasp_fc_ros.packed import Verdicts

# How long label_grasps looks for the action server when it has no timeout (s).
DEFAULT_SERVER_WAIT_S = 60.0
# How often label_grasps redraws its progress bar and looks at its deadline (s).
PROGRESS_POLL_S = 0.1
# How long label_grasps waits for the decided prefix after it cancelled its goal (s):
# the node ends a canceled goal within ~0.1 s.
CANCEL_WAIT_S = 10.0


def request_on_spin_thread(node: Node, request: Callable[[], RclpyFuture]) -> RclpyFuture:
    """Make ``request()`` on the thread that spins ``node``; a Future of its response.

    For an rclpy ActionClient's ``send_goal_async``, ``get_result_async`` and
    ``cancel_goal_async``: rclpy 7 registers the request's future only after sending the
    request, so made from another thread, a response that the spin thread took in
    between was dropped ("Ignoring unexpected goal response") and the future never
    completed (a goal the node accepted and the client never learned of: seen once in
    a CI run). On the spin thread nothing is taken between the two. ``node`` must have
    been added to an executor that spins.
    """
    async def make_request() -> Any:
        return await request()

    executor = node.executor
    assert executor is not None, "the node is spun by no executor"
    return executor.create_task(make_request)


class LabelActionClient:
    """Send label_grasps goals and follow them to their end.

    Parameters
    ----------
    node : Node
        The client's node, spun by an executor on another thread.
    node_name : str
        The force_closure node's full name.

    Attributes
    ----------
    action_client : rclpy.action.ActionClient
    last_goal_status : int
        ``action_msgs/GoalStatus`` code of the last goal (STATUS_UNKNOWN before any).
    """

    def __init__(self, node: Node, node_name: str):
        self._node = node
        self.action_name = resolve(node_name, LABEL_ACTION)
        self.action_client = ActionClient(node, LabelGrasps, self.action_name)
        self.last_goal_status = GoalStatus.STATUS_UNKNOWN

    def label(self, batch: ContactArrayBatch, progress: bool, timeout: float | None
              ) -> Verdicts:
        """Send ``batch`` as one goal and wait for its verdicts (see
        :meth:`grasp_fc_ros.client.GraspClient.label_grasps`)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        wait_s = (DEFAULT_SERVER_WAIT_S if deadline is None
                  else max(deadline - time.monotonic(), 0))
        if not self.action_client.wait_for_server(timeout_sec=wait_s):
            raise TimeoutError(f"no label_grasps action server within {wait_s:.1f} s "
                               f"({self.action_name}): is the node up?")
        latest: list[Any] = [None]  # the newest feedback, written by the spin thread
        goal_handle = wait_rclpy(
            request_on_spin_thread(self._node, lambda: self.action_client.send_goal_async(
                LabelGrasps.Goal(grasps=batch),
                feedback_callback=lambda msg: latest.__setitem__(0, msg.feedback))),
            deadline, "the label_grasps goal to be accepted")
        if not goal_handle.accepted:
            raise RuntimeError("the node rejected the label_grasps goal (shutting down?)")
        result_future = request_on_spin_thread(self._node, goal_handle.get_result_async)
        started = time.monotonic()
        done = threading.Event()
        result_future.add_done_callback(lambda _: done.set())

        def cancel() -> None:
            request_on_spin_thread(self._node, goal_handle.cancel_goal_async)

        with tqdm(total=len(batch.ids), unit="grasp", disable=not progress,
                  dynamic_ncols=True, desc=LABEL_ACTION) as bar:
            try:
                follow_goal(done, latest, bar, deadline, cancel)
            except KeyboardInterrupt:
                cancel()
                if not done.wait(CANCEL_WAIT_S):
                    raise
            response = result_future.result()
            assert response is not None
            verdicts = verdict_array_to_numpy(response.result.verdicts)
            # The last feedback may predate the end (a short goal may have none after its
            # first): the bar ends on the verdicts themselves.
            elapsed = max(time.monotonic() - started, 1e-9)
            bar.set_postfix(force_closure=int(np.count_nonzero(verdicts.force_closure)),
                            rate=f"{len(verdicts) / elapsed:.0f}/s", refresh=False)
            bar.update(len(verdicts) - bar.n)
        self.last_goal_status = response.status
        return verdicts


def wait_rclpy(future: RclpyFuture, deadline: float | None, what: str) -> Any:
    """The result of an rclpy Future that the client's spin thread resolves."""
    done = threading.Event()
    future.add_done_callback(lambda _: done.set())
    wait_s = None if deadline is None else max(deadline - time.monotonic(), 0)
    if not done.wait(wait_s):
        raise TimeoutError(f"timed out waiting for {what}")
    return future.result()


def follow_goal(done: threading.Event, latest: list[Any], bar: tqdm,
                deadline: float | None, cancel: Callable[[], None]) -> None:
    """Show a goal's feedback until its result is in; ``cancel()`` it at ``deadline``."""
    while not done.wait(PROGRESS_POLL_S):
        show_progress(bar, latest[0])
        if deadline is not None and time.monotonic() > deadline:
            cancel()
            raise TimeoutError("label_grasps goal not done within its timeout (cancelled)")


def show_progress(bar: tqdm, feedback: Any) -> None:
    """Move a tqdm ``bar`` to a LabelGrasps feedback's ``done`` (None: none yet)."""
    if feedback is None:
        return
    bar.set_postfix(force_closure=feedback.force_closure,
                    rate=f"{feedback.grasps_per_second:.0f}/s", refresh=False)
    bar.update(int(feedback.done) - bar.n)
