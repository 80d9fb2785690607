"""The action lane: ``label_grasps`` (LabelGrasps), a long batch with feedback and cancel.

Served from a helper node, ``<name>_action`` in the node's namespace, with an executor
of its own, so that goal, cancel and result requests never wait for the node's
executor. Its callbacks only queue or flag: each goal's execute coroutine waits
(without blocking the executor) for one of :data:`ACTION_THREADS` goal threads, which
decide goals in chunks on the workers (:func:`~grasp_fc_ros.engine.long_jobs.decide_in_chunks`)
and publish their feedback; so a running goal holds up neither cancel requests, nor
other goals, nor the other lanes. A goal is answered as the batch topic answers
(invalid and oversized goals, beyond ``max_batch`` grasps or ``max_message_contacts``
contacts, get INVALID_INPUT verdicts, without feedback); a cancel or the node's
shutdown ends it with the verdicts decided so far, a prefix. An ended goal's result is
answered for 15 minutes, as rclpy's own default, within bounds of count and bytes
(:mod:`.kept_results`).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from typing import Any

from grasp_fc_msgs.action import LabelGrasps
from grasp_fc_msgs.msg import ForceClosureVerdictArray
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.serialization import deserialize_message, serialize_message

from grasp_fc_ros.core import Status
from grasp_fc_ros.engine.long_jobs import Progress, decide_in_chunks
from grasp_fc_ros.interface.conversions import (
    MalformedBatch,
    batch_contacts,
    batch_size,
    batch_to_packed,
    verdicts_to_array_msg,
)
from grasp_fc_ros.interface.names import LABEL_ACTION
from grasp_fc_ros.node.kept_results import KeptResults
from grasp_fc_ros.node.label_goal import LabelGoal
from grasp_fc_ros.node.lane import Drained, LaneContext, Refusal, start_thread
from grasp_fc_ros.node.participant import BatchParticipant
from grasp_fc_ros.node.replies import refused_verdicts

# label_grasps goals decided side by side (their chunks share the workers); more wait.
ACTION_THREADS = 4
# How long rclpy's action server keeps an ended goal, its request (the whole batch) and
# result (s). Short, because every goal kept is in every status message the server sends
# and each action client converts in Python: a GraspClient job of many parts (goals)
# slowed down with the list (tuned: docs/performance.md#big-label-jobs); and rclpy's
# default, 15 minutes, would hold ~60 MB of request per 100,000-grasp goal that long.
# The result alone stays longer, for late result requests (.kept_results).
ACTION_RESULT_TIMEOUT_S = 5
# At shutdown, how long the goals ended then may take to have their result responses
# sent (s): the action's executor sends each one when the goal's client has asked for it
# (GraspClient asks at acceptance), so this is only waited out in full for a client that
# never asks.
ACTION_RESULT_SEND_TIMEOUT_S = 2.0
# After the last of those responses was sent, time for DDS to deliver it before the
# process goes (s): rclpy has no acknowledgement to wait for on a service response (a
# shorter wait lost an aborted goal's result now and then).
ACTION_RESULT_DELIVERY_S = 0.25


class _ResultReportingActionServer(ActionServer):
    """An ActionServer that reports each result response it has sent, and answers
    result requests for goals it has forgotten from the results it kept of them.

    Shutdown waits for the results of the goals it ends to have been sent. rclpy offers
    no public hook for that; ``_send_result_response`` is the method (rclpy 7, Jazzy)
    that sends one, and its response holds the very Result object the execute callback
    returned. Likewise ``_execute_expire_goals`` is where it forgets ended goals (after
    ``result_timeout``) and ``_execute_get_result_request`` where it answers a result
    request (STATUS_UNKNOWN for a forgotten goal): the response of an expiring goal goes,
    serialized, to :attr:`kept_results`, which answers later requests for it.
    """

    def __init__(self, *args: Any, on_result_sent: Any, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self._on_result_sent = on_result_sent
        self.kept_results = KeptResults()

    def _send_result_response(self, request_header: Any, future: Any) -> None:
        super()._send_result_response(request_header, future)
        self._on_result_sent(future.result().result)

    async def _execute_expire_goals(self, expired_goals: Any) -> None:
        for goal in expired_goals:
            key = bytes(goal.goal_id.uuid)
            future = self._result_futures.get(key)
            if future is not None and future.done():
                self.kept_results.keep(key, serialize_message(future.result()))
        await super()._execute_expire_goals(expired_goals)

    async def _execute_get_result_request(self, request_header_and_message: Any) -> None:
        request_header, request = request_header_and_message
        key = bytes(request.goal_id.uuid)
        kept = None if key in self._goal_handles else self.kept_results.get(key)
        if kept is None:
            await super()._execute_get_result_request(request_header_and_message)
            return
        response = deserialize_message(kept, self._action_type.Impl.GetResultService.Response)
        try:
            self._handle.send_result_response(request_header, response)
        except Exception:  # noqa: BLE001 - rclpy's RCLError: the client went away
            pass


class LabelAction:
    """Serve label_grasps: queue goals, decide them on goal threads, end them.

    Parameters
    ----------
    node : Node
        The force_closure node: its name and namespace.
    context : LaneContext
    participant : BatchParticipant
        The DDS participant the action is served on (the batch topic's).
    """

    def __init__(self, node: Node, context: LaneContext, participant: BatchParticipant):
        self._context = context
        self._lock = threading.Lock()
        self._queued = threading.Condition(self._lock)
        self._stopping = False
        # Goals waiting for a goal thread, oldest first; every goal not yet ended, by id.
        self._queue: deque[LabelGoal] = deque()
        self._goals: dict[bytes, LabelGoal] = {}
        self._running = 0
        # Results of goals ended at shutdown, by id, until sent; when the last was sent.
        self._unsent: dict[int, LabelGrasps.Result] = {}
        self._last_sent: float | None = None
        # On the batch topic's DDS participant: a raw goal of tens of MB floods its
        # shared-memory port, not the services' (see ..participant).
        self._helper = Node(f"{node.get_name()}_action", namespace=node.get_namespace(),
                            context=participant.context, use_global_arguments=False,
                            start_parameter_services=False)
        self._server = _ResultReportingActionServer(
            self._helper, LabelGrasps, LABEL_ACTION, self._execute,
            goal_callback=self._on_goal, cancel_callback=self._on_cancel,
            result_timeout=ACTION_RESULT_TIMEOUT_S, on_result_sent=self._on_result_sent)
        self._executor = SingleThreadedExecutor(context=participant.context)
        self._executor.add_node(self._helper)
        self._spinner = threading.Thread(target=self._spin, daemon=True, name="action")
        self._spinner.start()
        self._threads = [start_thread(f"goal_{index}", self._decide_next, self.stopping,
                                      context) for index in range(ACTION_THREADS)]

    def stopping(self) -> bool:
        return self._stopping

    def counts(self) -> dict[str, int]:
        with self._lock:
            return {"action_goals_queued": len(self._queue),
                    "action_goals_running": self._running}

    def _spin(self) -> None:
        try:
            self._executor.spin()
        except Exception:  # noqa: BLE001 - rclpy shut down while spinning: end quietly
            pass

    def _wake(self) -> None:
        """Wake the executor, which resumes waiting coroutines when it wakes up."""
        try:
            self._executor.wake()
        except Exception:  # noqa: BLE001 - rclpy shut down: no result can be sent anyway
            pass

    # --- the action's executor ------------------------------------------------------------

    def _on_goal(self, _request: Any) -> GoalResponse:
        if self._stopping:
            return GoalResponse.REJECT
        self._context.statistics.count_goal("received")
        return GoalResponse.ACCEPT

    def _on_cancel(self, handle: Any) -> CancelResponse:
        """Accept every cancel: a queued goal ends at once, a running one at its next poll."""
        with self._lock:
            goal = self._goals.get(bytes(handle.goal_id.uuid))
            queued = goal is not None and goal in self._queue
            if goal is not None and queued:
                self._queue.remove(goal)
        if goal is not None:
            goal.cancel()
            if queued:
                self._end(goal, goal.empty_reply(), aborted=False)
        return CancelResponse.ACCEPT

    async def _execute(self, handle: Any) -> LabelGrasps.Result:
        """Queue the goal for a goal thread and await its end."""
        goal = LabelGoal(handle, self._wake)
        with self._lock:
            self._goals[goal.key] = goal
            queue_it = not self._stopping and not handle.is_cancel_requested
            if queue_it:
                self._queue.append(goal)
                self._queued.notify()
        if not queue_it:  # canceled before it was queued, or the node is stopping
            self._end(goal, goal.empty_reply(), aborted=self._stopping)
        try:
            return await goal.finish(self._context.statistics)
        finally:
            with self._lock:
                del self._goals[goal.key]

    def _end(self, goal: LabelGoal, reply: ForceClosureVerdictArray, aborted: bool) -> None:
        """End ``goal`` with ``reply`` (from any thread)."""
        result = LabelGrasps.Result(verdicts=reply)
        with self._lock:
            if self._stopping:  # stop() waits until this result has been sent
                self._unsent[id(result)] = result
        goal.end(result, aborted)

    def _on_result_sent(self, result: LabelGrasps.Result) -> None:
        with self._lock:
            if self._unsent.pop(id(result), None) is not None:
                self._last_sent = time.monotonic()

    # --- the goal threads -----------------------------------------------------------------

    def _decide_next(self) -> None:
        """Decide the oldest queued goal in chunks and end it."""
        with self._lock:
            self._queued.wait_for(lambda: self._queue or self._stopping)
            if self._stopping:
                return
            goal = self._queue.popleft()
            self._running += 1
        try:
            reply, complete = self._decide(goal)
        finally:
            with self._lock:
                self._running -= 1
        self._end(goal, reply, aborted=not complete and not goal.canceled)

    def _decide(self, goal: LabelGoal) -> tuple[ForceClosureVerdictArray, bool]:
        """Decide a goal and count it: (verdicts of all or a prefix, complete)."""
        context = self._context
        query = goal.grasps
        start = context.clock()
        n_grasps = batch_size(query)
        context.statistics.count_received(n_grasps)
        settings = context.settings()
        refusal = context.refusals.oversize(n_grasps, settings, batch_contacts(query))
        if refusal is not None:
            return self._refused(query, refusal), True
        try:
            packed = batch_to_packed(query)
            conversion_s = context.clock() - start
            outcome = decide_in_chunks(
                context.pool, packed, settings,
                stop=lambda: goal.canceled or self._stopping,
                report=lambda progress: self._feedback(goal, progress))
            outcome.seconds["conversion_s"] = conversion_s
            context.warn_invalid(outcome.verdicts)
            reply = verdicts_to_array_msg(outcome.verdicts, query)
            context.statistics.record(outcome.verdicts.status, outcome.seconds,
                                      context.clock() - start)
            context.statistics.count_undecided(n_grasps - len(outcome.verdicts))
            return reply, outcome.complete
        except MalformedBatch as exc:
            if context.may_log("malformed"):
                context.logger.warning(f"label_grasps goal: {exc}")
            context.statistics.record_refused(Status.INVALID_INPUT, n_grasps)
            return self._refused(query, Refusal(Status.INVALID_INPUT, str(exc))), True
        except Exception as exc:  # noqa: BLE001 - the goal must still be answered
            context.internal_error(f"a label_grasps goal of {n_grasps} grasps", exc)
            context.statistics.record_failures(n_grasps)
            return self._refused(query, Refusal(Status.SOLVER_FAILURE,
                                                f"internal error: {exc}")), True

    @staticmethod
    def _refused(query: Any, refusal: Refusal) -> ForceClosureVerdictArray:
        return verdicts_to_array_msg(refused_verdicts(query, refusal), query)

    def _feedback(self, goal: LabelGoal, progress: Progress) -> None:
        try:
            goal.publish_feedback(progress)
        except Exception as exc:  # noqa: BLE001 - a lost feedback must not fail the goal
            self._context.internal_error("label_grasps feedback", exc)

    # --- shutdown -------------------------------------------------------------------------

    def stop(self) -> None:
        """End every goal and stop serving.

        The goal threads end their goals (aborted, with their prefix), the queued goals
        end aborted without verdicts; then waits, for a bounded time, until the results
        of the goals ended now have been sent, and a moment for DDS to deliver them.
        """
        with self._lock:
            self._stopping = True
            self._queued.notify_all()
        for thread in self._threads:
            thread.join()
        with self._lock:
            queued, self._queue = list(self._queue), deque()
        for goal in queued:
            self._end(goal, goal.empty_reply(), aborted=True)
        deadline = time.monotonic() + ACTION_RESULT_SEND_TIMEOUT_S
        while (self._goals or self._unsent) and time.monotonic() < deadline:
            time.sleep(0.01)
        if self._goals or self._unsent:
            self._context.logger.warning(
                f"label_grasps at shutdown: {len(self._goals)} goals not ended, "
                f"{len(self._unsent)} results not sent (not asked for?)")
        if self._last_sent is not None:
            time.sleep(max(0.0, self._last_sent + ACTION_RESULT_DELIVERY_S - time.monotonic()))
        self._executor.shutdown()
        self._spinner.join()
        self._server.destroy()
        self._helper.destroy_node()

    def drain(self) -> Drained:
        return Drained()  # stop() ended every goal
