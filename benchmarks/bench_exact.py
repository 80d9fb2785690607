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

With ``--against COMMIT`` (e.g. e89657b) it instead times this core's exact stage
(``exact_force_closure``: verdicts, the fast stage then Clarabel for what it leaves; and
with the margin certified to 1e-8, as ``check_force_closure`` asks by default) against
``exact_force_closure`` of that commit's ``grasp_fc_ros/core``, taken from the git
history into a temporary directory and imported under another name in this process:
the same grasps, CPU time, the two alternating, medians of ``--repeats``; ratios per
cell and the verdicts that differ from the old test's. Without the git history (no git,
not a checkout, unknown commit) it says so and exits 0.
"""

import os

# One core, as the targets are stated: keep BLAS from spreading over both.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import io  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tarfile  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable, Sequence  # noqa: E402
from pathlib import Path  # noqa: E402
from types import ModuleType  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

from grasp_fc_ros.core import check_force_closure, exact_force_closure, warm_up  # noqa: E402
from grasp_fc_ros.core.exact.certificates import normalise_positions  # noqa: E402
from grasp_fc_ros.core.exact.exact_test import solve_exact  # noqa: E402
from grasp_fc_ros.core.exact.interior_point import UNDECIDED, solve_fast  # noqa: E402
from grasp_fc_ros.core.model.grasp_input import prepare_grasps  # noqa: E402
from grasp_fc_ros.objects import ContactSurface, make_object, sample_grasps  # noqa: E402
from timing import MU_PAPER, median_seconds  # noqa: E402

MUS = (MU_PAPER, 0.5)


def measure_cell(surface: ContactSurface, n_fingers: int, mu: float, n_grasps: int,
                 repeats: int, rng: np.random.Generator) -> dict[str, Any]:
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


def one_grasp_latency(surface: ContactSurface, rng: np.random.Generator, calls: int,
                      **options: Any) -> float:
    positions, normals = sample_grasps(surface, calls, 6, rng)
    times: list[float] = []
    for g in range(calls):
        start = time.perf_counter()
        check_force_closure(positions[g], normals[g], MUS[0], **options)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def old_core(commit: str, where: str) -> ModuleType | str:
    """``grasp_fc_ros/core`` of ``commit`` from the git history of this checkout,
    unpacked under ``where`` and imported as the package ``core_<commit>``; or the reason
    it is not available (a str)."""
    root = Path(__file__).resolve().parents[1]
    try:
        archive = subprocess.run(["git", "-C", str(root), "archive", "--format=tar", commit,
                                  "grasp_fc_ros/core"], capture_output=True, check=True,
                                 timeout=120).stdout
    except (OSError, subprocess.SubprocessError) as error:
        detail = getattr(error, "stderr", b"") or b""
        return f"git history not available ({error}; {detail.decode(errors='replace').strip()})"
    with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
        tar.extractall(where, filter="data")
    name = f"core_{commit}"
    package = Path(where) / "grasp_fc_ros" / "core"
    spec = importlib.util.spec_from_file_location(
        name, package / "__init__.py", submodule_search_locations=[str(package)])
    if spec is None or spec.loader is None:
        return f"{package}: not an importable package"
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def cpu_seconds(function: Callable[[], object]) -> float:
    start = time.process_time()
    function()
    return time.process_time() - start


def against_cell(old: ModuleType, surface: ContactSurface, n_fingers: int, mu: float,
                 n_grasps: int, repeats: int, rng: np.random.Generator) -> dict[str, Any]:
    """This core's exact stage against the old commit's exact_force_closure on the same
    grasps, alternating, grasps/s (CPU): ``exact_force_closure`` (verdicts) and the exact
    stage with the margin certified to 1e-8 (``check_force_closure``'s default)."""
    positions, normals = sample_grasps(surface, n_grasps, n_fingers, rng)
    old_verdicts = old.exact_force_closure(positions, normals, mu)
    new_verdicts = exact_force_closure(positions, normals, mu)
    margin_verdicts = solve_exact(prepare_grasps(positions, normals, mu)).force_closure
    times: dict[str, list[float]] = {"old": [], "new": [], "margin": []}
    for _ in range(repeats):
        times["old"].append(cpu_seconds(lambda: old.exact_force_closure(positions, normals, mu)))
        times["new"].append(cpu_seconds(lambda: exact_force_closure(positions, normals, mu)))
        times["margin"].append(cpu_seconds(
            lambda: solve_exact(prepare_grasps(positions, normals, mu), "optimum")))
    rate = {key: n_grasps / statistics.median(value) for key, value in times.items()}
    return {"n": n_fingers, "mu": mu, **rate,
            "disagree": int(np.count_nonzero(new_verdicts != old_verdicts)
                            + np.count_nonzero(margin_verdicts != old_verdicts)),
            "fc_share": float(np.mean(old_verdicts))}


def run_against(commit: str, n_grasps: int, repeats: int, seed: int) -> None:
    with tempfile.TemporaryDirectory() as where:
        old = old_core(commit, where)
        if isinstance(old, str):
            print(f"--against {commit}: {old}; nothing measured")
            return
        warm_up()
        rng = np.random.default_rng(seed)
        surface = make_object("box")
        print(f"exact_force_closure against that of {commit} (Clarabel, 64 grasps per "
              f"solve), and this core's exact stage with the margin certified to 1e-8 "
              f"(check_force_closure's default); {n_grasps} box grasps per cell; CPU time, "
              f"one core, alternating, medians of {repeats}; grasps/s; target >= 30x")
        print(f"{'n':>2} {'mu':>6} {'FC%':>5} {commit:>9} {'verdicts':>9} {'ratio':>6} "
              f"{'+margin':>9} {'ratio':>6} {'disagree':>8}")
        for n_fingers in (4, 6, 8):
            for mu in MUS:
                cell = against_cell(old, surface, n_fingers, mu, n_grasps, repeats, rng)
                print(f"{cell['n']:>2} {cell['mu']:>6.3f} {100 * cell['fc_share']:>5.1f} "
                      f"{cell['old']:>9.0f} {cell['new']:>9.0f} "
                      f"{cell['new'] / cell['old']:>5.1f}x {cell['margin']:>9.0f} "
                      f"{cell['margin'] / cell['old']:>5.1f}x {cell['disagree']:>8d}",
                      flush=True)


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="500 grasps per cell")
    parser.add_argument("--grasps", type=int, default=4000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--calls", type=int, default=0,
                        help="one-grasp latency calls (default 2000, --quick 200)")
    parser.add_argument("--against", metavar="COMMIT",
                        help="time the exact stage against this commit's exact_force_closure")
    args = parser.parse_args(argv)
    n_grasps = 500 if args.quick else args.grasps
    if args.against:
        run_against(args.against, n_grasps, args.repeats, args.seed)
        return
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
