"""Action benchmark: the force_closure node's label_grasps action through DDS.

The node runs from its console script in a namespace of its own (as in bench_ros.py);
goals are sent with an rclpy ActionClient on a GraspClient's node. Prints

1. feedback: messages per second over one goal of --goal-grasps grasps, and the
   largest gap between two (target: at least 1 per second, i.e. gap <= 1 s);
2. cancel latency: --cancels goals, each cancelled --cancel-after s after its first
   progress; time from the cancel request to the result (median, max; target
   <= 100 ms), and whether every returned prefix equals the core's verdicts (0 lost);
3. throughput: goals of --goal-grasps against batches of the same grasps on the batch
   topic, --rounds alternating rounds (median grasps/s each, and their ratio).

The machine may be shared: rates and latencies vary from run to run; compare figures
of one run.

Usage: python benchmarks/bench_action.py [--goal-grasps N] [--cancels C]
       [--cancel-after S] [--rounds R] [--object NAME]
       python benchmarks/bench_action.py --quick    # the smoke test's form
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import threading
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
import rclpy
from action_msgs.msg import GoalStatus
from grasp_fc_msgs.action import LabelGrasps
from grasp_fc_msgs.msg import ContactArrayBatch
from rclpy.action import ActionClient
from rclpy.node import Node
from rclpy.task import Future

from bench_ros import REPLY_TIMEOUT_S, start_node, stop_node  # noqa: E402
from grasp_fc_ros.client import request_on_spin_thread
from grasp_fc_ros.core import check_force_closure
from grasp_fc_ros.interface.conversions import grasps_to_batch_msg, verdict_array_to_numpy
from grasp_fc_ros.objects import make_object, sample_grasps
from grasp_fc_ros.packed import Verdicts

N_FINGERS = 6
N_UNIQUE = 5000
TARGET_FEEDBACK_GAP_S = 1.0
TARGET_CANCEL_S = 0.1


class TimedGoal:
    """A goal, its feedback arrival times, and when its result came."""

    def __init__(self, action: tuple[ActionClient, Node], batch: ContactArrayBatch) -> None:
        """``action``: the ActionClient and the node it is on, which another thread
        spins; requests are made on that thread (rclpy's ActionClient loses a response
        taken between sending a request and registering its future)."""
        action_client, node = action
        self.feedback_times: list[float] = []
        self.done_reported = 0
        self.sent = time.monotonic()
        self._request = lambda request: request_on_spin_thread(node, request)
        accepted = threading.Event()
        future = self._request(lambda: action_client.send_goal_async(
            LabelGrasps.Goal(grasps=batch), feedback_callback=self._on_feedback))
        future.add_done_callback(lambda _: accepted.set())
        if not accepted.wait(REPLY_TIMEOUT_S) or not future.result().accepted:
            raise RuntimeError("goal not accepted")
        self.handle = future.result()
        self.ended: float | None = None
        self._done = threading.Event()
        self._result = self._request(self.handle.get_result_async)
        self._result.add_done_callback(self._on_result)

    def cancel(self) -> None:
        self._request(self.handle.cancel_goal_async)

    def _on_feedback(self, msg: Any) -> None:
        self.feedback_times.append(time.monotonic())
        self.done_reported = msg.feedback.done

    def _on_result(self, _: Future) -> None:
        self.ended = time.monotonic()
        self._done.set()

    def result(self) -> tuple[int, Verdicts]:
        if not self._done.wait(REPLY_TIMEOUT_S):
            raise RuntimeError("no result")
        response = self._result.result()
        return response.status, verdict_array_to_numpy(response.result.verdicts)


def bench_feedback(action: tuple[ActionClient, Node], batch: ContactArrayBatch,
                   n_grasps: int) -> float:
    goal = TimedGoal(action, batch)
    status, verdicts = goal.result()
    assert goal.ended is not None  # result() waited for it
    duration = goal.ended - goal.sent
    gaps = np.diff([goal.sent] + goal.feedback_times + [goal.ended])
    ok = status == GoalStatus.STATUS_SUCCEEDED and len(verdicts) == n_grasps
    print(f"feedback: {len(goal.feedback_times)} messages over {duration:.2f} s = "
          f"{len(goal.feedback_times) / duration:.1f} per s, largest gap {gaps.max():.3f} s "
          f"(target <= {TARGET_FEEDBACK_GAP_S:.0f} s: "
          f"{'meets target' if gaps.max() <= TARGET_FEEDBACK_GAP_S else 'BELOW target'})"
          f"{'' if ok else '  INCOMPLETE'}")
    return n_grasps / duration


def bench_cancel(action: tuple[ActionClient, Node], batch: ContactArrayBatch,
                 expected: np.ndarray, n_cancels: int, after_s: float) -> bool:
    """Cancels ``n_cancels`` goals ``after_s`` after their first progress; True when every
    answer is lossless. A goal that ended before its cancel reached the node (a loaded
    machine can delay the cancel past the goal's end) is a complete, correct answer, not
    a loss: it is counted apart and its latency left out."""
    latencies, lossless, prefixes, ended_first = [], True, [], 0
    for _ in range(n_cancels):
        goal = TimedGoal(action, batch)
        # A goal may end before any progress was reported (the node is fast, or the
        # feedback slow): its cancel then comes after its end.
        while goal.ended is None and (not goal.feedback_times or goal.done_reported == 0):
            time.sleep(0.005)
        time.sleep(after_s)
        cancel_at = time.monotonic()
        goal.cancel()
        status, verdicts = goal.result()
        assert goal.ended is not None
        n = len(verdicts)
        prefixes.append(n)
        if status == GoalStatus.STATUS_SUCCEEDED:
            ended_first += 1
            complete = n == len(expected)
        else:
            latencies.append(goal.ended - cancel_at)
            complete = status == GoalStatus.STATUS_CANCELED and n >= goal.done_reported
        lossless &= (complete and np.array_equal(verdicts.ids, np.arange(n))
                     and np.array_equal(verdicts.status, expected[:n]))
    if latencies:
        ms = np.array(latencies) * 1e3
        print(f"cancel latency over {len(ms)} cancels: median {np.median(ms):.1f} ms, "
              f"max {ms.max():.1f} ms (target <= {TARGET_CANCEL_S * 1e3:.0f} ms: "
              f"{'meets target' if ms.max() <= TARGET_CANCEL_S * 1e3 else 'BELOW target'})")
    print(f"cancels: {n_cancels - ended_first} cut goals short, {ended_first} came after "
          f"the goal ended; prefixes of {min(prefixes)}-{max(prefixes)} grasps, "
          f"{'0 lost, all equal the core' if lossless else 'LOST OR WRONG verdicts'}")
    return lossless


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Benchmark of the label_grasps action")
    parser.add_argument("--goal-grasps", type=int, default=100_000,
                        help="grasps per goal (at most the node's max_batch, 100,000)")
    parser.add_argument("--cancels", type=int, default=10, help="goals cancelled")
    # A 100,000-grasp goal takes ~0.5 s here and reports progress every ~0.25 s: a
    # later cancel mostly comes after the goal's end.
    parser.add_argument("--cancel-after", type=float, default=0.05,
                        help="seconds after a goal's first progress to cancel it")
    parser.add_argument("--rounds", type=int, default=3,
                        help="alternating goal/batch rounds for the throughput")
    parser.add_argument("--object", default="box", help="built-in object")
    parser.add_argument("--quick", action="store_true",
                        help="the smoke test's form: 2 cancels at the first progress, one round")
    args = parser.parse_args(argv)
    if args.quick:
        args.cancels, args.cancel_after, args.rounds = 2, 0.0, 1

    positions, normals = sample_grasps(make_object(args.object), min(N_UNIQUE, args.goal_grasps),
                                       N_FINGERS, np.random.default_rng(0))
    expected_unique = np.asarray(check_force_closure(positions, normals, 0.5).status)
    reps = -(-args.goal_grasps // len(positions))
    positions = np.concatenate([positions] * reps)[:args.goal_grasps]
    normals = np.concatenate([normals] * reps)[:args.goal_grasps]
    expected = np.concatenate([expected_unique] * reps)[:args.goal_grasps]
    batch = grasps_to_batch_msg(np.arange(args.goal_grasps), positions, normals)

    rclpy.init()
    # Goals as one message each, of up to max_batch grasps: no limit on their contacts.
    node, client = start_node("action", ["-p", "max_message_contacts:=0"])
    try:
        namespace = f"/grasp_fc_action_{os.getpid()}"  # as start_node("action") names it
        action_client = ActionClient(client.node, LabelGrasps, f"{namespace}/label_grasps")
        if not action_client.wait_for_server(timeout_sec=30.0):
            raise RuntimeError("no label_grasps server")
        action = (action_client, client.node)
        print(f"{args.goal_grasps} {N_FINGERS}-finger grasps per goal on '{args.object}'; "
              "the node has 2 workers; shared machine: figures vary between runs")
        bench_feedback(action, batch, args.goal_grasps)
        lossless = bench_cancel(action, batch, expected, args.cancels, args.cancel_after)
        goal_rates, batch_rates = [], []
        for _ in range(args.rounds):  # alternating, so that a busy spell hits both
            start = time.perf_counter()
            verdicts = client.check_batch(positions, normals, timeout=REPLY_TIMEOUT_S)
            batch_rates.append(len(verdicts) / (time.perf_counter() - start))
            start = time.perf_counter()
            TimedGoal(action, batch).result()
            goal_rates.append(args.goal_grasps / (time.perf_counter() - start))
        goal_rate, batch_rate = statistics.median(goal_rates), statistics.median(batch_rates)
        print(f"throughput (medians of {args.rounds} alternating rounds): action "
              f"{goal_rate:.0f} grasps/s, batch topic {batch_rate:.0f} grasps/s, "
              f"ratio {goal_rate / batch_rate:.2f}")
    finally:
        stop_node(node, client)
        rclpy.try_shutdown()
    return 0 if lossless else 1


if __name__ == "__main__":
    sys.exit(main())
