"""No stall behind a big message: one-grasp service calls while a large batch arrives.

The force_closure node runs in its own process. This process calls check_force_closure
with one 6-finger grasp every --period seconds through grasp_fc_ros.client.GraspClient,
while a batch of --grasps grasps of --contacts contacts each (100,000 x 12 by default,
~58 MB as one message) is sent to the node, decided and answered (--cases picks some):

1. ``batch``: from another process (``GraspClient.check_batch`` in a child process of
   this script);
2. ``goal``: the same grasps as a label_grasps job from another process
   (``GraspClient.label_grasps``);
3. ``raw``: the same grasps as ONE ContactArrayBatch from a plain rclpy publisher in
   another process (not GraspClient), answered on the shared ``verdicts_batch`` topic
   (refused whole beyond the node's ``max_message_contacts``: ``--node-args
   "-p max_message_contacts:=0"`` has it decided);
4. ``this``: from this process (the same GraspClient that makes the service calls, its
   batch sent from a second thread);
5. ``this-goal``: the same as a label_grasps job from this process;
6. ``call``: the same grasps as one ``GraspClient.call`` (the check_force_closure
   service) from another process, which sends them as requests of at most
   MAX_REQUEST_CONTACTS contacts.
7. ``this-raw``: the same as ONE ContactArrayBatch from a plain rclpy publisher on this
   process's client node (so on the participant that makes the service calls);
8. ``raw-goal``: the same as ONE label_grasps goal from a plain rclpy ActionClient in
   another process (refused whole beyond ``max_message_contacts``, as ``raw``).

For each it prints the service round trips while the batch was on its way and being
decided (p50, p99, max; targets p99 <= 50 ms, max <= 100 ms), the seconds from sending
the batch to its answer, and whether every grasp of it was answered (with how many
were refused, and why: the node refuses an oversized raw message); over UDP, also the
datagrams each host dropped at a full socket receive buffer meanwhile (each one sent
again later by DDS, after a negative acknowledgement).

With ``--udp-hosts`` the node and this process (with the sending processes) are on two
simulated hosts: network namespaces on one switch, DDS over UDP only, as
between two machines on a LAN (:mod:`udp_hosts`; needs root: the run is skipped,
saying why, where network namespaces cannot be made).

Usage: python benchmarks/bench_stall.py [--grasps N] [--contacts C] [--period S]
       [--cases batch,goal,raw,raw-goal,call,this,this-goal,this-raw]
       [--node-args "-p max_message_contacts:=0"] [--node-profile FILE] [--udp-hosts]
       [--quick]
       (--send NODE --how HOW is the child process's own form; --node-netns NAME the
       form run in the client's namespace)
"""

from __future__ import annotations

import argparse
import os
import queue
import shlex
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future

import numpy as np
import rclpy
from grasp_fc_msgs.action import LabelGrasps
from grasp_fc_msgs.msg import ContactArrayBatch, ForceClosureVerdictArray
from rclpy.action import ActionClient
from rclpy.node import Node
from rclpy.publisher import Publisher

from bench_ros import CONNECT_TIMEOUT_S, start_node, stop_node, verdict
from grasp_fc_ros.client import GraspClient
from grasp_fc_ros.core import Status, warm_up
from grasp_fc_ros.interface.conversions import grasps_to_batch_msg
from grasp_fc_ros.interface.names import (
    CONTACTS_BATCH_TOPIC,
    LABEL_ACTION,
    QUERY_QOS,
    VERDICTS_BATCH_TOPIC,
    resolve,
)
from grasp_fc_ros.objects import make_object, sample_grasps
from udp_hosts import UdpHosts, in_namespace, udp_drops, unavailable

GRASPS = 100_000
QUICK_GRASPS = 20_000
CONTACTS = 12
# A one-grasp call every 20 ms, as a planner checking grasps while a batch is labelled.
PERIOD_S = 0.02
SERVICE_FINGERS = 6
REPLY_TIMEOUT_S = 600.0
# Service calls timed before the batch is sent, as a baseline on the same machine.
IDLE_CALLS = 50
# The targets (printed, never asserted by a test).
TARGET_P99_MS = 50.0
TARGET_MAX_MS = 100.0


def batch_grasps(n_grasps: int, n_contacts: int) -> tuple[np.ndarray, np.ndarray]:
    """(positions, normals), each (n_grasps, n_contacts, 3): random box grasps."""
    return sample_grasps(make_object("box"), n_grasps, n_contacts, np.random.default_rng(1))


def time_calls(client: GraspClient, grasp: Grasp,
               period_s: float, until: Callable[[], bool]) -> tuple[np.ndarray, np.ndarray]:
    """Round trips (ms) of one-grasp calls, one every ``period_s``, until ``until()``,
    and when each began (``time.perf_counter``, s)."""
    times, starts = [], []
    positions, normals = grasp
    while not until():
        began = time.perf_counter()
        verdicts = client.call(positions, normals, timeout=REPLY_TIMEOUT_S)
        times.append(time.perf_counter() - began)
        starts.append(began)
        assert len(verdicts) == 1
        time.sleep(max(0.0, period_s - (time.perf_counter() - began)))
    return np.array(times) * 1e3, np.array(starts)


def summary(calls: tuple[np.ndarray, np.ndarray], sent_at: float | None = None) -> str:
    """p50, p99 and max of timed calls against the targets; with ``sent_at`` (when the
    batch was sent), a second line saying when the calls over the p99 target began."""
    times_ms, starts = calls
    if not len(times_ms):
        return "no calls"
    p99, worst = np.percentile(times_ms, 99), times_ms.max()
    line = (f"p50 {np.percentile(times_ms, 50):.2f} ms, p99 {p99:.2f} ms, max {worst:.1f} ms "
            f"over {len(times_ms)} calls  [target p99 <= {TARGET_P99_MS:g} ms, max <= "
            f"{TARGET_MAX_MS:g} ms: {verdict(p99 <= TARGET_P99_MS and worst <= TARGET_MAX_MS)}]")
    slow = times_ms > TARGET_P99_MS
    if sent_at is not None and slow.any():
        began = ", ".join(f"{start - sent_at:.2f}" for start in starts[slow][:10])
        line += f"\n    calls over {TARGET_P99_MS:g} ms began {began} s after the send"
    return line


# One grasp: its positions and normals, (n, 3) each.
Grasp = tuple[np.ndarray, np.ndarray]


# What the child process sends, by case: the heading of its lines of results.
SENT_AS = {"batch": "batch from another process", "goal": "goal from another process",
           "raw": "raw batch from another process",
           "raw-goal": "raw goal from another process",
           "call": "service call from another process"}
SENT_FROM_HERE_AS = {"this": "batch", "this-goal": "goal", "this-raw": "raw batch"}
CASES = (*SENT_AS, *SENT_FROM_HERE_AS)


def from_another_process(client: GraspClient, node_name: str, args: argparse.Namespace,
                         grasp: Grasp, how: str) -> str:
    """Time calls while a child process sends the grasps as ``how`` says; its lines of
    results."""
    sender = subprocess.Popen(
        [sys.executable, __file__, "--send", node_name, "--how", how,
         "--grasps", str(args.grasps), "--contacts", str(args.contacts)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert sender.stdin is not None and sender.stdout is not None
    try:
        if sender.stdout.readline().strip() != "ready":
            raise RuntimeError("the sending process did not connect to the node")
        sender.stdin.write("go\n")
        sender.stdin.flush()
        sent_at = time.perf_counter()
        finished = threading.Event()
        result: list[str] = []
        output = sender.stdout

        def read_result() -> None:
            result.append(output.readline())
            finished.set()

        reader = threading.Thread(target=read_result, daemon=True)
        reader.start()
        times = time_calls(client, grasp, args.period, finished.is_set)
        answered, seconds, refused = result[0].rstrip("\n").split(" ", 2)
        return (f"{SENT_AS[how]}: {summary(times, sent_at)}\n"
                f"    the batch answered in {float(seconds):.1f} s, {answered} of "
                f"{args.grasps} grasps{refused}")
    finally:
        sender.kill()
        sender.wait()


def from_this_process(client: GraspClient, node_name: str, args: argparse.Namespace,
                      grasp: Grasp, how: str) -> str:
    """Time calls while this process sends the grasps from another thread: as a batch
    or (``how`` "this-goal") a label_grasps job through the calling client, or
    ("this-raw") as one message from a plain rclpy publisher on the client's node."""
    positions, normals = batch_grasps(args.grasps, args.contacts)
    answer: Future = Future()
    channel = raw_channel(client.node, node_name) if how == "this-raw" else None
    raw = grasps_to_batch_msg(np.arange(len(positions)), positions, normals,
                              request_id=os.getpid()) if channel else None

    def send() -> None:
        if how == "this-goal":
            answer.set_result(client.label_grasps(positions, normals, progress=False,
                                                  timeout=REPLY_TIMEOUT_S))
        elif channel is not None:
            answer.set_result(publish_raw(channel, raw))
        else:
            client.submit_batch(positions, normals).add_done_callback(
                lambda done: answer.set_result(done.result()))

    began = time.perf_counter()
    thread = threading.Thread(target=send)
    thread.start()
    times = time_calls(client, grasp, args.period, answer.done)
    thread.join()
    verdicts = answer.result(REPLY_TIMEOUT_S)
    answered = len(verdicts.ids) if how == "this-raw" else len(verdicts)
    return (f"{SENT_FROM_HERE_AS[how]} from this process: {summary(times, began)}\n"
            f"    the batch answered in {time.perf_counter() - began:.1f} s, {answered} "
            f"of {args.grasps} grasps{refusals(verdicts.status, verdicts.messages)}")


def refusals(status: np.ndarray, messages: Sequence[str]) -> str:
    """' (K refused: <first message>)' for INVALID_INPUT verdicts, '' if none."""
    refused = np.flatnonzero(np.asarray(status) == Status.INVALID_INPUT)
    return f" ({len(refused)} refused: {messages[refused[0]]})" if len(refused) else ""


def report_answer(n_answered: int, began: float, status: np.ndarray,
                  messages: Sequence[str]) -> None:
    """The child process's answer line: '<grasps answered> <seconds since began>
    <refusals>' (``began`` from time.perf_counter())."""
    print(f"{n_answered} {time.perf_counter() - began:.3f} {refusals(status, messages)}",
          flush=True)


def send(node_name: str, how: str, n_grasps: int, n_contacts: int) -> int:
    """The child process: connect, say ready, send the grasps as ``how`` says on 'go',
    print '<grasps answered> <seconds> <refusals>' once answered."""
    positions, normals = batch_grasps(n_grasps, n_contacts)
    rclpy.init()
    client = GraspClient(node_name)
    try:
        if not client.wait_for_node(CONNECT_TIMEOUT_S):
            return 1
        if how == "raw":
            return send_raw(client.node, node_name, positions, normals)
        if how == "raw-goal":
            return send_raw_goal(node_name, positions, normals)
        print("ready", flush=True)
        sys.stdin.readline()
        began = time.perf_counter()
        if how == "goal":
            verdicts = client.label_grasps(positions, normals, progress=False,
                                           timeout=REPLY_TIMEOUT_S)
        elif how == "call":
            verdicts = client.call(positions, normals, timeout=REPLY_TIMEOUT_S)
        else:
            verdicts = client.check_batch(positions, normals, timeout=REPLY_TIMEOUT_S)
        report_answer(len(verdicts), began, verdicts.status, verdicts.messages)
        return 0
    finally:
        client.close()
        rclpy.try_shutdown()


def raw_channel(node: Node, node_name: str) -> tuple[Publisher, queue.SimpleQueue] | None:
    """A plain rclpy publisher of batches to the node, on ``node``, and a queue of the
    answers on the shared verdicts_batch topic, once both have matched the node (None if
    not within CONNECT_TIMEOUT_S). ``node`` must be spun (GraspClient's is)."""
    answers: queue.SimpleQueue = queue.SimpleQueue()
    publisher = node.create_publisher(
        ContactArrayBatch, resolve(node_name, CONTACTS_BATCH_TOPIC), QUERY_QOS)
    node.create_subscription(ForceClosureVerdictArray,
                             resolve(node_name, VERDICTS_BATCH_TOPIC), answers.put, QUERY_QOS)
    deadline = time.monotonic() + CONNECT_TIMEOUT_S
    while (publisher.get_subscription_count() == 0
           or node.count_publishers(resolve(node_name, VERDICTS_BATCH_TOPIC)) == 0):
        if time.monotonic() > deadline:
            return None
        time.sleep(0.05)
    return publisher, answers


def publish_raw(channel: tuple[Publisher, queue.SimpleQueue],
                msg: ContactArrayBatch) -> ForceClosureVerdictArray:
    """Publish ``msg`` as one message and wait for its answer (by request id)."""
    publisher, answers = channel
    publisher.publish(msg)
    while (answer := answers.get(timeout=REPLY_TIMEOUT_S)).request_id != msg.request_id:
        pass
    return answer


def send_raw(node: Node, node_name: str, positions: np.ndarray, normals: np.ndarray) -> int:
    """Publish the grasps as one ContactArrayBatch (client id 0) from a plain rclpy
    publisher on ``node`` and wait for its answer on the shared verdicts_batch topic."""
    msg = grasps_to_batch_msg(np.arange(len(positions)), positions, normals,
                              request_id=os.getpid())
    channel = raw_channel(node, node_name)
    if channel is None:
        return 1
    print("ready", flush=True)
    sys.stdin.readline()
    began = time.perf_counter()
    answer = publish_raw(channel, msg)
    report_answer(len(answer.ids), began, answer.status, answer.messages)
    return 0


def send_raw_goal(node_name: str, positions: np.ndarray, normals: np.ndarray) -> int:
    """Send the grasps as ONE label_grasps goal from a plain rclpy ActionClient (not
    GraspClient, which sends goals of at most MAX_MESSAGE_CONTACTS contacts) and wait
    for its result."""
    node = Node(f"raw_goal_sender_{os.getpid()}")
    client = ActionClient(node, LabelGrasps, resolve(node_name, LABEL_ACTION))
    try:
        if not client.wait_for_server(timeout_sec=CONNECT_TIMEOUT_S):
            return 1
        goal = LabelGrasps.Goal(grasps=grasps_to_batch_msg(
            np.arange(len(positions)), positions, normals, request_id=os.getpid()))
        print("ready", flush=True)
        sys.stdin.readline()
        began = time.perf_counter()
        sent = client.send_goal_async(goal)
        rclpy.spin_until_future_complete(node, sent, timeout_sec=REPLY_TIMEOUT_S)
        result = sent.result().get_result_async()
        rclpy.spin_until_future_complete(node, result, timeout_sec=REPLY_TIMEOUT_S)
        verdicts = result.result().result.verdicts
        report_answer(len(verdicts.ids), began, verdicts.status, verdicts.messages)
        return 0
    finally:
        client.destroy()
        node.destroy_node()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="service latency while a big batch arrives")
    parser.add_argument("--grasps", type=int, default=None,
                        help=f"grasps in the batch (default {GRASPS}; --quick {QUICK_GRASPS})")
    parser.add_argument("--contacts", type=int, default=CONTACTS, help="contacts per grasp")
    parser.add_argument("--period", type=float, default=PERIOD_S,
                        help="seconds between the starts of two service calls")
    parser.add_argument("--cases", default=",".join(CASES),
                        help=f"comma-separated, of {', '.join(CASES)} (default all)")
    parser.add_argument("--node-args", default="",
                        help="extra --ros-args for the node, e.g. '-p max_message_contacts:=0'")
    parser.add_argument("--node-profile", metavar="FILE", type=os.path.abspath,
                        help="a Fast DDS profiles file for the node (it then sets none of "
                             "its own: e.g. one of reader times only, without its receive "
                             "buffers, to compare)")
    parser.add_argument("--udp-hosts", action="store_true",
                        help="the node and the clients on two simulated hosts (network "
                             "namespaces, DDS over UDP); needs root")
    parser.add_argument("--quick", action="store_true", help="the smoke test's short form")
    parser.add_argument("--send", metavar="NODE", help=argparse.SUPPRESS)
    parser.add_argument("--how", choices=SENT_AS, default="batch", help=argparse.SUPPRESS)
    parser.add_argument("--node-netns", metavar="NAME", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    args.grasps = args.grasps or (QUICK_GRASPS if args.quick else GRASPS)
    if args.send:
        return send(args.send, args.how, args.grasps, args.contacts)
    if args.udp_hosts:
        return on_udp_hosts([arg for arg in (sys.argv[1:] if argv is None else argv)
                             if arg != "--udp-hosts"])
    cases = args.cases.split(",")
    if unknown := set(cases) - set(CASES):
        parser.error(f"unknown cases {sorted(unknown)}; choose from {', '.join(CASES)}")
    warm_up()  # a fresh clone compiles the kernels here, not in the node's start
    rng = np.random.default_rng(0)
    grasp = sample_grasps(make_object("box"), 1, SERVICE_FINGERS, rng)
    rclpy.init()
    wrapper = in_namespace(args.node_netns, []) if args.node_netns else []
    if args.node_profile:
        wrapper += ["env", f"FASTRTPS_DEFAULT_PROFILES_FILE={args.node_profile}"]
    node, client = start_node("stall", ["-p", f"max_batch:={args.grasps}",
                                        *shlex.split(args.node_args)], wrapper)
    node_name = f"/grasp_fc_stall_{os.getpid()}/force_closure"  # as start_node names it
    try:
        megabytes = args.grasps * args.contacts * 6 * 8 / 1e6  # positions, normals
        print(f"{args.grasps} grasps of {args.contacts} contacts (~{megabytes:.0f} MB as one "
              f"message), one {SERVICE_FINGERS}-finger service call every "
              f"{1e3 * args.period:g} ms")
        calls = iter(range(IDLE_CALLS + 1))
        idle = time_calls(client, grasp, args.period, lambda: next(calls) == IDLE_CALLS)
        print(f"idle: {summary(idle)}")
        for case in cases:
            dropped = (udp_drops(node.pid), udp_drops()) if args.node_netns else None
            print(from_this_process(client, node_name, args, grasp, case)
                  if case in SENT_FROM_HERE_AS else
                  from_another_process(client, node_name, args, grasp, case))
            if dropped is not None:
                print(f"    UDP datagrams dropped at a full receive buffer: "
                      f"{udp_drops(node.pid) - dropped[0]} on the node's host, "
                      f"{udp_drops() - dropped[1]} on the client's")
        return 0
    finally:
        stop_node(node, client)
        rclpy.try_shutdown()


def on_udp_hosts(argv: list[str]) -> int:
    """Run this benchmark (``argv``) in the client's namespace of two simulated hosts,
    its node in the node's; skipped, saying why, where namespaces cannot be made."""
    reason = unavailable()
    if reason is not None:
        print(f"two hosts over UDP: skipped: {reason}")
        return 0
    with UdpHosts() as hosts:
        print(f"two hosts over UDP: node in network namespace {hosts.namespaces['node']}, "
              f"clients in {hosts.namespaces['client']}, on one switch (test/net_hosts.py); "
              "Fast DDS on UDPv4 only", flush=True)
        return subprocess.run(hosts.command("client", [
            sys.executable, __file__, *argv, "--node-netns", hosts.namespaces["node"]])
        ).returncode


if __name__ == "__main__":
    sys.exit(main())
