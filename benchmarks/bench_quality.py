"""Benchmark of grasp quality on one CPU core: minimum friction mu* and contact forces s*.

For random n-finger grasps on a built-in object it measures, in this one process:
the exact force-closure test with its margin certified to 1e-8, as ``check_force_closure``
runs it by default (the unit of cost), ``minimum_friction`` (margin 0 and
margin MARGIN_TOL) with its SOCP solves per grasp, and ``optimal_contact_forces`` for a
random unit wrench per grasp (mu = 0.5); grasps per second and cost ratios to one exact
test; how many s* grasps the fast stage decided and how many went on to Clarabel, and
s* on the Clarabel stage alone for comparison. Figures are medians over ``--repeats``
runs after one warm-up, in CPU seconds of this process (single-threaded: BLAS and numba
on one thread), so that other processes on a shared machine do not inflate them; on an
idle core wall time is the same.

    python benchmarks/bench_quality.py             # 2000 six-finger box grasps
    python benchmarks/bench_quality.py --quick     # a few seconds
"""

import os

# One core, as the targets are stated: keep BLAS from spreading over both.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable, Sequence  # noqa: E402
from typing import Any, TypeVar  # noqa: E402

import numpy as np  # noqa: E402

from grasp_fc_ros.core.exact.exact_test import solve_exact  # noqa: E402
from grasp_fc_ros.core.forces import grasp_forces  # noqa: E402
from grasp_fc_ros.core.forces.grasp_forces import optimal_contact_forces  # noqa: E402
from grasp_fc_ros.core.model.grasp_input import prepare_grasps  # noqa: E402
from grasp_fc_ros.core.quality.minimum_friction import minimum_friction_bounds  # noqa: E402
from grasp_fc_ros.core.tolerances import MARGIN_TOL  # noqa: E402
from grasp_fc_ros.objects import (  # noqa: E402
    OBJECT_NAMES,
    ContactSurface,
    make_object,
    sample_grasps,
)

MU = 0.5

Result = TypeVar("Result")


def median_seconds(function: Callable[[], Result], repeats: int) -> tuple[float, Result]:
    """Median CPU time of ``repeats`` calls after one untimed warm-up; and the last result."""
    result = function()
    times = []
    for _ in range(repeats):
        start = time.process_time()
        result = function()
        times.append(time.process_time() - start)
    return statistics.median(times), result


def clarabel_share(function: Callable[[], object]) -> int:
    """Grasps that ``function`` (an untimed call) sends to s*'s Clarabel stage: those the
    fast stage did not decide."""
    counted: list[int] = []
    stage = grasp_forces._clarabel_stage

    def counting(gmap: np.ndarray, *args: Any) -> Any:
        counted.append(gmap.shape[0])
        return stage(gmap, *args)

    # The same call, counted (the stage's full signature passes through *args).
    grasp_forces._clarabel_stage = counting  # type: ignore[assignment]
    try:
        function()
    finally:
        grasp_forces._clarabel_stage = stage
    return sum(counted)


def without_fast_stage(function: Callable[[], Result]) -> Callable[[], Result]:
    """``function`` run with s*'s fast stage deciding nothing: the Clarabel stage alone."""
    def run() -> Result:
        stage = grasp_forces._fast_stage
        grasp_forces._fast_stage = lambda unit, *args: (
            np.zeros(unit.shape[0]), np.zeros(unit.shape[:2] + (3,)),
            np.zeros(unit.shape[0], dtype=bool))
        try:
            return function()
        finally:
            grasp_forces._fast_stage = stage
    return run


def measure(surface: ContactSurface, n_fingers: int, n_grasps: int, repeats: int,
            rng: np.random.Generator) -> dict[str, Any]:
    positions, normals = sample_grasps(surface, n_grasps, n_fingers, rng)
    wrench = rng.normal(size=(n_grasps, 6))
    wrench /= np.linalg.norm(wrench, axis=1, keepdims=True)
    exact_s, fc = median_seconds(
        lambda: solve_exact(prepare_grasps(positions, normals, MU)).force_closure, repeats)
    mu_s, bounds = median_seconds(lambda: minimum_friction_bounds(positions, normals), repeats)
    tol_s, tol_bounds = median_seconds(
        lambda: minimum_friction_bounds(positions, normals, margin=MARGIN_TOL), repeats)
    forces_s, (s_star, _, _) = median_seconds(
        lambda: optimal_contact_forces(positions, normals, MU, wrench), repeats)
    fallback = clarabel_share(lambda: optimal_contact_forces(positions, normals, MU, wrench))
    slow_s, (slow_star, _, _) = median_seconds(without_fast_stage(
        lambda: optimal_contact_forces(positions, normals, MU, wrench)), repeats)
    both = np.isfinite(s_star) & np.isfinite(slow_star)
    differ = float(np.max(np.abs(s_star[both] - slow_star[both]) / slow_star[both],
                          initial=0.0))
    value = bounds.value
    return {
        "n": n_fingers, "grasps": n_grasps,
        "exact_ms": 1e3 * exact_s / n_grasps,
        "mu_ms": 1e3 * mu_s / n_grasps, "tol_ms": 1e3 * tol_s / n_grasps,
        "forces_ms": 1e3 * forces_s / n_grasps,
        "solves": bounds.solves, "tol_solves": tol_bounds.solves,
        "finite": float(np.isfinite(value).mean()), "zero": float((value == 0).mean()),
        "unresolved": int(np.isnan(value).sum()) + int(np.isnan(tol_bounds.value).sum()),
        "median_mu": float(np.median(value[np.isfinite(value)])) if np.isfinite(value).any()
        else float("nan"),
        "fc": float(fc.mean()), "held": float(np.isfinite(s_star).mean()),
        "forces_failed": int(np.isnan(s_star).sum()), "forces_fallback": fallback,
        "clarabel_ms": 1e3 * slow_s / n_grasps, "clarabel_failed": int(np.isnan(slow_star).sum()),
        "inf_differ": int((np.isinf(s_star) != np.isinf(slow_star)).sum()), "differ": differ,
    }


def print_rows(rows: Sequence[dict[str, Any]], object_name: str) -> None:
    print(f"\nobject {object_name!r}; medians of CPU time, one thread (exact test and s* at "
          f"mu = {MU})")
    header = (f"{'n':>3} {'grasps':>7} {'exact ms':>9} {'mu* ms':>8} {'mu*/s':>7} {'x exact':>8} "
              f"{'solves mean/med/max':>20} {'mu*tol ms':>10} {'s* ms':>7} {'x exact':>8}")
    print(header)
    print("-" * len(header))
    for r in rows:
        solves = r["solves"]
        print(f"{r['n']:>3} {r['grasps']:>7} {r['exact_ms']:>9.3f} {r['mu_ms']:>8.2f} "
              f"{1e3 / r['mu_ms']:>7.0f} {r['mu_ms'] / r['exact_ms']:>8.1f} "
              f"{solves.mean():>8.2f}/{np.median(solves):>4.0f}/{solves.max():>4d}   "
              f"{r['tol_ms']:>10.2f} {r['forces_ms']:>7.3f} "
              f"{r['forces_ms'] / r['exact_ms']:>8.2f}")
    for r in rows:
        print(f"n = {r['n']}: mu* finite {100 * r['finite']:.1f}%, 0 {100 * r['zero']:.1f}%, "
              f"median {r['median_mu']:.4f}, unresolved {r['unresolved']}; force closure at "
              f"mu = {MU}: {100 * r['fc']:.1f}%; unit wrench held {100 * r['held']:.1f}%, "
              f"s* solver failures {r['forces_failed']}; s* fast stage "
              f"{r['grasps'] - r['forces_fallback']}, Clarabel {r['forces_fallback']}")
    for r in rows:
        print(f"n = {r['n']}: s* on the Clarabel stage alone {r['clarabel_ms']:.3f} ms "
              f"({r['clarabel_ms'] / r['forces_ms']:.1f}x the two stages), solver failures "
              f"{r['clarabel_failed']}; inf on one side only {r['inf_differ']}, largest "
              f"relative difference of finite s* {r['differ']:.1e}")


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--object", default="box", choices=OBJECT_NAMES)
    parser.add_argument("--grasps", type=int, default=2000)
    parser.add_argument("--fingers", type=int, nargs="+", default=[6, 4])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quick", action="store_true", help="small sizes, one repeat")
    args = parser.parse_args(argv)
    if args.quick:
        args.grasps, args.repeats = 256, 1
    rng = np.random.default_rng(args.seed)
    surface = make_object(args.object)
    rows = [measure(surface, n, args.grasps, args.repeats, rng) for n in args.fingers]
    print_rows(rows, args.object)
    six = next((r for r in rows if r["n"] == 6), None)
    if six:
        print(f"\nsix fingers: mu* {1e3 / six['mu_ms']:.0f} grasps/s today "
              f"({six['mu_ms'] / six['exact_ms']:.1f} exact tests' time per grasp, "
              f"{six['solves'].mean():.2f} SOCP solves per grasp); "
              f"s* {six['forces_ms'] / six['exact_ms']:.2f}x one exact test (target <= 3)")


if __name__ == "__main__":
    main()
