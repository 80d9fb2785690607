"""A running node loses no grasp when one of its worker processes dies: a worker SIGKILLed
in the middle of a batch and in the middle of a label_grasps goal, and every verdict is
still the one the core gives (check_force_closure on the same grasps).

The node runs in this process (own_node), so its worker processes are children of this
process: found through /proc by their command line. The long form, a 200,000-grasp
batch, is benchmarks/bench_faults.py.
"""

from __future__ import annotations

import os
import signal
import threading
import time
from concurrent.futures import Future
from pathlib import Path

import numpy as np
import pytest

from grasp_fc_ros.core import check_force_closure
from grasp_fc_ros.objects import make_object, sample_grasps

pytestmark = pytest.mark.timeout(180)

# Grasps per request: a few seconds of work for the node's two workers here, so that a
# kill once a worker is busy on it lands well before the end.
N_GRASPS = 40_000
N_FINGERS = 6
MU = 0.5  # the node's default friction
# A worker counts as busy on the request once it has used this much more CPU (s).
BUSY_CPU_S = 0.05
WAIT_S = 120.0
# A worker that uses no CPU for this long is idle (s).
IDLE_S = 0.3
# The exact test's margin depends on which grasps share a solver call, to solver accuracy.
MARGIN_ABS_TOL = 1e-6
MARGIN_REL_TOL = 1e-4


@pytest.fixture(scope="module")
def grasps():
    positions, normals = sample_grasps(make_object("box"), N_GRASPS, N_FINGERS,
                                       np.random.default_rng(22))
    return positions, normals, check_force_closure(positions, normals, MU)


def children() -> dict[int, str]:
    """Command line of each child process of this process (Linux /proc)."""
    found = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
            command = Path(f"/proc/{entry}/cmdline").read_bytes()
        except OSError:
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) == os.getpid():
            found[int(entry)] = command.replace(b"\0", b" ").decode()
    return found


def worker_pids() -> set[int]:
    return {pid for pid, command in children().items()
            if "grasp_fc_ros.engine.worker" in command}


def cpu_s(pid: int) -> float:
    """CPU seconds used so far by process ``pid`` (0 if it is gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def kill_a_busy_worker(workers: set[int], answer: Future) -> int:
    """SIGKILL the first of ``workers`` to use BUSY_CPU_S more CPU, before ``answer`` is
    done (the request is then still being decided); its pid."""
    start = {pid: cpu_s(pid) for pid in workers}
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        busy = [pid for pid in workers if cpu_s(pid) - start[pid] >= BUSY_CPU_S]
        if busy:
            assert not answer.done(), "the request was decided before the kill"
            os.kill(busy[0], signal.SIGKILL)
            return busy[0]
        time.sleep(0.002)
    raise AssertionError("no worker got busy")


def assert_as_core(verdicts, expected) -> None:
    np.testing.assert_array_equal(verdicts.ids, np.arange(N_GRASPS))
    np.testing.assert_array_equal(verdicts.status, expected.status)
    np.testing.assert_array_equal(verdicts.force_closure, expected.force_closure)
    np.testing.assert_allclose(verdicts.margin, expected.margin, rtol=MARGIN_REL_TOL,
                               atol=MARGIN_ABS_TOL, equal_nan=True)
    assert not any(verdicts.messages)


@pytest.fixture(scope="module")
def served(ros):
    """A node with two workers in a namespace of its own, a GraspClient of it, and the
    node's worker processes."""
    from rclpy.parameter import Parameter

    from grasp_fc_ros.client import GraspClient
    from grasp_fc_ros.node import ForceClosureNode
    from ros_fixtures import SpinThread

    before = worker_pids()
    namespace = "/faults_test"
    node = ForceClosureNode(namespace=namespace, parameter_overrides=[
        Parameter("workers", value=2)])
    spinner = SpinThread(node)
    client = GraspClient(f"{namespace}/force_closure")
    assert client.wait_for_node(timeout=30.0)
    workers = worker_pids() - before
    assert len(workers) == 2
    yield client, workers
    client.close()
    spinner.stop()


def replaced(served, killed: int) -> None:
    """The killed worker is reaped and the node has two idle workers again (the
    replacement's start uses CPU: a later kill_a_busy_worker must not take it for work)."""
    _, workers = served
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        now = worker_pids()
        if killed not in children() and len(now) == 2 and killed not in now:
            used = {pid: cpu_s(pid) for pid in now}
            time.sleep(IDLE_S)
            if all(cpu_s(pid) == used[pid] for pid in now):
                workers.clear()
                workers.update(now)
                return
        time.sleep(0.05)
    raise AssertionError(f"worker {killed} not reaped and replaced")


def test_a_worker_killed_mid_batch_costs_no_grasp(grasps, served):
    client, workers = served
    positions, normals, expected = grasps
    restarts = int(client.next_diagnostics()["worker_restarts"])
    answer = client.submit_batch(positions, normals)
    killed = kill_a_busy_worker(set(workers), answer)
    assert_as_core(answer.result(timeout=WAIT_S), expected)
    replaced(served, killed)
    assert int(client.next_diagnostics()["worker_restarts"]) == restarts + 1


def test_a_worker_killed_mid_goal_costs_no_grasp(grasps, served):
    client, workers = served
    positions, normals, expected = grasps
    answer: Future = Future()

    def label() -> None:
        try:
            answer.set_result(client.label_grasps(positions, normals, progress=False,
                                                  timeout=WAIT_S))
        except BaseException as exc:  # noqa: BLE001 - reported by answer.result()
            answer.set_exception(exc)

    thread = threading.Thread(target=label, daemon=True)
    thread.start()
    killed = kill_a_busy_worker(set(workers), answer)
    assert_as_core(answer.result(timeout=WAIT_S), expected)
    from action_msgs.msg import GoalStatus

    assert client.last_goal_status == GoalStatus.STATUS_SUCCEEDED
    replaced(served, killed)


def test_workers_killed_while_starting_come_back_and_diagnostics_warn_meanwhile(
        grasps, served):
    """An operator kills a worker, then each replacement while it starts (6 kills): the
    batch sent meanwhile is decided as by the core, /diagnostics is WARN with
    workers_alive below workers_configured, counts every kill in worker_restarts, and
    is OK with both workers again once the kills end (the pool never gives up)."""
    from diagnostic_msgs.msg import DiagnosticStatus

    from ros_fixtures import DiagnosticsWatch, key_values

    client, workers = served
    positions, normals, expected = grasps
    watch = DiagnosticsWatch("/faults_test/force_closure")
    try:
        before = watch.wait_for(lambda level, v: v["workers_alive"] == "2", "2 workers")
        assert before.level == DiagnosticStatus.OK
        restarts = int(key_values(before)["worker_restarts"])
        answer = client.submit_batch(positions, normals)
        seen = set(workers)
        os.kill(next(iter(workers)), signal.SIGKILL)
        kills = 1
        deadline = time.monotonic() + WAIT_S
        while kills < 6:
            assert time.monotonic() < deadline, f"only {kills} kills within {WAIT_S} s"
            for pid in worker_pids() - seen:
                seen.add(pid)
                os.kill(pid, signal.SIGKILL)  # a replacement, while it starts
                kills += 1
            time.sleep(0.005)
        short = watch.wait_for(lambda level, v: v["workers_alive"] == "1", "1 worker",
                               WAIT_S)
        assert short.level == DiagnosticStatus.WARN
        assert "1 of 2 worker processes running" in short.message
        assert_as_core(answer.result(timeout=WAIT_S), expected)
        back = watch.wait_for(lambda level, v: level == DiagnosticStatus.OK
                              and v["workers_alive"] == "2", "both workers back", WAIT_S)
        values = key_values(back)
        assert values["workers_configured"] == "2"
        assert int(values["worker_restarts"]) == restarts + kills
    finally:
        watch.close()
    workers.clear()
    workers.update(worker_pids())
    assert len(workers) == 2
