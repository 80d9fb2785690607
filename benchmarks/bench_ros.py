"""ROS benchmark: the force_closure node in its own process, queried through DDS.

Prints
1. single-grasp topic queries per second, sustained at reliable QoS with no loss
   (a window of queries in flight; every id must come back exactly once, in order);
2. batch throughput, 6-finger grasps in batches of 1,000, against the core alone on
   the same grasps in this process (ROS overhead = 1 - ROS rate / core rate);
3. service round trip p50/p99 for one 6-finger grasp;
4. where the node's time went (its /diagnostics counters: message conversion,
   filter, exact test), per phase.

The node is started from its console script (grasp-fc-node, next to this Python) in a
namespace of its own, so other nodes on the same ROS domain do not interfere.

Usage: python benchmarks/bench_ros.py [--queries N] [--batches B] [--batch-size S]
       [--service-calls C] [--object NAME] [--window W]
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from grasp_fc_msgs.msg import (
    ContactArray,
    ContactArrayBatch,
    ForceClosureVerdict,
    ForceClosureVerdictArray,
)
from grasp_fc_msgs.srv import CheckForceClosure
from grasp_fc_ros.conversions import grasp_to_contact_array, grasps_to_batch_msg
from grasp_fc_ros.core import check_force_closure
from grasp_fc_ros.objects import make_object, sample_grasps

N_FINGERS = 6
# History depth of the node's topics: far above the queries in flight (--window), so
# that reliable delivery is never the limit being measured.
NODE_QOS_DEPTH = 10_000
CONNECT_TIMEOUT_S = 30.0
REPLY_TIMEOUT_S = 120.0
TARGET_SINGLE_PER_S = 2000
TARGET_OVERHEAD = 0.20
TARGET_SERVICE_P50_MS = 2.0
DIAGNOSTIC_TIMES = ("conversion_time_total_s", "filter_time_total_s", "exact_time_total_s")


class BenchClient(Node):
    def __init__(self, namespace: str):
        super().__init__("bench_client", namespace=namespace)
        qos = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                         history=HistoryPolicy.KEEP_LAST, depth=NODE_QOS_DEPTH)
        self.cond = threading.Condition()
        self.single_ids: list[int] = []
        self.batch_replies: list[tuple[float, ForceClosureVerdictArray]] = []
        self.diagnostics: dict[str, str] = {}
        self.single_pub = self.create_publisher(ContactArray, "contacts", qos)
        self.batch_pub = self.create_publisher(ContactArrayBatch, "contacts_batch", qos)
        self.create_subscription(ForceClosureVerdict, "verdicts", self._on_single, qos)
        self.create_subscription(ForceClosureVerdictArray, "verdicts_batch", self._on_batch, qos)
        self.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10)
        self.service = self.create_client(CheckForceClosure, "check_force_closure")
        self.node_name = f"{namespace}/force_closure"

    def _on_single(self, msg):
        with self.cond:
            self.single_ids.append(msg.id)
            self.cond.notify_all()

    def _on_batch(self, msg):
        with self.cond:
            self.batch_replies.append((time.perf_counter(), msg))
            self.cond.notify_all()

    def _on_diagnostics(self, msg):
        for status in msg.status:
            if status.name.startswith(self.node_name + ":"):
                with self.cond:
                    self.diagnostics = {kv.key: kv.value for kv in status.values}
                    self.diagnostics["_stamp"] = time.perf_counter()
                    self.cond.notify_all()

    def wait_connected(self):
        assert self.service.wait_for_service(timeout_sec=CONNECT_TIMEOUT_S), "no node"
        deadline = time.monotonic() + CONNECT_TIMEOUT_S
        while time.monotonic() < deadline:
            if (self.single_pub.get_subscription_count() and self.batch_pub.get_subscription_count()
                    and self.count_publishers("verdicts") and self.count_publishers("verdicts_batch")):
                time.sleep(0.5)
                return
            time.sleep(0.05)
        raise RuntimeError("node topics not matched")

    def fresh_diagnostics(self) -> dict:
        """The node's next /diagnostics values (published once a second)."""
        with self.cond:
            since = time.perf_counter()
            self.cond.wait_for(lambda: self.diagnostics.get("_stamp", 0) > since, 3.0)
            return dict(self.diagnostics)


def time_split(before: dict, after: dict) -> str:
    parts = []
    for key in DIAGNOSTIC_TIMES:
        if key in before and key in after:
            parts.append(f"{key.split('_')[0]} {float(after[key]) - float(before[key]):.3f} s")
    return ", ".join(parts)


def bench_single(client: BenchClient, positions, normals, n_queries: int, window: int):
    msgs = [grasp_to_contact_array(i, positions[i % len(positions)], normals[i % len(normals)])
            for i in range(n_queries)]
    with client.cond:
        client.single_ids.clear()
    start = time.perf_counter()
    for i, msg in enumerate(msgs):
        with client.cond:
            if i - len(client.single_ids) >= window:
                ok = client.cond.wait_for(lambda: i - len(client.single_ids) < window,
                                          REPLY_TIMEOUT_S)
                if not ok:
                    break
        client.single_pub.publish(msg)
    with client.cond:
        client.cond.wait_for(lambda: len(client.single_ids) >= n_queries, REPLY_TIMEOUT_S)
        ids = list(client.single_ids)
    elapsed = time.perf_counter() - start
    lossless = ids == list(range(n_queries))
    return len(ids) / elapsed, lossless, len(ids)


def bench_batches(client: BenchClient, batches, in_flight: int = 2):
    msgs = [grasps_to_batch_msg(np.arange(len(p)) + k * len(p), p, n)
            for k, (p, n) in enumerate(batches)]
    with client.cond:
        client.batch_replies.clear()
    start = time.perf_counter()
    for k, msg in enumerate(msgs):
        with client.cond:
            client.cond.wait_for(lambda: k - len(client.batch_replies) < in_flight,
                                 REPLY_TIMEOUT_S)
        client.batch_pub.publish(msg)
    with client.cond:
        client.cond.wait_for(lambda: len(client.batch_replies) >= len(msgs), REPLY_TIMEOUT_S)
        replies = list(client.batch_replies)
    elapsed = time.perf_counter() - start
    n_grasps = sum(len(p) for p, _ in batches)
    complete = len(replies) == len(msgs) and all(
        len(r.ids) == len(p) for (_, r), (p, _) in zip(replies, batches))
    return n_grasps / elapsed, complete


def bench_core(batches):
    start = time.perf_counter()
    timing = {"filter_s": 0.0, "exact_s": 0.0}
    for p, n in batches:
        result = check_force_closure(p, n, 0.5)
        for key in timing:
            timing[key] += result.timing[key]
    elapsed = time.perf_counter() - start
    return sum(len(p) for p, _ in batches) / elapsed, timing


def bench_service(client: BenchClient, positions, normals, n_calls: int):
    times = []
    for i in range(n_calls):
        request = CheckForceClosure.Request(
            grasps=[grasp_to_contact_array(i, positions[i % len(positions)],
                                           normals[i % len(normals)])])
        done = threading.Event()
        start = time.perf_counter()
        future = client.service.call_async(request)
        future.add_done_callback(lambda _: done.set())
        if not done.wait(REPLY_TIMEOUT_S):
            raise RuntimeError("service call timed out")
        times.append(time.perf_counter() - start)
        assert future.result().verdicts[0].id == i
    times_ms = np.array(times) * 1e3
    return np.percentile(times_ms, 50), np.percentile(times_ms, 99)


def node_command(namespace: str) -> list[str]:
    script = Path(sys.executable).with_name("grasp-fc-node")
    found = str(script) if script.exists() else shutil.which("grasp-fc-node")
    if found is None:
        sys.exit("grasp-fc-node is not installed in this environment (pip install -e .)")
    return [found, "--ros-args", "-r", f"__ns:={namespace}",
            "-p", f"qos_depth:={NODE_QOS_DEPTH}", "--log-level", "warn"]


def verdict(ok: bool) -> str:
    return "meets target" if ok else "BELOW target"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="ROS benchmark of the force_closure node")
    parser.add_argument("--queries", type=int, default=10_000, help="single-grasp topic queries")
    parser.add_argument("--window", type=int, default=500,
                        help="single-grasp queries in flight at most")
    parser.add_argument("--batches", type=int, default=10, help="number of batches")
    parser.add_argument("--batch-size", type=int, default=1000, help="grasps per batch")
    parser.add_argument("--service-calls", type=int, default=500, help="service round trips")
    parser.add_argument("--object", default="box", help="built-in object")
    args = parser.parse_args(argv)

    rng = np.random.default_rng(0)
    surface = make_object(args.object)
    positions, normals = sample_grasps(surface, args.batches * args.batch_size, N_FINGERS, rng)
    batches = [(positions[k * args.batch_size:(k + 1) * args.batch_size],
                normals[k * args.batch_size:(k + 1) * args.batch_size])
               for k in range(args.batches)]

    namespace = f"/grasp_fc_bench_{os.getpid()}"
    node = subprocess.Popen(node_command(namespace))
    rclpy.init()
    client = BenchClient(namespace)
    executor = SingleThreadedExecutor()
    executor.add_node(client)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        client.wait_connected()
        print(f"object {args.object}, {N_FINGERS}-finger random grasps; node in a separate "
              f"process, reliable QoS; {os.cpu_count()} CPUs")

        d0 = client.fresh_diagnostics()
        rate, lossless, received = bench_single(client, positions, normals, args.queries,
                                                args.window)
        d1 = client.fresh_diagnostics()
        print(f"single-grasp topic: {rate:8.0f} queries/s over {args.queries} queries, "
              f"{'no loss, in order' if lossless else f'LOSS: {received} received'}  "
              f"[target >= {TARGET_SINGLE_PER_S}/s: {verdict(lossless and rate >= TARGET_SINGLE_PER_S)}]")
        print(f"    node time: {time_split(d0, d1)}")

        # Core alone before and after the ROS run, averaged: the machine's load drifts.
        core_before, _ = bench_core(batches)
        d1 = client.fresh_diagnostics()
        ros_rate, complete = bench_batches(client, batches)
        d2 = client.fresh_diagnostics()
        core_after, core_timing = bench_core(batches)
        core_rate = 0.5 * (core_before + core_after)
        overhead = 1.0 - ros_rate / core_rate
        print(f"batches of {args.batch_size}: {ros_rate:8.0f} grasps/s through ROS, "
              f"{core_rate:8.0f} grasps/s core alone (mean of {core_before:.0f}, {core_after:.0f}) -> ROS overhead {100 * overhead:.1f}%"
              f"{'' if complete else ' (INCOMPLETE replies)'}  "
              f"[target <= {100 * TARGET_OVERHEAD:.0f}%: {verdict(complete and overhead <= TARGET_OVERHEAD)}]")
        print(f"    node time: {time_split(d1, d2)}; core alone (last run): filter "
              f"{core_timing['filter_s']:.3f} s, exact {core_timing['exact_s']:.3f} s")
        build = time.perf_counter()
        for p, n in batches:
            grasps_to_batch_msg(np.arange(len(p)), p, n)
        print(f"    client-side packing of all batches: {time.perf_counter() - build:.3f} s")

        p50, p99 = bench_service(client, positions, normals, args.service_calls)
        d3 = client.fresh_diagnostics()
        print(f"service round trip (one grasp): p50 {p50:.2f} ms, p99 {p99:.2f} ms over "
              f"{args.service_calls} calls  [target p50 <= {TARGET_SERVICE_P50_MS} ms: "
              f"{verdict(p50 <= TARGET_SERVICE_P50_MS)}]")
        print(f"    node time: {time_split(d2, d3)}")
        # The same round trip without core work (an invalid one-contact grasp): the
        # part of the above that is ROS, messages and the node's Python.
        q50, q99 = bench_service(client, positions[:, :1], normals[:, :1], args.service_calls)
        print(f"service round trip, no core work (invalid query): p50 {q50:.2f} ms, "
              f"p99 {q99:.2f} ms")
        return 0
    finally:
        executor.shutdown()
        spinner.join()
        client.destroy_node()
        rclpy.try_shutdown()
        node.send_signal(signal.SIGINT)
        try:
            node.wait(timeout=10)
        except subprocess.TimeoutExpired:
            node.kill()


if __name__ == "__main__":
    sys.exit(main())
