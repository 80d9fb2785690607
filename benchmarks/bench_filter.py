"""Benchmark of the torque filter against the exact test, per contact count: does it pay?

For random n-finger grasps on a built-in object and each friction coefficient, prints
the filter's cost per grasp, the exact test's cost per grasp (today's Clarabel path,
no filter), the filter's hit rate (the share of grasps it rejects, each of which saves
one exact test), and the net saving per grasp, hit rate x exact cost - filter cost.
The filter pays where the saving is positive. The last lines give the largest n at
which it paid for every mu, the number that ``FILTER_PAYS_UP_TO_CONTACTS`` in
``grasp_fc_ros.core.filter.torque_space_filter`` holds. With ``--paths`` it also times the two
positive-span algorithms (pair test and convex hull) per grasp, for
``HULL_MIN_VECTORS`` in ``grasp_fc_ros.core.filter.positive_span``; with ``--large`` it times
one grasp of up to 10,000 contacts (the node's largest) through each stage.

Figures are medians over ``--repeats`` runs in this one process, on one core.

    python benchmarks/bench_filter.py            # n = 3..64, mu = 0.01, tan 10 deg, 0.5
    python benchmarks/bench_filter.py --quick    # fewer sizes and grasps, seconds
"""

import os

# One core: keep BLAS from spreading over both.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
from collections.abc import Sequence  # noqa: E402
from functools import partial  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

from grasp_fc_ros.core.filter import positive_span  # noqa: E402
from grasp_fc_ros.core.filter.torque_space_filter import passes_torque_filter  # noqa: E402
from grasp_fc_ros.core.model.grasp_input import prepare_grasps  # noqa: E402
from grasp_fc_ros.core.pipeline import run_pipeline  # noqa: E402
from grasp_fc_ros.objects import (  # noqa: E402
    OBJECT_NAMES,
    ContactSurface,
    make_object,
    sample_grasps,
)
from timing import MU_PAPER, median_seconds  # noqa: E402

MUS = (0.01, MU_PAPER, 0.5)
CONTACTS = (3, 4, 5, 6, 8, 10, 12, 14, 16, 20, 24, 32, 48, 64)
QUICK_CONTACTS = (4, 6, 8, 12, 16, 32)


def grasp_counts(n_contacts: int, scale: float) -> tuple[int, int]:
    """Grasps for the filter and for the exact test: fewer as n grows (cost ~ n)."""
    return (max(64, int(scale * 4000 * 6 / n_contacts)),
            max(16, int(scale * 400 * 6 / n_contacts)))


def measure(surface: ContactSurface, n_contacts: int, mu: float, scale: float, repeats: int,
            origins: str, rng: np.random.Generator) -> dict[str, Any]:
    """One cell: filter and exact cost per grasp (ms), hit rate, saving (ms)."""
    filter_grasps, exact_grasps = grasp_counts(n_contacts, scale)
    positions, normals = sample_grasps(surface, filter_grasps, n_contacts, rng)
    grasps = prepare_grasps(positions, normals, mu)
    subset = prepare_grasps(positions[:exact_grasps], normals[:exact_grasps], mu)
    passed = passes_torque_filter(grasps, origins)
    filter_ms = 1e3 * median_seconds(lambda: passes_torque_filter(grasps, origins),
                                     repeats) / filter_grasps
    exact_ms = 1e3 * median_seconds(lambda: run_pipeline(subset, use_filter=False),
                                    max(1, repeats // 2)) / exact_grasps
    hit_rate = float(1.0 - passed.mean())
    return {"n": n_contacts, "mu": mu, "filter_ms": filter_ms, "exact_ms": exact_ms,
            "hit_rate": hit_rate, "saving_ms": hit_rate * exact_ms - filter_ms}


def measure_paths(surface: ContactSurface, contacts: Sequence[int], mu: float, scale: float,
                  repeats: int, rng: np.random.Generator) -> list[tuple[int, float, float]]:
    """Filter cost per grasp (ms) with the pair test and with the hull test."""
    rows: list[tuple[int, float, float]] = []
    for n_contacts in contacts:
        filter_grasps, _ = grasp_counts(n_contacts, scale)
        positions, normals = sample_grasps(surface, filter_grasps, n_contacts, rng)
        grasps = prepare_grasps(positions, normals, mu)
        cost: dict[str, float] = {}
        for name, hull_from in (("pair", 10**9), ("hull", 0)):
            positive_span.HULL_MIN_VECTORS = hull_from
            cost[name] = 1e3 * median_seconds(partial(passes_torque_filter, grasps),
                                              repeats) / filter_grasps
        rows.append((n_contacts, cost["pair"], cost["hull"]))
    return rows


def measure_large(surface: ContactSurface, contacts: Sequence[int],
                  rng: np.random.Generator) -> list[tuple[int, float, float]]:
    """One grasp per n: filter (seed origins, mu = 0.01) and exact test, seconds."""
    rows = []
    for n_contacts in contacts:
        positions, normals = sample_grasps(surface, 1, n_contacts, rng)
        grasps = prepare_grasps(positions, normals, 0.01)
        filter_s = median_seconds(partial(passes_torque_filter, grasps), 1)
        exact_s = median_seconds(partial(run_pipeline, grasps, use_filter=False), 1)
        rows.append((n_contacts, filter_s, exact_s))
    return rows


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer sizes and grasps")
    parser.add_argument("--object", default="box", choices=OBJECT_NAMES)
    parser.add_argument("--origins", default="seed", choices=("seed", "all"))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--contacts", type=int, nargs="+",
                        help=f"contact counts to measure (default {CONTACTS})")
    parser.add_argument("--scale", type=float,
                        help="fraction of the default grasp counts (default 1, --quick 0.25)")
    parser.add_argument("--paths", action="store_true",
                        help="also time the pair test against the hull test")
    parser.add_argument("--large", action="store_true",
                        help="also time one grasp of 128 .. 10,000 contacts")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    contacts = args.contacts or (QUICK_CONTACTS if args.quick else CONTACTS)
    scale = args.scale or (0.25 if args.quick else 1.0)
    rng = np.random.default_rng(args.seed)
    surface = make_object(args.object)
    default_hull_from = positive_span.HULL_MIN_VECTORS

    print(f"object {args.object!r}, origins {args.origins!r}; ms per grasp, medians of "
          f"{args.repeats}, one core (a shared machine: figures are noisy)")
    header = (f"{'n':>3} {'mu':>7} {'filter ms':>10} {'exact ms':>9} {'hit rate':>9} "
              f"{'saving ms':>10} {'pays':>5}")
    print(header)
    print("-" * len(header))
    pays_up_to: dict[float, list[tuple[int, bool]]] = {}
    for n_contacts in contacts:
        for mu in MUS:
            r = measure(surface, n_contacts, mu, scale, args.repeats, args.origins, rng)
            print(f"{r['n']:>3} {r['mu']:>7.4f} {r['filter_ms']:>10.4f} "
                  f"{r['exact_ms']:>9.4f} {r['hit_rate']:>9.3f} {r['saving_ms']:>10.4f} "
                  f"{'yes' if r['saving_ms'] > 0 else 'no':>5}", flush=True)
            pays_up_to.setdefault(mu, [])
            pays_up_to[mu].append((n_contacts, r["saving_ms"] > 0))
    for mu, cells in pays_up_to.items():
        largest = max((n for n, pays in cells if pays), default=None)
        print(f"mu {mu:.4f}: pays at n = {[n for n, pays in cells if pays]}, largest {largest}")
    every_mu = [n for n in contacts
                if all(dict(cells)[n] for cells in pays_up_to.values())]
    print(f"pays for every mu at n = {every_mu}")

    if args.paths:
        print("\npositive-span algorithm, filter ms per grasp at mu = 0.01 "
              f"(HULL_MIN_VECTORS is {default_hull_from}, i.e. n >= "
              f"{default_hull_from // 2 + 1})")
        print(f"{'n':>3} {'K':>4} {'pair ms':>9} {'hull ms':>9}")
        path_contacts = (6, 8, 10, 12, 14, 16, 18, 20, 24, 32)
        for n_contacts, pair, hull in measure_paths(surface, path_contacts, 0.01, scale,
                                                    args.repeats, rng):
            print(f"{n_contacts:>3} {2 * (n_contacts - 1):>4} {pair:>9.4f} {hull:>9.4f}")
        positive_span.HULL_MIN_VECTORS = default_hull_from

    if args.large:
        print("\none grasp of n contacts, mu = 0.01: seconds (filter seed origins, exact)")
        print(f"{'n':>6} {'filter s':>9} {'exact s':>9} {'ratio':>7}")
        for n_contacts, filter_s, exact_s in measure_large(
                surface, (128, 300, 1000, 3000, 10000), rng):
            print(f"{n_contacts:>6} {filter_s:>9.4f} {exact_s:>9.4f} "
                  f"{filter_s / exact_s:>7.3f}", flush=True)


if __name__ == "__main__":
    main()
