"""One label_grasps goal on the node's side: its state apart from the action server.

As rclpy keeps a goal's state in ``ServerGoalHandle`` apart from ``ActionServer``,
:class:`LabelGoal` holds what the node knows of one accepted goal: its handle, its
cancel flag, its end (a future the goal's execute coroutine awaits) and the result it
ends with. :mod:`.label_action` queues, decides and serves them.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import numpy as np
from grasp_fc_msgs.action import LabelGrasps
from grasp_fc_msgs.msg import ContactArrayBatch, ForceClosureVerdictArray
from rclpy.task import Future

from grasp_fc_ros.core import Status
from grasp_fc_ros.engine.long_jobs import Progress
from grasp_fc_ros.interface.conversions import verdicts_to_array_msg
from grasp_fc_ros.node.statistics import Statistics
from grasp_fc_ros.packed import Verdicts


class LabelGoal:
    """One accepted label_grasps goal.

    Parameters
    ----------
    handle : rclpy.action.server.ServerGoalHandle
    wake : callable ()
        Wakes the action's executor, which resumes the goal's execute coroutine once
        the goal has ended.

    Whoever ends the goal (a goal thread, the cancel callback, shutdown) calls
    :meth:`end` once, from any thread; the execute coroutine awaits :meth:`finish`.
    """

    def __init__(self, handle: Any, wake: Callable[[], None]):
        self.handle = handle
        self._wake = wake
        self._cancel = threading.Event()
        self._finished: Future = Future()
        self.aborted = False

    @property
    def key(self) -> bytes:
        """The goal id's bytes."""
        return bytes(self.handle.goal_id.uuid)

    @property
    def grasps(self) -> ContactArrayBatch:
        """The goal's batch."""
        return self.handle.request.grasps

    @property
    def canceled(self) -> bool:
        """The cancel callback accepted a cancel: stop deciding."""
        return self._cancel.is_set()

    def cancel(self) -> None:
        self._cancel.set()

    def publish_feedback(self, progress: Progress) -> None:
        """Send a LabelGrasps feedback with ``progress``."""
        counts = progress.counts.tolist()
        self.handle.publish_feedback(LabelGrasps.Feedback(
            done=progress.done, total=progress.total,
            grasps_per_second=float(progress.grasps_per_second),
            force_closure=counts[Status.FORCE_CLOSURE],
            not_force_closure=counts[Status.NOT_FORCE_CLOSURE],
            filtered_out=counts[Status.FILTERED_OUT],
            invalid_input=counts[Status.INVALID_INPUT],
            solver_failure=counts[Status.SOLVER_FAILURE]))

    def empty_reply(self) -> ForceClosureVerdictArray:
        """The answer of a goal ended before any grasp was decided: no verdicts."""
        return verdicts_to_array_msg(
            Verdicts.failed(np.empty(0, np.uint64), Status.INVALID_INPUT, ""), self.grasps)

    def end(self, result: LabelGrasps.Result, aborted: bool) -> None:
        """End the goal with ``result`` (from any thread; once)."""
        self.aborted = aborted
        self._finished.set_result(result)
        self._wake()

    async def finish(self, statistics: Statistics) -> LabelGrasps.Result:
        """Await the goal's end (on the action's executor), set the handle's final state
        and count it; the result to return.

        The cancel callback and this coroutine both run on the action's executor, so a
        cancel accepted before the end has already made the goal CANCELING.
        """
        result = await self._finished
        if self.handle.is_cancel_requested:
            self.handle.canceled()
            statistics.count_goal("canceled")
        elif self.aborted:
            self.handle.abort()
            statistics.count_goal("aborted")
        else:
            self.handle.succeed()
            statistics.count_goal("succeeded")
        return result
