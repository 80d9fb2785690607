"""Cost of markers: building them next to the core, and the node's latency with them.

1. Building one answered query's markers next to deciding it with the core: random
   6-finger grasps on the built-in box; each figure is the median over 7 rounds of 100
   calls, the three measurements interleaved so that a change of machine load hits all
   of them alike. Prints milliseconds per call and the ratio markers / core.
2. The node (grasp-fc-node in its own process, namespace of its own, default
   parameters) with ``publish_markers`` off and on: round trips of one 6-finger query
   at a time, on the ``contacts`` topic (GraspClient.submit) and the service; rounds of
   ``--queries`` round trips alternate off, on, off, on ... (the parameter is set at
   run time), so both see the same machine load. A subscriber in a process of its own
   receives the markers (serialized, as RViz's C++ would cheaply) and counts them. Prints
   p50/p99 per setting and the ratio of the p50s (the issue's target: on <= 1.1 x off).
3. Markers from ``grasp-fc-node`` started with ``publish_markers:=true`` as a user does
   (its marker process starts with the node; issue 28: it never published): one-grasp
   service calls, each followed by the arrival of its markers at a viewer in this
   process; the seconds from the answer to the markers, in the default environment and
   with a user's own Fast DDS profiles file (target: within 1 s).

    .venv/bin/python benchmarks/bench_markers.py [--queries 200] [--rounds 6]
    .venv/bin/python benchmarks/bench_markers.py --no-node     # only 1.
    .venv/bin/python benchmarks/bench_markers.py --latency-calls 100
    .venv/bin/python benchmarks/bench_markers.py --quick       # the smoke test's form
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from grasp_fc_ros.core import check_force_closure
from grasp_fc_ros.markers.build import grasp_markers
from grasp_fc_ros.objects import make_object, sample_grasps
from timing import ratio_or_nan

if TYPE_CHECKING:
    from rclpy.node import Node
    from rclpy.parameter_client import AsyncParameterClient
    from visualization_msgs.msg import MarkerArray

CALLS, ROUNDS, FINGERS = 100, 7, 6
# The target: markers on add at most 10 % to the single-query latency.
TARGET_RATIO = 1.10
REPLY_TIMEOUT_S = 30.0
# Issue 28's target: a service request's markers within 1 s of its answer.
TARGET_LATENCY_S = 1.0
LATENCY_CALLS = 50


def per_call_s(f: Callable[[int], object]) -> float:
    start = time.perf_counter()
    for i in range(CALLS):
        f(i)
    return (time.perf_counter() - start) / CALLS


def bench_build() -> None:
    """1.: markers against the core, in this process."""
    p, n = sample_grasps(make_object("box"), CALLS, FINGERS, np.random.default_rng(0))
    cases: dict[str, Callable[[int], object]] = {
        "core (check_force_closure)": lambda i: check_force_closure(p[i], n[i], 0.5),
        "markers, 12 segments": lambda i: grasp_markers(
            p[i], n[i], 0.5, 0, query_id=i, frame_id="f", margin=0.01),
        "markers, 8 segments": lambda i: grasp_markers(
            p[i], n[i], 0.5, 0, query_id=i, frame_id="f", margin=0.01, cone_segments=8),
    }
    runs: dict[str, list[float]] = {name: [] for name in cases}
    for _ in range(ROUNDS):
        for name, f in cases.items():
            runs[name].append(per_call_s(f))
    medians = {name: statistics.median(v) for name, v in runs.items()}
    core = medians["core (check_force_closure)"]
    for name, seconds in medians.items():
        print(f"{name:28s} {seconds * 1e3:8.3f} ms   {seconds / core:5.2f} x core")


def listen(topic: str) -> int:
    """--listen: subscribe to ``topic`` as RViz would; at SIGINT print the arrays counted.

    Run as a process of its own, so that receiving the markers costs the measuring
    client nothing (RViz is a process of its own too). It takes the serialized messages
    (``raw=True``): RViz deserializes in C++, far cheaper than rclpy's Python messages.
    """
    import rclpy
    from visualization_msgs.msg import MarkerArray

    from grasp_fc_ros.markers.publisher import MARKER_QOS

    rclpy.init()
    node = rclpy.create_node("bench_markers_listener")
    count = [0]
    node.create_subscription(MarkerArray, topic, lambda _: count.__setitem__(0, count[0] + 1),
                             MARKER_QOS, raw=True)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        pass
    print(count[0], flush=True)
    return 0


def set_markers(parameters: AsyncParameterClient, on: bool) -> None:
    """Set the node's publish_markers through its parameter service."""
    from rclpy.parameter import Parameter

    future = parameters.set_parameters([Parameter("publish_markers", value=on)])
    done = threading.Event()
    future.add_done_callback(lambda _: done.set())
    if not done.wait(REPLY_TIMEOUT_S) or not future.result().results[0].successful:
        raise RuntimeError(f"could not set publish_markers to {on}")


def cpu_s(pid: int) -> float:
    """CPU seconds (user + system) used so far by process ``pid`` alone (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def marker_process_pid(node_pid: int) -> int | None:
    """The pid of the node's marker process, if it runs."""
    from bench_ros import process_tree

    for pid in process_tree(node_pid):
        try:
            if "grasp_fc_ros.markers.publisher" in Path(f"/proc/{pid}/cmdline").read_text():
                return pid
        except OSError:
            continue
    return None


def round_trips_ms(send: Callable[[int], object], n: int, first_id: int) -> list[float]:
    times = []
    for i in range(first_id, first_id + n):
        start = time.perf_counter()
        send(i)
        times.append((time.perf_counter() - start) * 1e3)
    return times


def bench_node(queries: int, rounds: int) -> None:
    """2.: one-query round trips through the node with publish_markers off and on."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter_client import AsyncParameterClient

    from bench_ros import start_node, stop_node

    p, n = sample_grasps(make_object("box"), 1000, FINGERS, np.random.default_rng(1))
    rclpy.init()
    node, client = start_node("markers")
    helper = rclpy.create_node("bench_markers_helper")
    executor = SingleThreadedExecutor()
    executor.add_node(helper)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    listener: subprocess.Popen | None = None
    try:
        namespace = f"/grasp_fc_markers_{os.getpid()}"  # as bench_ros.start_node names it
        listener = subprocess.Popen([sys.executable, __file__, "--listen",
                                     f"{namespace}/markers"], stdout=subprocess.PIPE, text=True)
        parameters = AsyncParameterClient(helper, f"{namespace}/force_closure")
        if not parameters.wait_for_services(REPLY_TIMEOUT_S):
            raise RuntimeError("parameter services of the node not found")
        k = lambda i: i % len(p)  # noqa: E731
        interfaces = {
            "topic": lambda i: client.submit(p[k(i)], n[k(i)], query_id=i).result(
                REPLY_TIMEOUT_S),
            "service": lambda i: client.call(p[k(i):k(i) + 1], n[k(i):k(i) + 1], ids=[i],
                                             timeout=REPLY_TIMEOUT_S),
        }
        times: dict[tuple[str, bool], list[float]] = {
            (kind, on): [] for kind in interfaces for on in (False, True)}
        next_id = 0
        for send in interfaces.values():  # warm-up: discovery, first calls
            round_trips_ms(send, 50, next_id)
            next_id += 50
        deadline = time.monotonic() + REPLY_TIMEOUT_S
        while helper.count_subscribers(f"{namespace}/markers") == 0:
            if time.monotonic() > deadline:
                raise RuntimeError("the marker listener did not come up")
            time.sleep(0.1)
        time.sleep(0.5)  # and let the node's publisher match it
        # CPU seconds of the node's own process and of the marker process, per setting:
        # unlike latencies these hardly depend on what else the machine runs.
        node_cpu = {False: 0.0, True: 0.0}
        marker_cpu = 0.0
        for r in range(rounds):
            on = r % 2 == 1
            set_markers(parameters, on)
            time.sleep(0.5)  # the marker process starts (first time) and goes idle
            marker_pid = marker_process_pid(node.pid)
            cpu_before = cpu_s(node.pid), cpu_s(marker_pid) if marker_pid else 0.0
            for interface, send in interfaces.items():
                times[(interface, on)] += round_trips_ms(send, queries, next_id)
                next_id += queries
            time.sleep(0.5)  # let the marker process finish this round's work
            node_cpu[on] += cpu_s(node.pid) - cpu_before[0]
            if on and marker_pid:
                marker_cpu += cpu_s(marker_pid) - cpu_before[1]
        set_markers(parameters, False)
        time.sleep(1.0)
        listener.send_signal(signal.SIGINT)
        received = int(listener.communicate(timeout=REPLY_TIMEOUT_S)[0].split()[-1])
        diagnostics = client.next_diagnostics()
        print(f"node: one 6-finger query at a time, {rounds} rounds of {queries} per "
              f"interface, publish_markers off/on alternating (shared, noisy machine)")
        for interface in interfaces:
            off_ms, on_ms = (np.array(times[(interface, s)]) for s in (False, True))
            ratio = np.median(on_ms) / np.median(off_ms)
            print(f"  {interface:8s} off: p50 {np.median(off_ms):6.3f} ms  p99 "
                  f"{np.percentile(off_ms, 99):6.3f} ms | on: p50 {np.median(on_ms):6.3f} ms  p99 "
                  f"{np.percentile(on_ms, 99):6.3f} ms | on/off p50 {ratio:5.3f}  [target <= "
                  f"{TARGET_RATIO:.2f}: {'met' if ratio <= TARGET_RATIO else 'NOT met'}]")
        sent_on = sum(len(times[(i, True)]) for i in interfaces)
        sent_off = sum(len(times[(i, False)]) for i in interfaces)
        print(f"  CPU per query: node process off {1e3 * node_cpu[False] / sent_off:.3f} ms, "
              f"on {1e3 * node_cpu[True] / sent_on:.3f} ms (ratio "
              f"{ratio_or_nan(node_cpu[True] / sent_on, node_cpu[False] / sent_off):.2f}); marker "
              f"process {1e3 * marker_cpu / sent_on:.3f} ms per query answered with markers on")
        print(f"  marker arrays received by a listener process {received} for {sent_on} "
              f"queries answered with "
              f"markers on; node: markers_published {diagnostics.get('markers_published')}, "
              f"markers_dropped {diagnostics.get('markers_dropped')}")
    finally:
        if listener is not None and listener.poll() is None:
            listener.kill()
        executor.shutdown()
        helper.destroy_node()
        stop_node(node, client)
        rclpy.try_shutdown()


class MarkerArrivals:
    """When the markers of each query id arrived at a viewer in this process."""

    def __init__(self, node: Node, topic: str):
        from visualization_msgs.msg import MarkerArray

        from grasp_fc_ros.markers.publisher import MARKER_QOS

        self._lock = threading.Condition()
        self.at: dict[str, float] = {}
        self.subscription = node.create_subscription(MarkerArray, topic, self._on_array,
                                                     MARKER_QOS)

    def _on_array(self, msg: MarkerArray) -> None:
        now = time.perf_counter()
        with self._lock:
            for marker in msg.markers:
                self.at.setdefault(marker.ns, now)
            self._lock.notify_all()

    def wait(self, namespace: str, timeout_s: float) -> float | None:
        with self._lock:
            self._lock.wait_for(lambda: namespace in self.at, timeout_s)
            return self.at.get(namespace)


def markers_latency_s(env: dict[str, str], calls: int) -> list[float | None]:
    """3., one environment: per service call, seconds from its answer to its markers
    (None: none within REPLY_TIMEOUT_S)."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from bench_ros import start_node, stop_node
    from grasp_fc_ros.markers.build import marker_namespace

    p, n = sample_grasps(make_object("box"), calls, FINGERS, np.random.default_rng(2))
    node, client = start_node("markers_latency", ["-p", "publish_markers:=true"], env=env)
    viewer = rclpy.create_node("bench_markers_viewer")
    arrivals = MarkerArrivals(viewer, f"/grasp_fc_markers_latency_{os.getpid()}/markers")
    executor = SingleThreadedExecutor()
    executor.add_node(viewer)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        deadline = time.monotonic() + REPLY_TIMEOUT_S
        while arrivals.subscription.get_publisher_count() == 0:  # the marker process
            if time.monotonic() > deadline:
                raise RuntimeError("the marker process's publisher never matched")
            time.sleep(0.05)
        time.sleep(0.5)  # matching is not symmetric in time: let the publisher match too
        latencies: list[float | None] = []
        for i in range(calls):
            client.call(p[i:i + 1], n[i:i + 1], ids=[i], timeout=REPLY_TIMEOUT_S)
            answered = time.perf_counter()
            arrived = arrivals.wait(marker_namespace(i), REPLY_TIMEOUT_S)
            latencies.append(None if arrived is None else max(0.0, arrived - answered))
        return latencies
    finally:
        executor.shutdown()
        viewer.destroy_node()
        stop_node(node, client)


def bench_latency(calls: int) -> None:
    """3.: markers after a service answer from grasp-fc-node started with them on."""
    import tempfile

    import rclpy

    from grasp_fc_ros.node.dds_profile import READER_PROFILE

    print(f"markers from grasp-fc-node started with publish_markers:=true, {calls} one-grasp "
          "service calls, seconds from each answer to its markers at a viewer")
    rclpy.init()
    try:
        with tempfile.TemporaryDirectory() as folder:
            # A valid profiles file of the user's (the node's own profile as its text:
            # what matters is that the user set it; the node then leaves it alone).
            profiles = Path(folder) / "my_profiles.xml"
            profiles.write_text(READER_PROFILE)
            environments = {
                "default environment": {},
                "a user's profiles file": {"FASTRTPS_DEFAULT_PROFILES_FILE": str(profiles)}}
            for setting, extra in environments.items():
                env = {name: value for name, value in os.environ.items()
                       if name not in ("FASTRTPS_DEFAULT_PROFILES_FILE",
                                       "FASTDDS_DEFAULT_PROFILES_FILE")}
                latencies = markers_latency_s({**env, **extra}, calls)
                arrived = np.array([t for t in latencies if t is not None]) * 1e3
                ok = len(arrived) == calls and arrived.max() <= TARGET_LATENCY_S * 1e3
                print(f"  {setting + ':':24s} {len(arrived)} of {calls} arrived; p50 "
                      f"{np.median(arrived) if len(arrived) else float('nan'):.1f} ms, max "
                      f"{arrived.max() if len(arrived) else float('nan'):.1f} ms  [target "
                      f"<= {TARGET_LATENCY_S:g} s: {'met' if ok else 'NOT met'}]")
    finally:
        rclpy.try_shutdown()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--queries", type=int, default=200,
                        help="round trips per interface and round")
    parser.add_argument("--rounds", type=int, default=6, help="rounds, alternating off/on")
    parser.add_argument("--no-node", action="store_true", help="skip the node measurement")
    parser.add_argument("--latency-calls", type=int, default=LATENCY_CALLS,
                        help="service calls of 3. per environment")
    parser.add_argument("--listen", metavar="TOPIC", help=argparse.SUPPRESS)
    parser.add_argument("--quick", action="store_true",
                        help="the smoke test's form: 2 rounds of 20 queries, 10 calls in 3.")
    args = parser.parse_args(argv)
    if args.quick:
        args.queries, args.rounds, args.latency_calls = 20, 2, 10
    if args.listen:
        return listen(args.listen)
    bench_build()
    if not args.no_node:
        bench_node(args.queries, args.rounds)
        bench_latency(args.latency_calls)
    return 0


if __name__ == "__main__":
    sys.exit(main())
