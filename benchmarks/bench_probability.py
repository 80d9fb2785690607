"""Benchmark of the probability of force closure (issue 29): speed against the exact test,
and the coverage of its Clopper-Pearson interval.

Speed (one process, one core, CPU time, medians over ``--repeats``): four-finger grasps
on the box at mu = 0.5 and the noise of issue 29 (2 mm, 3 degrees, friction 0.1; the
objects are in metres), ``--samples`` samples per grasp. It prints samples per second
of ``probability_of_force_closure``, and as the unit of cost the batched exact test
(``check_force_closure(..., margin="bound")``, verdicts only, default filter) on random
box grasps and on the very samples the probability decided (materialised first), and on
those samples without the filter, as the probability decides them; the ratios (target
>= 0.5); and the latency of one grasp with 1,000 samples.

Coverage (``--coverage``): for ``--grasps`` grasps (built-in objects in turn, 4 fingers,
mu = 0.5, the same noise), the 95% interval from ``--interval-samples`` samples against
a reference from ``--reference-samples`` samples drawn from other streams; the share of
grasps whose interval contains the reference (target >= 0.94 for 2,000 against 100,000
on 500 grasps), overall and among grasps whose reference is in (0.02, 0.98).

``--blocks`` times the call for several BLOCK_CONTACTS sizes, and its peak memory.

    python benchmarks/bench_probability.py                 # speed
    python benchmarks/bench_probability.py --coverage      # 500 grasps x 102,000 samples
    python benchmarks/bench_probability.py --quick         # a few seconds
"""

import os

# One core, as the targets are stated: keep BLAS from spreading over both.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
import tracemalloc  # noqa: E402
from collections.abc import Sequence  # noqa: E402

import numpy as np  # noqa: E402

from grasp_fc_ros.core import check_force_closure, warm_up  # noqa: E402
from grasp_fc_ros.core.model.grasp_input import prepare_grasps  # noqa: E402
from grasp_fc_ros.core.robustness import probability  # noqa: E402
from grasp_fc_ros.core.robustness.probability import (  # noqa: E402
    _ErrorModel,
    _stream,
    probability_of_force_closure,
)
from grasp_fc_ros.objects import OBJECT_NAMES, make_object, sample_grasps  # noqa: E402
from timing import median_cpu_seconds  # noqa: E402

MU = 0.5
#: Issue 29's noise: 2 mm (the objects are in metres), 3 degrees, 0.1 on mu.
NOISE = {"position_sigma": 0.002, "normal_sigma": float(np.radians(3.0)),
         "friction_sigma": 0.1}
#: Streams of the reference samples start here, far from the interval's 0..N-1.
REFERENCE_STREAMS = 1 << 40


def materialised(positions: np.ndarray, normals: np.ndarray, samples: int,
                 seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The perturbed grasps the probability decides for these grasps and seed, as arrays
    (N * samples, n, 3), (N * samples, n, 3), (N * samples, n)."""
    grasps = prepare_grasps(positions, normals, MU)
    model = _ErrorModel(**NOISE)
    columns = model.columns(positions.shape[1])
    draws = np.stack([_stream(seed, k).standard_normal((samples, columns))
                      for k in range(positions.shape[0])])
    return model.perturb(grasps.positions, grasps.normals, grasps.mu, draws)


def speed(n_grasps: int, samples: int, repeats: int, rng: np.random.Generator) -> None:
    surface = make_object("box")
    positions, normals = sample_grasps(surface, n_grasps, 4, rng)
    total = n_grasps * samples
    prob_s = median_cpu_seconds(lambda: probability_of_force_closure(
        positions, normals, MU, samples=samples, seed=1, **NOISE), repeats)
    random_p, random_n = sample_grasps(surface, total, 4, rng)
    random_s = median_cpu_seconds(
        lambda: check_force_closure(random_p, random_n, MU, margin="bound"), repeats)
    same_p, same_n, same_mu = materialised(positions, normals, samples, 1)
    same_s = median_cpu_seconds(
        lambda: check_force_closure(same_p, same_n, same_mu, margin="bound"), repeats)
    bare_s = median_cpu_seconds(
        lambda: check_force_closure(same_p, same_n, same_mu, margin="bound", use_filter=False),
        repeats)
    result = probability_of_force_closure(positions, normals, MU, samples=samples, seed=1,
                                          **NOISE)
    print(f"speed: {n_grasps} box grasps, 4 fingers, mu = {MU}, {samples} samples each, "
          f"noise {NOISE}; CPU time, medians of {repeats}")
    print(f"  probability_of_force_closure   {total / prob_s:>10.0f} samples/s "
          f"(mean estimate {np.mean(result.estimate):.3f}, undecided samples "
          f"{int(np.sum(result.undecided))})")
    print(f"  exact test, random grasps      {total / random_s:>10.0f} grasps/s  "
          f"-> ratio {random_s / prob_s:.2f} (target >= 0.5)")
    print(f"  exact test, the same samples   {total / same_s:>10.0f} grasps/s  "
          f"-> ratio {same_s / prob_s:.2f}")
    print(f"  ... without the filter         {total / bare_s:>10.0f} grasps/s  "
          f"(what the probability runs)")
    one_p, one_n = positions[:1], normals[:1]
    latencies = []
    for k in range(max(20, repeats * 10)):
        start = time.perf_counter()
        probability_of_force_closure(one_p[0], one_n[0], MU, samples=1000, seed=k, **NOISE)
        latencies.append(time.perf_counter() - start)
    print(f"  one grasp, 1,000 samples: median {1e3 * statistics.median(latencies):.1f} ms, "
          f"max {1e3 * max(latencies):.1f} ms of {len(latencies)} (wall time)")


def blocks(n_grasps: int, samples: int, sizes: Sequence[int], repeats: int,
           rng: np.random.Generator) -> None:
    positions, normals = sample_grasps(make_object("box"), n_grasps, 4, rng)
    print(f"BLOCK_CONTACTS: {n_grasps} box grasps x {samples} samples, CPU time")
    default = probability.BLOCK_CONTACTS
    try:
        for size in sizes:
            probability.BLOCK_CONTACTS = size
            seconds = median_cpu_seconds(lambda: probability_of_force_closure(
                positions, normals, MU, samples=samples, seed=1, **NOISE), repeats)
            tracemalloc.start()
            probability_of_force_closure(positions, normals, MU, samples=samples, seed=1,
                                         **NOISE)
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
            print(f"  {size:>8} {n_grasps * samples / seconds:>10.0f} samples/s, peak "
                  f"{peak / 1e6:.1f} MB (tracemalloc)")
    finally:
        probability.BLOCK_CONTACTS = default


def coverage(n_grasps: int, interval_samples: int, reference_samples: int,
             rng: np.random.Generator) -> None:
    per_object = -(-n_grasps // len(OBJECT_NAMES))
    parts = [sample_grasps(make_object(name), per_object, 4, rng) for name in OBJECT_NAMES]
    positions = np.concatenate([p for p, _ in parts])[:n_grasps]
    normals = np.concatenate([n for _, n in parts])[:n_grasps]
    start = time.perf_counter()
    interval = probability_of_force_closure(positions, normals, MU, samples=interval_samples,
                                            seed=7, **NOISE)
    reference = probability_of_force_closure(
        positions, normals, MU, samples=reference_samples, seed=7,
        grasp_ids=REFERENCE_STREAMS + np.arange(n_grasps), **NOISE)
    seconds = time.perf_counter() - start
    truth = reference.estimate
    inside = (interval.lower <= truth) & (truth <= interval.upper)
    middle = (truth > 0.02) & (truth < 0.98)
    print(f"coverage: {n_grasps} grasps over {len(OBJECT_NAMES)} objects, 4 fingers, "
          f"mu = {MU}, noise {NOISE}; {interval.confidence:.0%} interval from "
          f"{interval_samples} samples against {reference_samples} samples "
          f"({seconds:.0f} s wall)")
    print(f"  contains the reference: {inside.mean():.3f} of all grasps (target >= 0.94); "
          f"{inside[middle].mean() if middle.any() else float('nan'):.3f} of the "
          f"{int(middle.sum())} with reference in (0.02, 0.98)")
    print(f"  reference 0: {int((truth == 0).sum())}, 1: {int((truth == 1).sum())}; "
          f"mean interval width {np.mean(interval.upper - interval.lower):.3f}; undecided "
          f"samples {int(np.sum(interval.undecided) + np.sum(reference.undecided))}")


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grasps", type=int, default=None,
                        help="grasps (speed: 100; coverage: 500)")
    parser.add_argument("--samples", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--coverage", action="store_true")
    parser.add_argument("--interval-samples", type=int, default=2000)
    parser.add_argument("--reference-samples", type=int, default=100_000)
    parser.add_argument("--blocks", type=int, nargs="*", default=None,
                        help="time these BLOCK_CONTACTS sizes")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quick", action="store_true", help="small sizes, one repeat")
    args = parser.parse_args(argv)
    if args.quick:
        args.repeats, args.samples = 1, 200
        args.interval_samples, args.reference_samples = 200, 2000
    rng = np.random.default_rng(args.seed)
    warm_up()
    if args.coverage:
        coverage(args.grasps or (40 if args.quick else 500), args.interval_samples,
                 args.reference_samples, rng)
    elif args.blocks is not None:
        blocks(args.grasps or 100, args.samples, args.blocks or [16_384, 65_536, 262_144],
               args.repeats, rng)
    else:
        speed(args.grasps or (20 if args.quick else 100), args.samples, args.repeats, rng)


if __name__ == "__main__":
    main()
