"""grasp-fc-demo: the force_closure node answering a stream of random grasps.

The demo starts the node *in this process*, spun by its own executor on a separate
thread, and a client node that streams random 6-finger grasps on a built-in object
to it through the node's topics: packed ``ContactArrayBatch`` messages on
``contacts_batch``, plus a few single-grasp ``ContactArray`` queries on ``contacts``.
Every message still goes through DDS (serialised, delivered, deserialised); only the
process is shared, which keeps start-up fast and needs no discovery of a second
process. Both nodes live in a namespace of their own (``/grasp_fc_demo_<pid>``) so a
node started elsewhere with ``grasp-fc-node`` cannot answer the demo's queries.

Usage::

    grasp-fc-demo [--grasps N] [--object NAME] [--seed S]

``GRASP_FC_DEMO_GRASPS`` and ``GRASP_FC_DEMO_OBJECT`` set the defaults.
Exit code 0 when every query got its verdict.
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time

import numpy as np
import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from grasp_fc_msgs.msg import (
    ContactArray,
    ContactArrayBatch,
    ForceClosureVerdict,
    ForceClosureVerdictArray,
)
from grasp_fc_ros.conversions import (
    grasp_to_contact_array,
    grasps_to_batch_msg,
    verdict_array_to_numpy,
)
from grasp_fc_ros.core import Status
from grasp_fc_ros.node import ForceClosureNode, shutdown_rclpy
from grasp_fc_ros.objects import OBJECT_NAMES, make_object, sample_grasps

N_FINGERS = 6
BATCH_SIZE = 250
SINGLE_QUERIES = 20
CONNECT_TIMEOUT_S = 10.0
REPLY_TIMEOUT_S = 60.0
QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                 depth=100)


class DemoClient(Node):
    """Sends grasp queries and collects the node's verdicts."""

    def __init__(self, namespace: str):
        super().__init__("grasp_fc_demo_client", namespace=namespace)
        self._replies = threading.Condition()
        self._batches: dict[str, ForceClosureVerdictArray] = {}
        self._singles: list[ForceClosureVerdict] = []
        self.batch_pub = self.create_publisher(ContactArrayBatch, "contacts_batch", QOS)
        self.single_pub = self.create_publisher(ContactArray, "contacts", QOS)
        self.create_subscription(ForceClosureVerdictArray, "verdicts_batch", self._on_batch, QOS)
        self.create_subscription(ForceClosureVerdict, "verdicts", self._on_single, QOS)

    def _on_batch(self, msg):
        with self._replies:
            self._batches[msg.header.frame_id] = msg
            self._replies.notify_all()

    def _on_single(self, msg):
        with self._replies:
            self._singles.append(msg)
            self._replies.notify_all()

    def wait_connected(self) -> bool:
        deadline = time.monotonic() + CONNECT_TIMEOUT_S
        while time.monotonic() < deadline:
            if (self.batch_pub.get_subscription_count() and self.single_pub.get_subscription_count()
                    and self.count_publishers("verdicts_batch")
                    and self.count_publishers("verdicts")):
                return True
            time.sleep(0.02)
        return False

    def ask_batch(self, tag: str, ids, positions, normals):
        """Publish one batch and wait for its verdicts (None on timeout)."""
        msg = grasps_to_batch_msg(ids, positions, normals)
        msg.header.frame_id = tag
        msg.header.stamp = self.get_clock().now().to_msg()
        self.batch_pub.publish(msg)
        with self._replies:
            if not self._replies.wait_for(lambda: tag in self._batches, REPLY_TIMEOUT_S):
                return None
            return verdict_array_to_numpy(self._batches.pop(tag))

    def ask_singles(self, ids, positions, normals):
        """Publish single-grasp queries; return their verdicts as arrays (None on timeout)."""
        for i, p, n in zip(ids, positions, normals):
            self.single_pub.publish(grasp_to_contact_array(i, p, n))
        with self._replies:
            if not self._replies.wait_for(lambda: len(self._singles) >= len(ids), REPLY_TIMEOUT_S):
                return None
            replies, self._singles = self._singles, []
        if [r.id for r in replies] != list(ids):
            return None
        return np.array([r.status for r in replies], dtype=np.uint8)


def parse_args(argv=None):
    parser = argparse.ArgumentParser(prog="grasp-fc-demo", description=__doc__.split("\n")[0])
    parser.add_argument("--grasps", type=int,
                        default=int(os.environ.get("GRASP_FC_DEMO_GRASPS", "2000")),
                        help="number of random grasps (env GRASP_FC_DEMO_GRASPS; default 2000)")
    parser.add_argument("--object", choices=OBJECT_NAMES,
                        default=os.environ.get("GRASP_FC_DEMO_OBJECT", "box"),
                        help="built-in object (env GRASP_FC_DEMO_OBJECT; default box)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    args = parser.parse_args(argv)
    if args.grasps < 1:
        parser.error("--grasps must be >= 1")
    return args


def _progress(done: int, total: int, start: float):
    rate = done / max(time.perf_counter() - start, 1e-9)
    line = f"  {done:>7}/{total} grasps  {100 * done / total:5.1f}%  {rate:8.0f} grasps/s"
    if sys.stdout.isatty():
        print("\r" + line, end="", flush=True)
    else:
        print(line, flush=True)


def _table(status: np.ndarray, elapsed_s: float, object_name: str) -> str:
    counts = np.bincount(status, minlength=len(Status))
    rows = [
        ("object", object_name),
        ("queries", f"{len(status)}"),
        ("force closure", f"{counts[Status.FORCE_CLOSURE]}"),
        ("rejected by the filter", f"{counts[Status.FILTERED_OUT]}"),
        ("decided by the exact test",
         f"{counts[Status.FORCE_CLOSURE] + counts[Status.NOT_FORCE_CLOSURE]}"),
        ("invalid input", f"{counts[Status.INVALID_INPUT]}"),
        ("solver failures", f"{counts[Status.SOLVER_FAILURE]}"),
        ("elapsed", f"{elapsed_s:.2f} s"),
        ("throughput", f"{len(status) / elapsed_s:.0f} grasps/s"),
    ]
    width = max(len(name) for name, _ in rows)
    return "\n".join(f"  {name:<{width}}  {value:>12}" for name, value in rows)


def run(args) -> int:
    namespace = f"/grasp_fc_demo_{os.getpid()}"
    fc_node = ForceClosureNode(namespace=namespace)
    client = DemoClient(namespace)
    spinners = []
    for node in (fc_node, client):
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        thread = threading.Thread(target=_spin_quietly, args=(executor,), daemon=True)
        thread.start()
        spinners.append((executor, thread))
    try:
        if not client.wait_connected():
            print("demo client could not reach the node", file=sys.stderr)
            return 1
        surface = make_object(args.object)
        positions, normals = sample_grasps(surface, args.grasps, N_FINGERS,
                                           np.random.default_rng(args.seed))
        print(f"{args.grasps} random {N_FINGERS}-finger grasps on '{args.object}' -> "
              f"node {fc_node.get_fully_qualified_name()}")
        start = time.perf_counter()
        n_single = min(SINGLE_QUERIES, args.grasps)
        single = client.ask_singles(range(n_single), positions[:n_single], normals[:n_single])
        if single is None:
            print("\nsingle-grasp queries were not all answered in order", file=sys.stderr)
            return 1
        statuses = [single]
        _progress(n_single, args.grasps, start)
        for first in range(n_single, args.grasps, BATCH_SIZE):
            ids = np.arange(first, min(first + BATCH_SIZE, args.grasps))
            verdicts = client.ask_batch(f"batch-{first}", ids, positions[ids], normals[ids])
            if verdicts is None or not np.array_equal(verdicts.ids, ids):
                print(f"\nbatch starting at grasp {first} was not answered", file=sys.stderr)
                return 1
            statuses.append(verdicts.status)
            _progress(ids[-1] + 1, args.grasps, start)
        elapsed = time.perf_counter() - start
        if sys.stdout.isatty():
            print()
        print(_table(np.concatenate(statuses), elapsed, args.object))
        return 0
    finally:
        # Stop spinning before the nodes go away: destroying a node that an executor
        # thread is still waiting on aborts the process.
        for executor, thread in spinners:
            executor.shutdown()
            thread.join()
        client.destroy_node()
        fc_node.destroy_node()


def _spin_quietly(executor):
    try:
        executor.spin()
    except ExternalShutdownException:
        pass


def main(argv=None) -> int:
    args = parse_args(argv)
    rclpy.init()
    try:
        return run(args)
    except (KeyboardInterrupt, ExternalShutdownException):
        print("\ninterrupted", file=sys.stderr)
        return 130
    finally:
        shutdown_rclpy()


if __name__ == "__main__":
    sys.exit(main())
