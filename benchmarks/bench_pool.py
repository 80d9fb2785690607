"""The node's worker pool alone, without ROS: batches through
grasp_fc_ros.engine.pool.EvaluationPool against the core in one process and against the
core in one process per core at once (the machine's ceiling), in alternating rounds.

Prints per round the three rates, and the CPU per grasp of this process (the pool's
owner: chunking, feeding the workers, collecting) and of the workers. What the node adds
on top of this is ROS: taking and answering the messages (benchmarks/bench_ros.py).

Usage: python benchmarks/bench_pool.py [--batches B] [--batch-size S] [--rounds R]
       [--workers W]
       python benchmarks/bench_pool.py --quick    # the smoke test's form
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Sequence

import numpy as np

from bench_ros import bench_core, bench_core_everywhere, ceiling_pool, tree_cpu_s
from grasp_fc_ros.engine.pool import EvaluationPool
from grasp_fc_ros.objects import make_object, sample_grasps
from grasp_fc_ros.packed import PackedGrasps, Settings

N_FINGERS = 6
MU = 0.5  # as bench_ros.bench_core decides the same grasps


def packed(positions: np.ndarray, normals: np.ndarray) -> PackedGrasps:
    """Grasps (N, n, 3) as one request of the pool, every contact at friction MU."""
    n_grasps, n_contacts = positions.shape[:2]
    return PackedGrasps(ids=np.arange(n_grasps, dtype=np.uint64),
                        counts=np.full(n_grasps, n_contacts), positions=positions.reshape(-1, 3),
                        normals=normals.reshape(-1, 3), mu=np.full(n_grasps * n_contacts, MU))


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="the node's worker pool without ROS")
    parser.add_argument("--batches", type=int, default=10)
    parser.add_argument("--batch-size", type=int, default=10_000)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--quick", action="store_true",
                        help="the smoke test's form: 2 batches of 300, 2 rounds, 2 workers")
    args = parser.parse_args(argv)
    if args.quick:
        args.batches, args.batch_size, args.rounds, args.workers = 2, 300, 2, 2
    rng = np.random.default_rng(0)
    positions, normals = sample_grasps(make_object("box"), args.batches * args.batch_size,
                                       N_FINGERS, rng)
    batches = [(positions[k:k + args.batch_size], normals[k:k + args.batch_size])
               for k in range(0, len(positions), args.batch_size)]
    requests = [packed(p, n) for p, n in batches]
    n_grasps = len(positions)
    everywhere, taken = ceiling_pool(batches, args.workers)
    pool = EvaluationPool(args.workers)
    try:
        pool.decide(requests[0], Settings())  # the workers' first chunks: not timed
        bench_core(batches[:1])
        print(f"{args.batches} batches of {args.batch_size} {N_FINGERS}-finger grasps, "
              f"{args.workers} workers, {os.cpu_count()} CPUs")
        ratios: list[float] = []
        for _ in range(args.rounds):
            core, _ = bench_core(batches)
            ceiling = bench_core_everywhere(everywhere, taken, args.workers)
            pids = pool.worker_pids()
            owner_cpu, workers_cpu = time.process_time(), [tree_cpu_s(pid) for pid in pids]
            start = time.perf_counter()
            for decision in [pool.start(request, Settings()) for request in requests]:
                decision.result()
            rate = n_grasps / (time.perf_counter() - start)
            owner = (time.process_time() - owner_cpu) / n_grasps
            workers = sum(tree_cpu_s(pid) - c
                          for pid, c in zip(pids, workers_cpu, strict=True)) / n_grasps
            ratios.append(rate / core)
            print(f"core {core:8.0f} grasps/s; core in {args.workers} processes "
                  f"{ceiling:8.0f} ({ceiling / core:.2f}x); pool {rate:8.0f} "
                  f"({rate / core:.2f}x); CPU per grasp: owner {1e6 * owner:.2f} us, "
                  f"workers {1e6 * workers:.2f} us")
        print(f"pool: median {np.median(ratios):.2f}x the core in one process")
    finally:
        pool.close()
        everywhere.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
