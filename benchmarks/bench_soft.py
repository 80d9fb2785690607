"""Soft-finger contacts: filter soundness on many random grasps, and what soft costs.

1. Soundness: random grasps of 2 to 6 contacts on an ellipsoid, each contact soft
   (gamma up to 0.3 of the object's size) with probability 1/2, half of the 2-contact
   ones antipodal. Every grasp the filter rejects (seed and all origins) is decided by
   the exact test with its torsional friction; the count of force-closure grasps
   rejected must be 0. Default 100,000 grasps.
2. Cost per grasp (ms, medians of ``--repeats`` in this process, one core): the exact
   test of hard grasps (fast stage), of the same grasps with gamma = 0 given explicitly
   (the hard path too), and soft (every contact soft: the Clarabel path), and the
   filter on hard and on soft grasps with its hit rates (hard, all contacts soft, about
   half of them soft).

    python benchmarks/bench_soft.py                # 100,000 grasps, n = 3, 4, 6
    python benchmarks/bench_soft.py --grasps 2000 --cost-grasps 200   # seconds
    python benchmarks/bench_soft.py --quick        # the smoke test's form
"""

import os

# One core: keep BLAS from spreading over both.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
from collections.abc import Callable, Sequence  # noqa: E402
from typing import Any, cast  # noqa: E402

import numpy as np  # noqa: E402

from grasp_fc_ros.core import exact_force_closure, torque_filter, warm_up  # noqa: E402
from timing import median_seconds  # noqa: E402

MU = 0.3
CHUNK = 5000


def passed(*args: Any, **kwargs: Any) -> np.ndarray:
    """:func:`torque_filter`'s verdicts (N,): True where a grasp passes (without
    certificates it returns the verdicts alone)."""
    return cast(np.ndarray, torque_filter(*args, **kwargs))


def random_soft_grasps(rng: np.random.Generator, n_grasps: int,
                       n_contacts: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ellipsoid grasps (axes 1, 2, 3) with gamma on about half of the contacts."""
    axes = np.array([1.0, 2.0, 3.0])
    direction = rng.normal(size=(n_grasps, n_contacts, 3))
    direction /= np.linalg.norm(direction, axis=2, keepdims=True)
    positions = direction * axes
    normals = -positions / axes ** 2
    normals /= np.linalg.norm(normals, axis=2, keepdims=True)
    if n_contacts == 2:
        positions[::2, 1] = -positions[::2, 0]
        normals[::2, 1] = -normals[::2, 0]
    gamma = rng.uniform(0.0, 0.9, (n_grasps, n_contacts))
    gamma *= rng.random((n_grasps, n_contacts)) < 0.5
    return positions, normals, gamma


def soundness(rng: np.random.Generator, n_grasps: int) -> tuple[int, int, int]:
    """(grasps, rejected, force-closure grasps rejected) over n = 2..6 contacts."""
    checked = rejected = wrong = 0
    while checked < n_grasps:
        size = min(CHUNK, n_grasps - checked)
        n_contacts = int(rng.integers(2, 7))
        positions, normals, gamma = random_soft_grasps(rng, size, n_contacts)
        for origins in ("seed", "all"):
            out = ~passed(positions, normals, MU, origins=origins,
                          torsional_friction=gamma)
            if out.any():
                wrong += int(exact_force_closure(positions[out], normals[out], MU,
                                                 torsional_friction=gamma[out]).sum())
            rejected += int(out.sum())
        checked += size
    return checked, rejected, wrong


def costs(rng: np.random.Generator, n_contacts: int, n_grasps: int,
          repeats: int) -> dict[str, float]:
    """ms per grasp of the exact test (hard, gamma = 0, soft) and the filter."""
    positions, normals, mixed = random_soft_grasps(rng, n_grasps, n_contacts)
    gamma = rng.uniform(0.05, 0.3, (n_grasps, n_contacts))
    zero = np.zeros_like(gamma)
    per_grasp = 1e3 / n_grasps

    def time(function: Callable[..., object], *args: Any, **kwargs: Any) -> float:
        return per_grasp * median_seconds(lambda: function(*args, **kwargs), repeats)

    result = {
        "hard": time(exact_force_closure, positions, normals, MU),
        "zero": time(exact_force_closure, positions, normals, MU, torsional_friction=zero),
        "soft": time(exact_force_closure, positions, normals, MU, torsional_friction=gamma),
        "filter_hard": time(torque_filter, positions, normals, MU),
        "filter_soft": time(torque_filter, positions, normals, MU, torsional_friction=gamma),
    }
    result["hit_hard"] = float((~passed(positions, normals, MU)).mean())
    result["hit_soft"] = float((~passed(positions, normals, MU,
                                        torsional_friction=gamma)).mean())
    result["hit_mixed"] = float((~passed(positions, normals, MU,
                                         torsional_friction=mixed)).mean())
    return result


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--grasps", type=int, default=100_000,
                        help="random soft grasps for the soundness count")
    parser.add_argument("--cost-grasps", type=int, default=1000)
    parser.add_argument("--contacts", type=int, nargs="+", default=[3, 4, 6])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quick", action="store_true",
                        help="the smoke test's form: 3000 grasps, costs of 40 at n = 4")
    args = parser.parse_args(argv)
    if args.quick:
        args.grasps, args.cost_grasps, args.contacts, args.repeats = 3000, 40, [4], 1
    rng = np.random.default_rng(args.seed)
    warm_up()

    checked, rejected, wrong = soundness(rng, args.grasps)
    print(f"soundness: {checked} random soft grasps (n = 2..6, mu = {MU}), "
          f"{rejected} filter rejections (seed + all origins), "
          f"force-closure grasps rejected: {wrong}", flush=True)

    print(f"\nms per grasp, medians of {args.repeats}, {args.cost_grasps} grasps, one core "
          "(a shared machine: figures are noisy)")
    header = (f"{'n':>3} {'exact hard':>11} {'gamma=0':>9} {'exact soft':>11} "
              f"{'soft/hard':>10} {'filter hard':>12} {'filter soft':>12} "
              f"{'hit hard':>9} {'hit soft':>9} {'hit half':>9}")
    print(header)
    print("-" * len(header))
    for n_contacts in args.contacts:
        r = costs(rng, n_contacts, args.cost_grasps, args.repeats)
        print(f"{n_contacts:>3} {r['hard']:>11.4f} {r['zero']:>9.4f} {r['soft']:>11.4f} "
              f"{r['soft'] / r['hard']:>10.1f} {r['filter_hard']:>12.4f} "
              f"{r['filter_soft']:>12.4f} {r['hit_hard']:>9.3f} {r['hit_soft']:>9.3f} "
              f"{r['hit_mixed']:>9.3f}",
              flush=True)
    return wrong


if __name__ == "__main__":
    raise SystemExit(1 if main() else 0)
