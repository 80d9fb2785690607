"""Benchmark of the exact stage: the fast interior-point stage against the Clarabel path.

For random n-finger grasps on the box (n = 4, 6, 8; mu = tan 10 deg and 0.5), in this
one process on one core, prints per cell: grasps per second of the Clarabel path alone
(``solve_exact(..., fast=False)``, 64 grasps per solve) and of the fast stage with its
Clarabel fallback, verdicts only (``margin="bound"``) and with the margin to 1e-8
(``margin="optimum"``); their ratios; how many grasps fell back to Clarabel; and the
verdict disagreements with the Clarabel path counted in the same run. Then the latency
of one grasp through ``check_force_closure``. Figures are medians over ``--repeats``.

    python benchmarks/bench_exact.py            # 4,000 grasps per cell
    python benchmarks/bench_exact.py --quick    # 500 grasps per cell
"""

import os

# One core, as the targets are stated: keep BLAS from spreading over both.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from grasp_fc_ros.core import check_force_closure, warm_up  # noqa: E402
from grasp_fc_ros.core.certificates import normalise_positions  # noqa: E402
from grasp_fc_ros.core.exact_test import solve_exact  # noqa: E402
from grasp_fc_ros.core.grasp_input import prepare_grasps  # noqa: E402
from grasp_fc_ros.core.interior_point import UNDECIDED, solve_fast  # noqa: E402
from grasp_fc_ros.objects import make_object, sample_grasps  # noqa: E402
from timing import MU_PAPER, median_seconds  # noqa: E402

MUS = (MU_PAPER, 0.5)


def measure_cell(surface, n_fingers, mu, n_grasps, repeats, rng):
    positions, normals = sample_grasps(surface, n_grasps, n_fingers, rng)
    grasps = prepare_grasps(positions, normals, mu)
    clarabel_s = median_seconds(lambda: solve_exact(grasps, fast=False), repeats)
    bound_s = median_seconds(lambda: solve_exact(grasps, "bound"), repeats)
    optimum_s = median_seconds(lambda: solve_exact(grasps, "optimum"), repeats)
    reference = solve_exact(grasps, fast=False)
    disagreements = 0
    for mode in ("bound", "optimum"):
        fast = solve_exact(grasps, mode)
        decided = ~(fast.solver_failure | reference.solver_failure)
        disagreements += int(np.sum((fast.force_closure != reference.force_closure) & decided))
    unit = normalise_positions(grasps.positions)[0]
    fallback = int(np.sum(solve_fast(unit, grasps.normals, grasps.mu)[0] == UNDECIDED))
    return {"n": n_fingers, "mu": mu, "clarabel": n_grasps / clarabel_s,
            "bound": n_grasps / bound_s, "optimum": n_grasps / optimum_s,
            "fallback": fallback, "disagree": disagreements,
            "fc_share": float(reference.force_closure.mean())}


def one_grasp_latency(surface, rng, calls, **options):
    positions, normals = sample_grasps(surface, calls, 6, rng)
    times = []
    for g in range(calls):
        start = time.perf_counter()
        check_force_closure(positions[g], normals[g], MUS[0], **options)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="500 grasps per cell")
    parser.add_argument("--grasps", type=int, default=4000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--calls", type=int, default=0,
                        help="one-grasp latency calls (default 2000, --quick 200)")
    args = parser.parse_args(argv)
    n_grasps = 500 if args.quick else args.grasps
    start = time.perf_counter()
    warm_up()
    print(f"warm_up (compile or cache load): {time.perf_counter() - start:.2f} s")
    rng = np.random.default_rng(args.seed)
    surface = make_object("box")
    print(f"{n_grasps} box grasps per cell, medians of {args.repeats}; grasps/s")
    print(f"{'n':>2} {'mu':>6} {'FC%':>5} {'clarabel':>9} {'fast':>9} {'ratio':>6} "
          f"{'+margin':>9} {'ratio':>6} {'fallback':>8} {'disagree':>8}")
    for n_fingers in (4, 6, 8):
        for mu in MUS:
            cell = measure_cell(surface, n_fingers, mu, n_grasps, args.repeats, rng)
            print(f"{cell['n']:>2} {cell['mu']:>6.3f} {100 * cell['fc_share']:>5.1f} "
                  f"{cell['clarabel']:>9.0f} {cell['bound']:>9.0f} "
                  f"{cell['bound'] / cell['clarabel']:>5.1f}x {cell['optimum']:>9.0f} "
                  f"{cell['optimum'] / cell['clarabel']:>5.1f}x {cell['fallback']:>8d} "
                  f"{cell['disagree']:>8d}")
    calls = args.calls or (200 if args.quick else 2000)
    for label, options in (("default", {}), ('margin="bound"', {"margin": "bound"}),
                           ("use_filter=False", {"use_filter": False}),
                           ('use_filter=False, margin="bound"',
                            {"use_filter": False, "margin": "bound"}),
                           ("certificates=True", {"certificates": True})):
        latency = one_grasp_latency(surface, rng, calls, **options)
        print(f"one 6-finger grasp through check_force_closure ({label}): "
              f"{latency * 1e3:.3f} ms median of {calls}")


if __name__ == "__main__":
    main()
