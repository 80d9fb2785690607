"""One label_grasps job of the client: its parts sent as goals, presented as one job.

A job larger than :data:`~grasp_fc_ros.interface.names.MAX_MESSAGE_CONTACTS` contacts
goes to the node as several goals (parts of whole grasps, in order), so that no goal
request, and no result, is large enough to hold up the node's service calls behind it
(docs/performance.md#big-batches). At most :data:`PARTS_IN_FLIGHT` parts are unfinished
at once, and each part is sent only once the node accepted the one before. The job's
verdicts are its parts' verdicts in order; its progress adds up the parts' feedback; a
cancel cancels the parts in flight and sends no more. The job ends as a prefix of the
grasps when a part is canceled, aborted or rejected: the parts before it, and the
verdicts that part decided.
"""

from __future__ import annotations

import queue
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
from action_msgs.msg import GoalStatus
from grasp_fc_msgs.action import LabelGrasps
from grasp_fc_msgs.msg import ContactArrayBatch
from rclpy.action import ActionClient
from rclpy.node import Node
from rclpy.task import Future as RclpyFuture

from grasp_fc_ros.core import Status
from grasp_fc_ros.interface.conversions import verdict_array_to_numpy
from grasp_fc_ros.packed import Verdicts

# Parts of one job sent and not ended at once: two, so that the node decides one while
# the next one crosses DDS and a result comes back, and a job leaves the node's other
# goal threads to other clients' goals (tuned: docs/performance.md#big-batches).
PARTS_IN_FLIGHT = 2
# A plain integer: comparing an array with an IntEnum member is slow.
_FORCE_CLOSURE = int(Status.FORCE_CLOSURE)


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


class JobProgress(NamedTuple):
    """How far a job is: grasps decided (``done``) of ``total``, and how many of them
    are force closure."""

    done: int
    total: int
    force_closure: int


class LabelJob:
    """Send a job's parts as goals, follow them, join their verdicts.

    Parameters
    ----------
    node : Node
        The client's node, spun by an executor on another thread; every action request
        is made on that thread (:func:`request_on_spin_thread`).
    action_client : ActionClient
        The client of the node's label_grasps action (its server found).
    parts : list of ContactArrayBatch
        The job's grasps, in order, in parts of whole grasps.

    Attributes
    ----------
    total : int
        Grasps in the job.
    canceled : bool
        :meth:`cancel` was called.
    rejected_part : int or None
        The part the node rejected (it is shutting down), if any: none is sent after it.

    The caller's thread drives the job: :meth:`step` sends what may be sent and takes
    one event from the spin thread (a goal accepted or rejected, a feedback, a result).
    """

    def __init__(self, node: Node, action_client: ActionClient,
                 parts: list[ContactArrayBatch]):
        self._node = node
        self._action = action_client
        self._parts = parts
        self.total = sum(len(part.ids) for part in parts)
        # (kind, part index, payload) from the spin thread, in arrival order.
        self._events: queue.SimpleQueue[tuple[str, int, Any]] = queue.SimpleQueue()
        self._next = 0  # the next part to send
        self._awaiting_acceptance = False
        self._handles: dict[int, Any] = {}  # parts accepted and not ended: goal handles
        self._feedback: dict[int, Any] = {}  # their latest LabelGrasps feedback
        self._ended: dict[int, tuple[int, Verdicts]] = {}  # part -> (GoalStatus, verdicts)
        self._ended_counts = JobProgress(0, self.total, 0)  # the ended parts' verdicts
        self._stopped = False  # send no more parts
        self.canceled = False
        self.rejected_part: int | None = None

    @property
    def sent(self) -> int:
        """Parts sent so far."""
        return self._next

    def ended(self) -> bool:
        """Every part sent has ended, and no more will be sent."""
        return (not self._awaiting_acceptance and not self._handles
                and (self._stopped or self._next == len(self._parts)))

    def step(self, wait_s: float) -> None:
        """Send the next part if it may go, then handle one event (waiting for one at
        most ``wait_s`` seconds)."""
        self._send_next()
        try:
            kind, index, payload = self._events.get(timeout=wait_s)
        except queue.Empty:
            return
        if kind == "accepted":
            self._on_accepted(index, payload)
        elif kind == "result":
            self._on_result(index, payload)
        elif index in self._handles:  # feedback; a late one after the result is stale
            self._feedback[index] = payload

    def cancel(self) -> None:
        """Send no more parts and cancel those in flight (their decided prefixes come
        back with their results)."""
        self._stopped = True
        self.canceled = True
        for handle in self._handles.values():
            request_on_spin_thread(self._node, handle.cancel_goal_async)

    def progress(self) -> JobProgress:
        """Grasps decided so far: the ended parts' verdicts and the feedback of those
        in flight."""
        done, _, force_closure = self._ended_counts
        for feedback in self._feedback.values():
            done += int(feedback.done)
            force_closure += int(feedback.force_closure)
        return JobProgress(done, self.total, force_closure)

    def verdicts(self) -> Verdicts:
        """The job's verdicts, in order: every part's when all succeeded, else the
        parts before the first that did not, and that part's decided prefix."""
        joined = []
        for index in range(len(self._parts)):
            if index not in self._ended:
                break
            status, verdicts = self._ended[index]
            if len(verdicts):  # an empty one may lack the optional fields the others have
                joined.append(verdicts)
            if status != GoalStatus.STATUS_SUCCEEDED:
                break
        return joined[0] if len(joined) == 1 else Verdicts.concatenate(joined)

    def status(self) -> int:
        """The job's ``action_msgs/GoalStatus``: ABORTED if a part was aborted or
        rejected (the node is shutting down), else CANCELED if a part was, else
        SUCCEEDED."""
        statuses = {status for status, _ in self._ended.values()}
        if self.rejected_part is not None or GoalStatus.STATUS_ABORTED in statuses:
            return GoalStatus.STATUS_ABORTED
        if self.canceled or GoalStatus.STATUS_CANCELED in statuses:
            return GoalStatus.STATUS_CANCELED
        return GoalStatus.STATUS_SUCCEEDED

    # --- the parts ------------------------------------------------------------------------

    def _send_next(self) -> None:
        """Send the next part once the one before was accepted and fewer than
        PARTS_IN_FLIGHT are in flight."""
        if (self._stopped or self._awaiting_acceptance or self._next == len(self._parts)
                or len(self._handles) >= PARTS_IN_FLIGHT):
            return
        index, self._next = self._next, self._next + 1
        self._awaiting_acceptance = True
        goal = LabelGrasps.Goal(grasps=self._parts[index])
        events = self._events
        future = request_on_spin_thread(self._node, lambda: self._action.send_goal_async(
            goal, feedback_callback=lambda msg: events.put(("feedback", index, msg.feedback))))
        future.add_done_callback(lambda done: events.put(("accepted", index, done)))

    def _on_accepted(self, index: int, future: RclpyFuture) -> None:
        self._awaiting_acceptance = False
        handle = future.result()
        if not handle.accepted:
            self.rejected_part = index
            self._stopped = True
            return
        self._handles[index] = handle
        result = request_on_spin_thread(self._node, handle.get_result_async)
        result.add_done_callback(lambda done: self._events.put(("result", index, done)))
        if self.canceled:  # cancelled while this part was on its way
            request_on_spin_thread(self._node, handle.cancel_goal_async)

    def _on_result(self, index: int, future: RclpyFuture) -> None:
        response = future.result()
        del self._handles[index]
        self._feedback.pop(index, None)
        verdicts = verdict_array_to_numpy(response.result.verdicts)
        self._ended[index] = (response.status, verdicts)
        done, total, force_closure = self._ended_counts
        self._ended_counts = JobProgress(
            done + len(verdicts), total,
            force_closure + int(np.count_nonzero(verdicts.status == _FORCE_CLOSURE)))
        if response.status != GoalStatus.STATUS_SUCCEEDED and not self._stopped:
            self._stopped = True  # aborted: the node is stopping; end the others too
            for handle in self._handles.values():
                request_on_spin_thread(self._node, handle.cancel_goal_async)
