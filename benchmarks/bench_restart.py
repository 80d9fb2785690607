"""A node SIGKILLed mid-job: how soon a label_grasps job ends after the node's restart.

The force_closure node runs in its own process (its console script, default parameters).
A ``GraspClient.label_grasps`` job of --grasps 6-finger grasps (timeout None, as a user
calls it) runs on a thread of this process; once the job's feedback shows part of it decided, the
node is SIGKILLed and started again at once. Printed: the seconds from the restart to
the job's end (target <= 30 s; it includes deciding what the killed node had not
answered), the goals the client sent again and when, and whether every verdict came back once, in
order, equal to the core's (check_force_closure in this process on the same grasps).

With --never-back, a second run kills the node and does not restart it: the job must end
with NodeGoneError and the decided prefix (equal to the core's) once the node has been
out of the ROS graph for NODE_RETURN_WAIT_S (its DDS lease first: Fast DDS, 20 s).

Usage: python benchmarks/bench_restart.py [--grasps N] [--never-back] [--quick]
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import rclpy
from action_msgs.msg import GoalStatus

from bench_ros import CONNECT_TIMEOUT_S, node_command, verdict
from grasp_fc_ros.client import GraspClient, NodeGoneError, Verdicts
from grasp_fc_ros.client.label_action import NODE_RETURN_WAIT_S
from grasp_fc_ros.core import check_force_closure, warm_up
from grasp_fc_ros.objects import make_object, sample_grasps

N_FINGERS = 6
MU = 0.5  # the node's default friction
GRASPS = 400_000
# Several seconds of work at the quick form's rate, so that the kill, at the job's first
# feedback (~0.25 s), lands while it runs even on an idle machine.
QUICK_GRASPS = 300_000
UNIQUE_GRASPS = 2000
# The target: the job ends within this long of the node's restart (s).
TARGET_END_S = 30.0
# Longest any wait here may take (s): far beyond the targets, so a hang shows as a failure.
JOB_LIMIT_S = 600.0


class Job:
    """``client.label_grasps`` on a thread of its own; its outcome and end time."""

    def __init__(self, client: GraspClient, positions: np.ndarray, normals: np.ndarray):
        self.verdicts: Verdicts | None = None
        self.error: BaseException | None = None
        self.ended_at: float | None = None
        self.started_at = time.monotonic()
        self._thread = threading.Thread(target=self._run, args=(client, positions, normals),
                                        daemon=True)
        self._thread.start()

    def _run(self, client: GraspClient, positions: np.ndarray, normals: np.ndarray) -> None:
        try:
            self.verdicts = client.label_grasps(positions, normals, progress=False)
        except BaseException as exc:  # noqa: BLE001 - reported by the caller
            self.error = exc
        self.ended_at = time.monotonic()

    def join(self) -> bool:
        """Wait for the job's end (at most JOB_LIMIT_S); whether it ended."""
        self._thread.join(JOB_LIMIT_S)
        return not self._thread.is_alive()


def kill_mid_job(node: subprocess.Popen[bytes], client: GraspClient, positions: np.ndarray,
                 normals: np.ndarray) -> tuple[Job, float]:
    """Start the job once the node is there; SIGKILL ``node`` once the job's feedback
    shows part of it decided: (the job, when the node died)."""
    if not client.wait_for_node(CONNECT_TIMEOUT_S):
        raise RuntimeError("node did not come up")
    job = Job(client, positions, normals)
    deadline = time.monotonic() + JOB_LIMIT_S
    while (progress := client.label_action.last_job_progress) is None or progress.done == 0:
        if job.ended_at is not None or time.monotonic() > deadline:
            raise RuntimeError(f"the job ended (or never started) before the kill: {job.error!r}")
        time.sleep(0.005)
    node.send_signal(signal.SIGKILL)
    node.wait(timeout=10)
    if job.ended_at is not None:
        raise RuntimeError("the job ended before the kill: use more --grasps")
    return job, time.monotonic()


def goals_sent_again(client: GraspClient, job: Job) -> float | None:
    """When the client sent the job's unfinished goals again (time.monotonic()); None if
    the job ended first."""
    deadline = time.monotonic() + JOB_LIMIT_S
    while client.label_action.last_job_resent == 0:
        if job.ended_at is not None or time.monotonic() > deadline:
            return None
        time.sleep(0.01)
    return time.monotonic()


def equal_to_core(verdicts: Verdicts, expected: np.ndarray) -> tuple[int, int]:
    """(verdicts whose id or status differs from the core's, grasps missing)."""
    n = len(verdicts)
    differ = int(np.count_nonzero((verdicts.ids != np.arange(n))
                                  | (verdicts.status != expected[:n])))
    return differ, len(expected) - n


def killed_and_restarted(namespace: str, positions: np.ndarray, normals: np.ndarray,
                         expected: np.ndarray) -> bool:
    command = node_command(namespace)
    node = subprocess.Popen(command)
    client = GraspClient(f"{namespace}/force_closure")
    try:
        job, killed_at = kill_mid_job(node, client, positions, normals)
        node = subprocess.Popen(command)
        restarted_at = time.monotonic()
        resent_at = goals_sent_again(client, job)
        ended = job.join()
    finally:
        client.close()
        node.send_signal(signal.SIGINT)
        node.wait(timeout=10)
    if not ended or job.ended_at is None:
        print(f"killed and restarted: the job did not end within {JOB_LIMIT_S:g} s  "
              f"[target <= {TARGET_END_S:g} s: {verdict(False)}]")
        return False
    if job.error is not None or job.verdicts is None:
        print(f"killed and restarted: the job failed: {job.error!r}  [{verdict(False)}]")
        return False
    differ, missing = equal_to_core(job.verdicts, expected)
    end_s = job.ended_at - restarted_at
    ok = (end_s <= TARGET_END_S and differ == 0 and missing == 0
          and client.last_goal_status == GoalStatus.STATUS_SUCCEEDED)
    resent = ("never" if resent_at is None
              else f"{resent_at - restarted_at:.1f} s after the restart")
    print(f"killed {killed_at - job.started_at:.1f} s into the job and restarted: the job "
          f"ended {end_s:.1f} s after the restart, {client.label_action.last_job_resent} "
          f"goals sent again ({resent}); {len(job.verdicts)} of {len(expected)} verdicts, "
          f"{differ} differ from the core's  [target <= {TARGET_END_S:g} s, complete, equal: "
          f"{verdict(ok)}]")
    return ok


def never_back(namespace: str, positions: np.ndarray, normals: np.ndarray,
               expected: np.ndarray) -> bool:
    node = subprocess.Popen(node_command(namespace))
    client = GraspClient(f"{namespace}/force_closure")
    try:
        job, killed_at = kill_mid_job(node, client, positions, normals)
        ended = job.join()
    finally:
        client.close()
    if not ended or job.ended_at is None or not isinstance(job.error, NodeGoneError):
        print(f"never back: the job did not end with NodeGoneError: {job.error!r}  "
              f"[{verdict(False)}]")
        return False
    differ, _ = equal_to_core(job.error.verdicts, expected)
    print(f"never back: NodeGoneError {job.ended_at - killed_at:.1f} s after the kill "
          f"(lease, then {NODE_RETURN_WAIT_S:g} s), prefix of {len(job.error.verdicts)} of "
          f"{len(expected)} verdicts, {differ} differ from the core's  "
          f"[ends, prefix equal: {verdict(differ == 0)}]")
    return differ == 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="a label job across a node's SIGKILL")
    parser.add_argument("--grasps", type=int, default=None,
                        help=f"grasps in the job (default {GRASPS}; --quick {QUICK_GRASPS})")
    parser.add_argument("--never-back", action="store_true",
                        help="also kill the node for good (the job ends ~80 s later)")
    parser.add_argument("--quick", action="store_true", help="the smoke test's short form")
    args = parser.parse_args(argv)
    n_grasps = args.grasps or (QUICK_GRASPS if args.quick else GRASPS)
    warm_up()  # the node's workers then load the kernels from numba's cache
    unique = sample_grasps(make_object("box"), UNIQUE_GRASPS, N_FINGERS,
                           np.random.default_rng(0))
    reps = -(-n_grasps // UNIQUE_GRASPS)
    positions, normals = (np.tile(a, (reps, 1, 1))[:n_grasps] for a in unique)
    expected = np.tile(check_force_closure(*unique, MU).status, reps)[:n_grasps]
    print(f"a label_grasps job of {n_grasps} {N_FINGERS}-finger box grasps; "
          f"{os.cpu_count()} CPUs; load {os.getloadavg()[0]:.1f}")
    rclpy.init()
    try:
        ok = killed_and_restarted(f"/grasp_fc_restart_{os.getpid()}", positions, normals,
                                  expected)
        if args.never_back:
            ok = never_back(f"/grasp_fc_gone_{os.getpid()}", positions, normals,
                            expected) and ok
    finally:
        rclpy.try_shutdown()
    print(f"a label job across its node's SIGKILL: {verdict(ok)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
