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
from concurrent.futures import TimeoutError as FutureTimeout

import numpy as np
import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

from grasp_fc_ros.client import GraspClient
from grasp_fc_ros.core import Status
from grasp_fc_ros.node import NODE_NAME, ForceClosureNode, shutdown_rclpy
from grasp_fc_ros.objects import OBJECT_NAMES, make_object, sample_grasps

N_FINGERS = 6
BATCH_SIZE = 250
SINGLE_QUERIES = 20
CONNECT_TIMEOUT_S = 20.0
REPLY_TIMEOUT_S = 120.0


def parse_args(argv=None):
    parser = argparse.ArgumentParser(prog="grasp-fc-demo", description=__doc__.split("\n")[0])
    parser.add_argument("--grasps", type=int,
                        default=int(os.environ.get("GRASP_FC_DEMO_GRASPS", "2000")),
                        help="number of random grasps (env GRASP_FC_DEMO_GRASPS; default 2000)")
    parser.add_argument("--object", choices=OBJECT_NAMES,
                        default=os.environ.get("GRASP_FC_DEMO_OBJECT", "box"),
                        help="built-in object (env GRASP_FC_DEMO_OBJECT; default box)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--node-name", default=None,
                        help="drive this running node (e.g. force_closure or "
                             "/robot/force_closure) instead of starting one in-process")
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
    """Stream the grasps to the node through a GraspClient; print the table."""
    node_name = args.node_name
    fc_node = spinner = None
    if node_name is None:
        namespace = f"/grasp_fc_demo_{os.getpid()}"
        fc_node = ForceClosureNode(namespace=namespace)
        spinner = SingleThreadedExecutor()
        spinner.add_node(fc_node)
        threading.Thread(target=_spin_quietly, args=(spinner,), daemon=True).start()
        node_name = f"{namespace}/{NODE_NAME}"
    client = GraspClient(node_name)
    try:
        if not client.wait_for_node(CONNECT_TIMEOUT_S):
            print(f"demo client could not reach the node {node_name}", file=sys.stderr)
            return 1
        return _stream(client, args, node_name)
    except (TimeoutError, FutureTimeout):
        print(f"\nno verdicts from {node_name} within {REPLY_TIMEOUT_S:.0f} s", file=sys.stderr)
        return 1
    finally:
        client.close()
        if spinner is not None:
            # Stop spinning before the node goes away: destroying a node that an
            # executor thread is still waiting on aborts the process.
            spinner.shutdown()
            fc_node.destroy_node()


def _stream(client: GraspClient, args, node_name: str) -> int:
    surface = make_object(args.object)
    positions, normals = sample_grasps(surface, args.grasps, N_FINGERS,
                                       np.random.default_rng(args.seed))
    print(f"{args.grasps} random {N_FINGERS}-finger grasps on '{args.object}' -> node "
          f"{node_name}")
    start = time.perf_counter()
    n_single = min(SINGLE_QUERIES, args.grasps)
    futures = [client.submit(positions[i], normals[i], query_id=i) for i in range(n_single)]
    single = [f.result(REPLY_TIMEOUT_S) for f in futures]
    statuses = [np.array([v.status for v in single], dtype=np.uint8)]
    _progress(n_single, args.grasps, start)
    for first in range(n_single, args.grasps, BATCH_SIZE):
        ids = np.arange(first, min(first + BATCH_SIZE, args.grasps))
        verdicts = client.check_batch(positions[ids], normals[ids], ids=ids,
                                      timeout=REPLY_TIMEOUT_S)
        if not np.array_equal(verdicts.ids, ids):
            print(f"\nbatch starting at grasp {first} came back with other ids",
                  file=sys.stderr)
            return 1
        statuses.append(verdicts.status)
        _progress(ids[-1] + 1, args.grasps, start)
    elapsed = time.perf_counter() - start
    if sys.stdout.isatty():
        print()
    served = client.call(positions[:1], normals[:1], timeout=REPLY_TIMEOUT_S)
    if served.status[0] != statuses[0][0]:
        print("\nthe service and the topic disagree on grasp 0", file=sys.stderr)
        return 1
    print(_table(np.concatenate(statuses), elapsed, args.object))
    return 0


def _spin_quietly(executor):
    try:
        executor.spin()
    except (ExternalShutdownException, RuntimeError):
        pass  # shut down while spinning


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
