"""grasp-fc-demo: the force_closure node answering a stream of random grasps.

The demo starts the node *in this process*, spun by its own executor on a separate
thread, with its ``publish_markers`` parameter on, and a client node that sends random
6-finger grasps on a built-in object to it: a few single-grasp ``ContactArray``
queries on ``contacts``, then the rest through the ``label_grasps`` action (jobs of
:data:`GOAL_GRASPS` at most), with a progress bar fed by the action's feedback (Ctrl-C
cancels the job and keeps the verdicts decided so far), and one service call. The
table counts both parts (the bar only the second). Every
message still goes through DDS (serialised, delivered, deserialised); only the process
is shared, which keeps start-up fast and needs no discovery of a second process. Both
nodes live in a namespace of their own (``/grasp_fc_demo_<pid>``) so a node started
elsewhere with ``grasp-fc-node`` cannot answer the demo's queries. At the end it writes a PNG of the
RViz markers of one grasp per verdict (:mod:`grasp_fc_ros.markers.render`).

Usage::

    grasp-fc-demo [--grasps N] [--object NAME] [--seed S] [--markers-png PATH]

``GRASP_FC_DEMO_GRASPS`` and ``GRASP_FC_DEMO_OBJECT`` set the defaults.
Exit code 0 when every query got its verdict.
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from collections.abc import Sequence
from concurrent.futures import TimeoutError as FutureTimeout

import numpy as np
import rclpy
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.parameter import Parameter

from grasp_fc_ros.client import GraspClient
from grasp_fc_ros.core import Status, check_force_closure
from grasp_fc_ros.interface.names import NODE_NAME
from grasp_fc_ros.node import ForceClosureNode, shutdown_rclpy
from grasp_fc_ros.objects import OBJECT_NAMES, ContactSurface, make_object, sample_grasps

N_FINGERS = 6
SINGLE_QUERIES = 20
# Grasps per label_grasps job (one progress bar, one REPLY_TIMEOUT_S each); more grasps
# go as several jobs, one after the other. The client sends each job as goals of at
# most MAX_MESSAGE_CONTACTS contacts.
GOAL_GRASPS = 100_000
# The node's default friction, which the demo's grasps use (for the PNG's certificates).
DEMO_MU = 0.5
DEFAULT_MARKERS_PNG = "demo_out/markers.png"
CONNECT_TIMEOUT_S = 20.0
REPLY_TIMEOUT_S = 120.0


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
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
    parser.add_argument("--markers-png", default=DEFAULT_MARKERS_PNG,
                        help="where to write the PNG of a few grasps' markers (default "
                             f"{DEFAULT_MARKERS_PNG}; its folder is created)")
    args = parser.parse_args(argv)
    if args.grasps < 1:
        parser.error("--grasps must be >= 1")
    return args


def _table(status: np.ndarray, elapsed_s: float, object_name: str, n_single: int) -> str:
    """The verdicts' counts: ``n_single`` single queries first, then the label_grasps
    job (the progress bar's total), adding up to the queries."""
    counts = np.bincount(status, minlength=len(Status))
    rows = [
        ("object", object_name),
        ("single queries (contacts)", f"{n_single}"),
        ("label_grasps (progress bar)", f"{len(status) - n_single}"),
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


def run(args: argparse.Namespace) -> int:
    """Stream the grasps to the node through a GraspClient; print the table."""
    node_name = args.node_name
    fc_node: ForceClosureNode | None = None
    spinner: SingleThreadedExecutor | None = None
    if node_name is None:
        namespace = f"/grasp_fc_demo_{os.getpid()}"
        # A node without the parameter warns that it ignores it; the demo goes on.
        fc_node = ForceClosureNode(namespace=namespace, parameter_overrides=[
            Parameter("publish_markers", value=True)])
        spinner = SingleThreadedExecutor()
        spinner.add_node(fc_node)
        threading.Thread(target=_spin_quietly, args=(spinner,), daemon=True).start()
        node_name = f"{namespace}/{NODE_NAME}"
    print(_markers_note(fc_node, node_name))
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
        if fc_node is not None:
            fc_node.destroy_node()


def _markers_note(fc_node: ForceClosureNode | None, node_name: str) -> str:
    """Where the node's RViz markers go, as far as the demo can tell."""
    topic = node_name.rsplit("/", 1)[0] + "/markers"
    if fc_node is None:
        return (f"markers: on {topic} when that node's publish_markers parameter is on "
                "(visualization_msgs/MarkerArray, for RViz)")
    if fc_node.has_parameter("publish_markers") and fc_node.get_parameter(
            "publish_markers").value:
        return (f"markers: published on {topic} (publish_markers is on; "
                "visualization_msgs/MarkerArray, for RViz)")
    return "markers: none published (this node has no publish_markers parameter)"


def _stream(client: GraspClient, args: argparse.Namespace, node_name: str) -> int:
    surface = make_object(args.object)
    positions, normals = sample_grasps(surface, args.grasps, N_FINGERS,
                                       np.random.default_rng(args.seed))
    print(f"{args.grasps} random {N_FINGERS}-finger grasps on '{args.object}' -> node "
          f"{node_name}", flush=True)
    start = time.perf_counter()
    n_single = min(SINGLE_QUERIES, args.grasps)
    if args.grasps > n_single:
        jobs = ("a label_grasps job (its progress bar)" if args.grasps - n_single <= GOAL_GRASPS
                else f"label_grasps jobs of {GOAL_GRASPS} (a progress bar each)")
        print(f"the first {n_single} as single queries on contacts, the other "
              f"{args.grasps - n_single} as {jobs}:", flush=True)
    futures = [client.submit(positions[i], normals[i], query_id=i) for i in range(n_single)]
    single = [f.result(REPLY_TIMEOUT_S) for f in futures]
    statuses = np.array([v.status for v in single], dtype=np.uint8)
    margins = np.array([v.margin for v in single], dtype=np.float64)
    complete = True
    for first in range(n_single, args.grasps, GOAL_GRASPS):
        ids = np.arange(first, min(first + GOAL_GRASPS, args.grasps))
        verdicts = client.label_grasps(positions[ids], normals[ids], ids=ids,
                                       timeout=REPLY_TIMEOUT_S)
        if not np.array_equal(verdicts.ids, ids[:len(verdicts)]):
            print("a label_grasps job came back with other ids", file=sys.stderr)
            return 1
        statuses = np.concatenate([statuses, verdicts.status])
        margins = np.concatenate([margins, verdicts.margin])
        complete = len(verdicts) == len(ids)
        if not complete:
            break  # Ctrl-C cancelled the job
    elapsed = time.perf_counter() - start
    served = client.call(positions[:1], normals[:1], timeout=REPLY_TIMEOUT_S)
    if served.status[0] != statuses[0]:
        print("the service and the topic disagree on grasp 0", file=sys.stderr)
        return 1
    print(_table(statuses, elapsed, args.object, n_single))
    _write_markers_png(args.markers_png, surface, positions[:len(statuses)],
                       normals[:len(statuses)], statuses, margins)
    if not complete:
        print(f"interrupted: {len(statuses)} of {args.grasps} grasps decided",
              file=sys.stderr)
        return 130
    return 0


def _write_markers_png(path: str, surface: ContactSurface, positions: np.ndarray,
                       normals: np.ndarray, status: np.ndarray, margin: np.ndarray) -> None:
    """Draw the markers of the first grasp of each verdict to ``path``; say where.

    Separating wrenches come from the core on those few grasps (the node sends them
    only with its ``certificates`` parameter on), drawn where the core agrees with
    the node's verdict.
    """
    from grasp_fc_ros.markers.render import EXAMPLE_STATUSES, render_verdict_examples

    chosen = [int(np.flatnonzero(status == s)[0]) for s in EXAMPLE_STATUSES
              if np.any(status == s)]
    if not chosen:
        print("markers PNG: no grasp with a drawable verdict")
        return
    local = check_force_closure(positions[chosen], normals[chosen], DEMO_MU,
                                certificates=True)
    assert local.separating_wrench is not None  # certificates=True
    wrench = np.where((local.status == status[chosen])[:, None], local.separating_wrench,
                      np.nan)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    render_verdict_examples(path, positions[chosen], normals[chosen], DEMO_MU,
                            status[chosen], margin[chosen], ids=np.array(chosen),
                            separating_wrench=wrench, frame_id=surface.name,
                            cloud=surface.points[::4])
    print(f"markers PNG: {len(chosen)} grasps (one per verdict) drawn from their RViz "
          f"markers to {os.path.abspath(path)}")


def _spin_quietly(executor: Executor) -> None:
    try:
        executor.spin()
    except (ExternalShutdownException, RuntimeError):
        pass  # shut down while spinning


def main(argv: Sequence[str] | None = None) -> int:
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
