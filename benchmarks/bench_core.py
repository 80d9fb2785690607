"""Benchmark of the ROS-free core on one CPU core: filter, exact test, pipeline.

Prints, for random n-finger grasps on a built-in object (mu = tan 10 deg, as in the
seed paper): grasps per second of the torque filter, of the exact SOCP test on every
grasp (unfiltered) and of the filtered pipeline; per-query costs and their ratio (the
paper: 0.05 ms vs 2.62 ms); and the filter's share of the pipeline's time.
Figures are medians over ``--repeats`` runs in this one process.

Then one grasp per call: ``check_force_closure`` with default settings on one (n, 3)
grasp at a time against the same call on the whole batch, per n (``--one-grasp-fingers``),
CPU time, the two alternating ``--repeats`` times: grasps/s of each, their ratio (the
target is >= 0.25), and how many lone verdicts and statuses differ from the batch's.

    python benchmarks/bench_core.py                # full: 100,000 six-finger grasps
    python benchmarks/bench_core.py --quick        # a few seconds
    python benchmarks/bench_core.py --peer 200     # also the 8-sided-pyramid Qhull peer
"""

import os

# One core, as the targets are stated: keep BLAS from spreading over both.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from collections.abc import Sequence  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

from grasp_fc_ros.core import check_force_closure, warm_up  # noqa: E402
from grasp_fc_ros.core.filter.torque_space_filter import passes_torque_filter  # noqa: E402
from grasp_fc_ros.core.model.grasp_input import prepare_grasps  # noqa: E402
from grasp_fc_ros.core.pipeline import run_pipeline  # noqa: E402
from grasp_fc_ros.experiment.linearized_peer import linearized_force_closure  # noqa: E402
from grasp_fc_ros.objects import (  # noqa: E402
    OBJECT_NAMES,
    ContactSurface,
    make_object,
    sample_grasps,
)
from timing import MU_PAPER, median_seconds  # noqa: E402

MU = MU_PAPER


def measure(surface: ContactSurface, n_fingers: int, n_grasps: int, exact_grasps: int,
            repeats: int, rng: np.random.Generator) -> dict[str, Any]:
    positions, normals = sample_grasps(surface, n_grasps, n_fingers, rng)
    grasps = prepare_grasps(positions, normals, MU)
    subset = prepare_grasps(positions[:exact_grasps], normals[:exact_grasps], MU)

    filter_s = median_seconds(lambda: passes_torque_filter(grasps), repeats)
    exact_s = median_seconds(lambda: run_pipeline(subset, use_filter=False), repeats)
    timings: list[dict[str, float]] = []
    pipeline_s = median_seconds(
        lambda: timings.append(run_pipeline(subset, use_filter=True).timing), repeats)
    result = check_force_closure(positions[:exact_grasps], normals[:exact_grasps], MU,
                                 use_filter=True)  # the paper's pipeline, as timed above
    filter_share = statistics.median(t["filter_s"] / (t["filter_s"] + t["exact_s"])
                                     for t in timings[1:])
    return {
        "n": n_fingers,
        "filter_per_s": n_grasps / filter_s,
        "exact_per_s": exact_grasps / exact_s,
        "pipeline_per_s": exact_grasps / pipeline_s,
        "filter_ms": 1e3 * filter_s / n_grasps,
        "exact_ms": 1e3 * exact_s / exact_grasps,
        "filter_share": filter_share,
        "rejected": float(result.filtered_out.mean()),
        "force_closure": float(result.force_closure.mean()),
    }


def peer_ratio(surface: ContactSurface, n_grasps: int, peer_grasps: int, repeats: int,
               rng: np.random.Generator) -> tuple[float, float, float]:
    """The linearized peer (inscribed 8-sided pyramids, Qhull) on ``peer_grasps``
    six-finger grasps against the paper's filtered pipeline and the exact test alone on
    ``n_grasps``; ms per grasp. Returns (peer, filtered, exact)."""
    positions, normals = sample_grasps(surface, n_grasps, 6, rng)
    grasps = prepare_grasps(positions, normals, MU)
    filtered_s = median_seconds(lambda: run_pipeline(grasps, use_filter=True), repeats)
    exact_s = median_seconds(lambda: run_pipeline(grasps, use_filter=False), repeats)
    peer_s = median_seconds(lambda: linearized_force_closure(
        positions[:peer_grasps], normals[:peer_grasps], MU, 8), 1)
    return (1e3 * peer_s / peer_grasps, 1e3 * filtered_s / n_grasps, 1e3 * exact_s / n_grasps)


def one_grasp_per_call(surface: ContactSurface, n_fingers: int, n_grasps: int, calls: int,
                       repeats: int, rng: np.random.Generator) -> dict[str, Any]:
    """``check_force_closure`` (default settings) on ``calls`` grasps one at a time
    against the same call on all ``n_grasps`` of the batch, CPU time, alternating,
    medians of ``repeats``; grasps/s of each, and the lone results that differ from the
    batch's (force closure, status), compared outside the timed loops."""
    positions, normals = sample_grasps(surface, n_grasps, n_fingers, rng)
    lone = [(positions[g], normals[g]) for g in range(calls)]
    batch = check_force_closure(positions, normals, MU)
    results = [check_force_closure(p, n, MU) for p, n in lone]

    def one_at_a_time() -> None:
        for p, n in lone:            # as a planner would: each result used, then dropped
            check_force_closure(p, n, MU)

    one_s: list[float] = []
    batch_s: list[float] = []
    for _ in range(repeats):
        start = time.process_time()
        one_at_a_time()
        one_s.append((time.process_time() - start) / calls)
        start = time.process_time()
        check_force_closure(positions, normals, MU)
        batch_s.append((time.process_time() - start) / n_grasps)
    one_per_s = 1.0 / statistics.median(one_s)
    batch_per_s = 1.0 / statistics.median(batch_s)
    return {"n": n_fingers, "one_per_s": one_per_s, "batch_per_s": batch_per_s,
            "ratio": one_per_s / batch_per_s, "calls": calls, "grasps": n_grasps,
            "verdicts_differ": sum(bool(r.force_closure != batch.force_closure[g])
                                   for g, r in enumerate(results)),
            "statuses_differ": sum(bool(r.status != batch.status[g])
                                   for g, r in enumerate(results))}


def print_one_grasp_table(rows: Sequence[dict[str, Any]], repeats: int) -> None:
    print(f"\none grasp per check_force_closure call (default settings) vs the batched call; "
          f"CPU time, alternating, medians of {repeats}; target ratio >= 0.25")
    header = (f"{'n':>3} {'one/s':>9} {'batched/s':>10} {'ratio':>6} {'calls':>6} "
              f"{'batch':>7} {'verdicts differ':>16} {'statuses differ':>16}")
    print(header)
    print("-" * len(header))
    for r in rows:
        print(f"{r['n']:>3} {r['one_per_s']:>9.0f} {r['batch_per_s']:>10.0f} "
              f"{r['ratio']:>6.3f} {r['calls']:>6d} {r['grasps']:>7d} "
              f"{r['verdicts_differ']:>16d} {r['statuses_differ']:>16d}")


def print_table(rows: Sequence[dict[str, Any]], object_name: str, six_finger_grasps: int,
                sweep_grasps: int) -> None:
    print(f"\nobject {object_name!r}, mu = tan(10 deg) = {MU:.4f}; {six_finger_grasps} "
          f"six-finger grasps, {sweep_grasps} for other n; medians, one core")
    header = (f"{'n':>3} {'filter/s':>10} {'exact/s':>9} {'pipeline/s':>11} "
              f"{'filter ms':>10} {'exact ms':>9} {'ratio':>6} {'filter share':>13} "
              f"{'rejected':>9} {'FC':>6}")
    print(header)
    print("-" * len(header))
    for r in rows:
        print(f"{r['n']:>3} {r['filter_per_s']:>10.0f} {r['exact_per_s']:>9.0f} "
              f"{r['pipeline_per_s']:>11.0f} {r['filter_ms']:>10.4f} {r['exact_ms']:>9.4f} "
              f"{r['exact_ms'] / r['filter_ms']:>6.0f} {100 * r['filter_share']:>12.1f}% "
              f"{100 * r['rejected']:>8.1f}% {100 * r['force_closure']:>5.1f}%")


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--object", default="box", choices=OBJECT_NAMES)
    parser.add_argument("--grasps", type=int, default=100_000,
                        help="grasps for the six-finger figures (default 100000)")
    parser.add_argument("--sweep-grasps", type=int, default=20_000,
                        help="grasps for the other finger counts (default 20000)")
    parser.add_argument("--fingers", type=int, nargs="+", default=[6, 3, 4, 8, 12])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--one-grasp-fingers", type=int, nargs="*", default=[3, 4, 6, 8],
                        help="finger counts of the one-grasp-per-call table (none: skip it)")
    parser.add_argument("--one-grasp-calls", type=int, default=5_000,
                        help="lone calls per repeat of that table (default 5000); the "
                             "batch is --sweep-grasps grasps")
    parser.add_argument("--quick", action="store_true", help="small sizes, one repeat")
    parser.add_argument("--peer", type=int, default=0, metavar="GRASPS",
                        help="also time the linearized Qhull peer on this many six-finger "
                             "grasps (~20 ms each) against the pipeline on --grasps")
    args = parser.parse_args(argv)
    if args.quick:
        args.grasps, args.sweep_grasps, args.repeats = 5_000, 1_000, 1
        args.one_grasp_calls = 500

    warm_up()
    rng = np.random.default_rng(args.seed)
    surface = make_object(args.object)
    if args.peer:
        peer, filtered, exact = peer_ratio(surface, args.grasps, args.peer, args.repeats, rng)
        print(f"six fingers, 8-sided-pyramid Qhull peer {peer:.2f} ms per grasp; filtered "
              f"pipeline {filtered:.4f} ms ({peer / filtered:.0f}x faster, target >= 1000x); "
              f"exact test alone {exact:.4f} ms ({peer / exact:.0f}x)", flush=True)
    rows = []
    for n in args.fingers:
        size = args.grasps if n == 6 else args.sweep_grasps
        rows.append(measure(surface, n, size, size, args.repeats, rng))
        print(f"measured n = {n}", flush=True)
    print_table(rows, args.object, args.grasps, args.sweep_grasps)
    six = next((r for r in rows if r["n"] == 6), None)
    if six:
        print(f"\nsix fingers: filter {six['filter_per_s']:.0f} grasps/s (target >= 100000), "
              f"exact {six['exact_per_s']:.0f} grasps/s batched (target >= 3000), "
              f"per query {six['filter_ms']:.4f} ms vs {six['exact_ms']:.3f} ms "
              f"(ratio {six['exact_ms'] / six['filter_ms']:.0f}; paper 0.05 vs 2.62 ms, 52), "
              f"filter share of pipeline time {100 * six['filter_share']:.1f}% (target < 5%)")
    if args.one_grasp_fingers:
        one = [one_grasp_per_call(surface, n, args.sweep_grasps,
                                  min(args.one_grasp_calls, args.sweep_grasps),
                                  max(args.repeats, 3), rng)
               for n in args.one_grasp_fingers]
        print_one_grasp_table(one, max(args.repeats, 3))


if __name__ == "__main__":
    main()
