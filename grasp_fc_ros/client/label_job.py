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

A job outlives its node as batches do (:mod:`.connection`): when a new action server
appears (the node was killed and restarted), every part sent and not ended goes again
as a new goal, and a goal request the node has not answered within
:data:`~grasp_fc_ros.client.pending.RESEND_AFTER_S` goes again too. Each send of a part
is an attempt; only the latest attempt's events count, and a goal an earlier attempt
got accepted (by a node that was not dead after all) is cancelled, so each part's
verdicts come from one goal, once.
"""

from __future__ import annotations

import queue
import time
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
from action_msgs.msg import GoalStatus
from grasp_fc_msgs.action import LabelGrasps
from grasp_fc_msgs.msg import ContactArrayBatch
from rclpy.action import ActionClient
from rclpy.node import Node
from rclpy.task import Future as RclpyFuture

from grasp_fc_ros.client.connection import MATCH_GRACE_S, ActionServerWatch
from grasp_fc_ros.client.pending import RESEND_AFTER_S
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
    watch : ActionServerWatch
        The action's servers in the graph, looked at while the job runs.

    Attributes
    ----------
    total : int
        Grasps in the job.
    canceled : bool
        :meth:`cancel` was called.
    rejected_part : int or None
        The part the node rejected (it is shutting down), if any: none is sent after it.
    resent : int
        Parts sent again (a new node appeared, or a goal request went unanswered).

    The caller's thread drives the job: :meth:`step` sends what may be sent and takes
    one event from the spin thread (a goal accepted or rejected, a feedback, a result).
    """

    def __init__(self, node: Node, action_client: ActionClient,
                 parts: list[ContactArrayBatch], watch: ActionServerWatch):
        self._node = node
        self._action = action_client
        self._parts = parts
        self._watch = watch
        self.total = sum(len(part.ids) for part in parts)
        # (kind, part index, attempt, payload) from the spin thread, in arrival order.
        self._events: queue.SimpleQueue[tuple[str, int, int, Any]] = queue.SimpleQueue()
        self._next = 0  # the next part to send for the first time
        self._again: list[int] = []  # parts to send again, ascending: before _next
        self._attempts = [0] * len(parts)  # each part's latest send
        # The part whose goal request is unanswered, and when it was sent.
        self._awaiting: tuple[int, float] | None = None
        self._handles: dict[int, Any] = {}  # parts accepted and not ended: goal handles
        self._feedback: dict[int, Any] = {}  # their latest LabelGrasps feedback
        self._ended: dict[int, tuple[int, Verdicts]] = {}  # part -> (GoalStatus, verdicts)
        self._ended_counts = JobProgress(0, self.total, 0)  # the ended parts' verdicts
        self._resend_at: float | None = None  # a new server appeared: resend then
        self._warned_gone = False
        self._stopped = False  # send no more parts
        self.canceled = False
        self.rejected_part: int | None = None
        self.resent = 0

    @property
    def sent(self) -> int:
        """Parts sent so far (at least once)."""
        return self._next

    def ended(self) -> bool:
        """Every part sent has ended, and no more will be sent."""
        return (self._awaiting is None and not self._handles
                and (self._stopped or (self._next == len(self._parts) and not self._again)))

    def gone_for(self) -> float:
        """Seconds since the graph last showed a label_grasps server (0 while one is
        there)."""
        since = self._watch.gone_since
        return 0.0 if since is None else time.monotonic() - since

    def step(self, wait_s: float) -> None:
        """Look for a new server, send the next part if it may go, then handle one event
        (waiting for one at most ``wait_s`` seconds)."""
        self._watch_servers()
        self._send_next()
        try:
            kind, index, attempt, payload = self._events.get(timeout=wait_s)
        except queue.Empty:
            return
        if attempt != self._attempts[index]:
            if kind == "accepted":
                self._on_stale_acceptance(payload)
        elif kind == "accepted":
            self._on_accepted(index, attempt, payload)
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
        # A copy: another thread may read the progress while the spin thread adds feedback.
        for feedback in list(self._feedback.values()):
            done += int(feedback.done)
            force_closure += int(feedback.force_closure)
        return JobProgress(done, self.total, force_closure)

    def verdicts(self) -> Verdicts:
        """The job's verdicts, in order: every part's when all succeeded, else the
        parts before the first that did not (or has not ended), and that part's decided
        prefix."""
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
        """Send the next part (one to send again first) once the one before was
        accepted and fewer than PARTS_IN_FLIGHT are in flight; send a goal request
        again that has had no answer for RESEND_AFTER_S."""
        if self._awaiting is not None:
            index, sent_at = self._awaiting
            if time.monotonic() - sent_at < RESEND_AFTER_S:
                return
            self._send_again([index])
        if self._stopped or len(self._handles) >= PARTS_IN_FLIGHT:
            return
        if self._again:
            index = self._again.pop(0)
        elif self._next < len(self._parts):
            index, self._next = self._next, self._next + 1
        else:
            return
        attempt = self._attempts[index]
        self._awaiting = (index, time.monotonic())
        goal = LabelGrasps.Goal(grasps=self._parts[index])
        events = self._events
        future = request_on_spin_thread(self._node, lambda: self._action.send_goal_async(
            goal, feedback_callback=lambda msg: events.put(
                ("feedback", index, attempt, msg.feedback))))
        future.add_done_callback(lambda done: events.put(("accepted", index, attempt, done)))

    def _on_accepted(self, index: int, attempt: int, future: RclpyFuture) -> None:
        self._awaiting = None
        handle = future.result()
        if not handle.accepted:
            self.rejected_part = index
            self._stopped = True
            return
        self._handles[index] = handle
        result = request_on_spin_thread(self._node, handle.get_result_async)
        result.add_done_callback(
            lambda done: self._events.put(("result", index, attempt, done)))
        if self.canceled:  # cancelled while this part was on its way
            request_on_spin_thread(self._node, handle.cancel_goal_async)

    def _on_stale_acceptance(self, future: RclpyFuture) -> None:
        """An earlier attempt's goal was accepted after all: cancel it (the part has a
        later attempt)."""
        handle = future.result()
        if handle.accepted:
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

    # --- a node that went away ----------------------------------------------------------

    def _watch_servers(self) -> None:
        """When a new server has appeared, send every unfinished part again (after
        MATCH_GRACE_S: its goal service matches this client a moment after its status
        publisher shows); a stopped job forgets them instead (they ended with their
        node). Warn once when no server is left."""
        if self._watch.poll():
            self._resend_at = time.monotonic() + MATCH_GRACE_S
        gone = self._watch.gone_since is not None
        if gone and not self._warned_gone:
            self._node.get_logger().warning(
                "label_grasps: the node's action server went away (it is no longer in "
                "the ROS graph); this job's unfinished goals go again when it is back")
        self._warned_gone = gone
        if self._resend_at is None or time.monotonic() < self._resend_at:
            return
        self._resend_at = None
        unfinished = list(self._handles)
        if self._awaiting is not None:
            unfinished.append(self._awaiting[0])
        if unfinished and not self._stopped:
            self._node.get_logger().warning(
                "label_grasps: a new action server appeared (the node restarted?): "
                f"sending the {len(unfinished)} unfinished goals of this job again")
        self._send_again(unfinished)

    def _send_again(self, indices: list[int]) -> None:
        """Forget the current attempts of parts ``indices`` (sent, not ended) and queue
        them to be sent again, in order."""
        for index in indices:
            self._attempts[index] += 1
            self._handles.pop(index, None)
            self._feedback.pop(index, None)
            if self._awaiting is not None and self._awaiting[0] == index:
                self._awaiting = None
        self._again = sorted({*self._again, *indices})
        self.resent += len(indices)
