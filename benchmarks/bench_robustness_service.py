"""ROS benchmark of the assess_robustness service: the node in its own process (its
console script, a namespace of its own), called through grasp_fc_ros.client.GraspClient.

Prints
1. the round trip of one 4-finger box grasp with 1,000 samples (issue 29's errors and
   noise: 2 mm, 3 degrees, friction 0.1), idle: p50/p99 (target p99 <= 50 ms);
2. one-grasp ``check_force_closure`` round trips, idle and while another thread's
   ``assess_robustness`` call of --big-grasps grasps x 1,000 samples is decided: the
   assessment is served on a thread of its own and decided by the workers, so the
   check calls should not wait for it;
3. the answers' consistency: every call's rows equal the core's on the same grasp;
4. the work of one such call without DDS, in this process: CPU time p50/p99 of the
   engine's ``evaluate`` on the same grasps (what 1. costs on an idle core), and of its
   three parts alone: the core's ``probability_of_force_closure``, ``robustness`` and
   ``holds_under``.

    python benchmarks/bench_robustness_service.py            # 300 calls, 200-grasp call
    python benchmarks/bench_robustness_service.py --quick    # 20 calls, 20-grasp call
"""

from __future__ import annotations

import argparse
import math
import os
import threading
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
import rclpy

from bench_ros import percentiles, start_node, stop_node
from grasp_fc_ros.client import GraspClient
from grasp_fc_ros.core import holds_under, probability_of_force_closure, robustness
from grasp_fc_ros.engine.evaluation import evaluate, warm_up_epsilon
from grasp_fc_ros.interface.conversions import batch_to_packed, grasps_to_batch_msg
from grasp_fc_ros.objects import make_object, sample_grasps
from grasp_fc_ros.packed import RobustnessQuery, Settings

MU = 0.5
ERROR = {"position_error": 0.002, "normal_error": math.radians(3.0), "friction_error": 0.1}
NOISE = {"position_sigma": 0.002, "normal_sigma": math.radians(3.0), "friction_sigma": 0.1}
SAMPLES = 1000


def assess(client: GraspClient, positions: np.ndarray, normals: np.ndarray, seed: int,
           ids: np.ndarray, timeout: float) -> Any:
    """The service's answer for these grasps: issue 29's errors and noise, SAMPLES."""
    return client.assess_robustness(
        positions, normals, MU, position_error=ERROR["position_error"],
        normal_error=ERROR["normal_error"], friction_error=ERROR["friction_error"],
        position_sigma=NOISE["position_sigma"], normal_sigma=NOISE["normal_sigma"],
        friction_sigma=NOISE["friction_sigma"], samples=SAMPLES, seed=seed, ids=ids,
        timeout=timeout)


def assess_times(client: GraspClient, positions: np.ndarray, normals: np.ndarray,
                 calls: int) -> tuple[np.ndarray, int]:
    """Round trips (ms) of one-grasp assessments, grasp k % N of the given ones; and how
    many answers differ from the core's probability on the same grasp."""
    times, wrong = [], 0
    for k in range(calls):
        g = k % len(positions)
        start = time.perf_counter()
        answer = assess(client, positions[g], normals[g], k, np.array([g]), 30.0)
        times.append(1e3 * (time.perf_counter() - start))
        core = probability_of_force_closure(positions[g], normals[g], MU, samples=SAMPLES,
                                            seed=k, grasp_ids=[g], **NOISE)
        wrong += int(answer.robustness.probability[0] != core.estimate)
    return np.array(times), wrong


def engine_cpu_ms(positions: np.ndarray, normals: np.ndarray, calls: int) -> np.ndarray:
    """CPU time (ms) of the engine's evaluate on one-grasp assessment requests, grasp
    k % N, as the service decides them (kernels warm)."""
    warm_up_epsilon()
    query = RobustnessQuery(ERROR["position_error"], ERROR["normal_error"],
                            ERROR["friction_error"], NOISE["position_sigma"],
                            NOISE["normal_sigma"], NOISE["friction_sigma"], SAMPLES)
    settings = Settings(robustness=query)
    times = []
    for k in range(calls + 1):
        g = k % len(positions)
        packed = batch_to_packed(grasps_to_batch_msg([g], positions[g:g + 1],
                                                     normals[g:g + 1], MU))
        start = time.process_time()
        evaluate(packed, settings)
        times.append(1e3 * (time.process_time() - start))
    return np.array(times[1:])


def part_cpu_ms(positions: np.ndarray, normals: np.ndarray, calls: int) -> dict[str, np.ndarray]:
    """CPU time (ms) of each core part of a one-grasp assessment, grasp k % N."""
    parts = {
        "probability": lambda g: probability_of_force_closure(
            positions[g], normals[g], MU, samples=SAMPLES, seed=g, **NOISE),
        "robustness": lambda g: robustness(positions[g], normals[g], MU),
        "holds_under": lambda g: holds_under(positions[g], normals[g], MU, **ERROR)}
    times: dict[str, np.ndarray] = {}
    for name, part in parts.items():
        part(0)
        spent = []
        for k in range(calls):
            start = time.process_time()
            part(k % len(positions))
            spent.append(1e3 * (time.process_time() - start))
        times[name] = np.array(spent)
    return times


def check_times(client: GraspClient, positions: np.ndarray, normals: np.ndarray,
                calls: int, until: threading.Event | None = None) -> np.ndarray:
    """Round trips (ms) of one-grasp check_force_closure calls: ``calls``, or until
    ``until`` is set."""
    times: list[float] = []
    k = 0
    # (at least one call while ``until`` is not set when the loop starts)
    while (until is None and k < calls) or (until is not None and (not k or not until.is_set())):
        g = k % len(positions)
        start = time.perf_counter()
        client.call(positions[g:g + 1], normals[g:g + 1], MU, timeout=30.0)
        times.append(1e3 * (time.perf_counter() - start))
        k += 1
    return np.array(times)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=300)
    parser.add_argument("--big-grasps", type=int, default=200)
    parser.add_argument("--quick", action="store_true", help="20 calls, a 20-grasp call")
    args = parser.parse_args(argv)
    if args.quick:
        args.calls, args.big_grasps = 20, 20
    rng = np.random.default_rng(0)
    positions, normals = sample_grasps(make_object("box"), max(args.big_grasps, 50), 4, rng)
    rclpy.init()
    node, client = start_node("robustness")
    try:
        assess(client, positions[0], normals[0], 0, np.array([0]), 60.0)  # warm
        times, wrong = assess_times(client, positions[:50], normals[:50], args.calls)
        print(f"assess_robustness, one grasp x {SAMPLES} samples, idle: {percentiles(times)}"
              f" [target p99 <= 50 ms: {'met' if np.percentile(times, 99) <= 50 else 'NOT met'}]"
              f"; answers differing from the core's: {wrong}")
        idle = check_times(client, positions, normals, args.calls)
        started, done = threading.Event(), threading.Event()
        big: dict[str, float] = {}

        def assess_big() -> None:
            # (start_node's namespace for the tag "robustness")
            with GraspClient(f"/grasp_fc_robustness_{os.getpid()}/force_closure") as other:
                other.wait_for_node(20.0)
                started.set()
                start = time.perf_counter()
                assess(other, positions[:args.big_grasps], normals[:args.big_grasps], 1,
                       np.arange(args.big_grasps), 600.0)
                big["s"] = time.perf_counter() - start
            done.set()

        worker = threading.Thread(target=assess_big)
        worker.start()
        started.wait(60.0)  # the other client's node is connected: its call goes out now
        busy = check_times(client, positions, normals, 0, until=done)
        worker.join()
        print(f"check_force_closure, one grasp, idle: {percentiles(idle)}")
        cpu = engine_cpu_ms(positions[:50], normals[:50], args.calls)
        print(f"the work of one assessment (engine, this process, CPU time): "
              f"{percentiles(cpu)}")
        for name, spent in part_cpu_ms(positions[:50], normals[:50], args.calls).items():
            print(f"  of which {name} alone: {percentiles(spent)}")
        print(f"check_force_closure, one grasp, during a {args.big_grasps}-grasp x "
              f"{SAMPLES}-sample assessment ({big.get('s', float('nan')):.2f} s): "
              f"{percentiles(busy)}")
    finally:
        stop_node(node, client)
        rclpy.shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
