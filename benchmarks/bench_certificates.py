"""What the node's `certificates` and `compute_min_friction` parameters cost.

Starts the force_closure node (its console script, default 2 workers, a namespace of its
own) once per setting: both off, certificates on, both on; and prints for each
1. batch throughput through DDS (6-finger grasps, two batches in flight, after one
   untimed warm-up batch) and CPU seconds per grasp of the node's process tree (which,
   unlike the rate, does not depend on what else the machine runs);
2. single-grasp topic queries per second (back to back through GraspClient);
3. the serialised size of one batch verdict message (CDR, as DDS sends it), per grasp.

Usage: python benchmarks/bench_certificates.py [--batches B] [--batch-size S]
       [--queries Q] [--object NAME]
       python benchmarks/bench_certificates.py --quick    # the smoke test's form
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

import numpy as np
import rclpy
from rclpy.serialization import serialize_message

from bench_ros import (
    N_FINGERS,
    Batch,
    bench_batches,
    bench_single,
    start_node,
    stop_node,
    tree_cpu_s,
)
from grasp_fc_ros.interface.conversions import verdicts_to_array_msg
from grasp_fc_ros.objects import make_object, sample_grasps
from timing import ratio_or_nan

SETTINGS = {
    "off": [],
    "certificates": ["-p", "certificates:=true"],
    "certificates+min_friction": ["-p", "certificates:=true",
                                  "-p", "compute_min_friction:=true"],
}


def measure(tag: str, parameters: list[str], batches: list[Batch], positions: np.ndarray,
            normals: np.ndarray, n_queries: int) -> tuple[float, bool, float, float, bool, float]:
    node, client = start_node("cert_" + tag.replace("+", "_"), parameters)
    try:
        warm = client.check_batch(batches[0][0], batches[0][1], timeout=600.0)
        cpu = tree_cpu_s(node.pid)
        rate, complete = bench_batches(client, batches)
        cpu_per_grasp = (tree_cpu_s(node.pid) - cpu) / sum(len(p) for p, _ in batches)
        single_rate, lossless = bench_single(client, positions, normals, n_queries)
    finally:
        stop_node(node, client)
    size = len(serialize_message(verdicts_to_array_msg(warm)))
    return rate, complete, cpu_per_grasp, single_rate, lossless, size / len(warm)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batches", type=int, default=5, help="timed batches per setting")
    parser.add_argument("--batch-size", type=int, default=1000, help="grasps per batch")
    parser.add_argument("--queries", type=int, default=2000, help="single-grasp queries")
    parser.add_argument("--object", default="box", help="built-in object")
    parser.add_argument("--quick", action="store_true",
                        help="the smoke test's form: one batch of 40, 50 queries")
    args = parser.parse_args(argv)
    if args.quick:
        args.batches, args.batch_size, args.queries = 1, 40, 50
    rng = np.random.default_rng(0)
    n = args.batch_size
    positions, normals = sample_grasps(make_object(args.object), (args.batches + 1) * n,
                                       N_FINGERS, rng)
    batches = [(positions[k * n:(k + 1) * n], normals[k * n:(k + 1) * n])
               for k in range(args.batches + 1)]
    rclpy.init()
    try:
        results = {tag: measure(tag, parameters, batches, positions, normals, args.queries)
                   for tag, parameters in SETTINGS.items()}
    finally:
        rclpy.try_shutdown()
    print(f"{N_FINGERS}-finger grasps on {args.object}, batches of {n}, machine shared:")
    base_rate, base_cpu, base_single, base_size = (results["off"][i] for i in (0, 2, 3, 5))
    for tag, (rate, complete, cpu, single, lossless, size) in results.items():
        print(f"  {tag:<26} batch {rate:9.0f} grasps/s "
              f"({ratio_or_nan(rate, base_rate):5.2f}x off), "
              f"{cpu * 1e3:.4f} CPU ms/grasp ({ratio_or_nan(cpu, base_cpu):5.2f}x)"
              f"{'' if complete else ' INCOMPLETE'}; single {single:6.0f} queries/s "
              f"({ratio_or_nan(single, base_single):4.2f}x){'' if lossless else ' LOST'}; "
              f"verdict message {size:6.1f} B/grasp ({ratio_or_nan(size, base_size):4.1f}x)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
