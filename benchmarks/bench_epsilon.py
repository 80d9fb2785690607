"""The certified epsilon against the 8-edge-pyramid Qhull Q1 of the dataset tools, one core.

On the same random grasps of the project's objects (grasp_fc_ros.objects: make_object,
sample_grasps; torques about the object's centre, the origin of its frame, divided by
L = the grasp's largest |p_i - c|), for n = 4 and 6 contacts and mu = 0.5 and tan 10 deg:

* ``epsilon_quality`` at ``--rtol`` (default 1e-3), all grasps of a cell in one call;
* the peer: the Q1 that DexGraspBench (q1.py) and BODex (chq1.py) compute, written out
  as they do it (grasp_fc_ros.experiment.epsilon_study.pyramid_q1): per contact 8 edges
  of unit normal force at radius mu (inscribed), Qhull (scipy's ConvexHull) of the 8 n
  wrench points and the origin, least facet offset (0 when the origin is not strictly
  inside), one grasp per Qhull call.

Grasps per second are medians of ``--repeats`` runs, ours and the peer's interleaved,
in CPU seconds of this process (BLAS and numba on one thread), so that other processes
on a shared machine do not inflate them. Also counted, per cell: grasps where the
pyramid Q1 exceeds the certified upper bound (the pyramid is inside W, so this must be
0), inconsistencies with the verdicts of check_force_closure (lower > 0 for a grasp
that is not force closure, upper <= 0 for one that is; must be 0), grasps not
converged, and the force-closure grasps the pyramid scores 0.

    python benchmarks/bench_epsilon.py             # 100 grasps per object and cell
    python benchmarks/bench_epsilon.py --quick     # a few seconds (the smoke test)
"""

import os

# One core, as the targets are stated: keep BLAS and numba from spreading over both.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable, Sequence  # noqa: E402
from functools import partial  # noqa: E402
from typing import Any, TypeVar  # noqa: E402

import numpy as np  # noqa: E402

from grasp_fc_ros.core import EpsilonResult, epsilon_quality  # noqa: E402
from grasp_fc_ros.experiment.epsilon_study import pyramid_q1_batch  # noqa: E402
from grasp_fc_ros.objects import OBJECT_NAMES, make_object, sample_grasps  # noqa: E402
from timing import MU_PAPER, ratio_or_nan  # noqa: E402

FINGERS = (4, 6)
FRICTIONS = (0.5, MU_PAPER)
#: The dataset tools' pyramid: 8 edges.
PEER_EDGES = 8
#: Target of issue 21: at least this many times the peer's grasps per second.
TARGET_RATIO = 10.0


Result = TypeVar("Result")


def cell_grasps(n_fingers: int, per_object: int, objects: Sequence[str],
                seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The same random grasps for every friction of a finger count: (positions,
    normals), each (N, n, 3), drawn object by object."""
    rng = np.random.default_rng(seed + n_fingers)
    drawn = [sample_grasps(make_object(name), per_object, n_fingers, rng) for name in objects]
    return (np.concatenate([p for p, _ in drawn]), np.concatenate([n for _, n in drawn]))


def cpu_seconds(function: Callable[[], Result]) -> tuple[float, Result]:
    start = time.process_time()
    result = function()
    return time.process_time() - start, result


def measure(positions: np.ndarray, normals: np.ndarray, mu: float, rtol: float,
            repeats: int) -> dict[str, Any]:
    """One cell: medians of our and the peer's CPU seconds (interleaved), and counts."""
    centre = np.zeros(3)
    epsilon_quality(positions[:2], normals[:2], mu, rtol=rtol)   # compile or load the cache
    ours: list[float] = []
    peer: list[float] = []
    result: EpsilonResult | None = None
    q1: np.ndarray | None = None
    for _ in range(repeats):
        seconds, found = cpu_seconds(partial(epsilon_quality, positions, normals, mu,
                                             center=centre, rtol=rtol))
        ours.append(seconds)
        seconds, q1 = cpu_seconds(partial(pyramid_q1_batch, positions, normals, mu, centre,
                                          found.torque_scale, PEER_EDGES))
        peer.append(seconds)
        result = found
    assert result is not None and q1 is not None, "repeats must be at least 1"
    fc = result.force_closure
    inconsistent = int(np.sum((result.lower > 0) & ~fc) + np.sum(fc & ~(result.upper > 0)))
    with np.errstate(divide="ignore", invalid="ignore"):
        error = np.where(fc, (result.lower - q1) / result.lower, np.nan)
    return {
        "n": positions.shape[1], "mu": mu, "grasps": positions.shape[0],
        "fc": float(fc.mean()),
        "ours": positions.shape[0] / statistics.median(ours),
        "peer": positions.shape[0] / statistics.median(peer),
        "violations": int(np.sum(q1 > result.upper)),
        "inconsistent": inconsistent,
        "not_converged": int(np.sum(~result.converged)),
        "pyramid_zero": int(np.sum(fc & (q1 == 0))),
        "median_error": float(np.nanmedian(error)) if fc.any() else float("nan"),
        "points": float(result.support_points[fc].mean()) if fc.any() else 0.0,
    }


def print_rows(rows: Sequence[dict[str, Any]], rtol: float) -> None:
    print(f"epsilon_quality (rtol {rtol:g}) vs the {PEER_EDGES}-edge pyramid Qhull Q1; "
          "CPU time, one thread; medians")
    header = (f"{'n':>2} {'mu':>6} {'grasps':>6} {'fc':>5} {'ours/s':>8} {'peer/s':>7} "
              f"{'ratio':>6} {'violations':>10} {'inconsistent':>12} {'unconverged':>11} "
              f"{'pyr0':>5} {'med.err':>8} {'points':>6}")
    print(header)
    print("-" * len(header))
    for r in rows:
        print(f"{r['n']:>2} {r['mu']:>6.3f} {r['grasps']:>6} {r['fc']:>5.2f} {r['ours']:>8.0f} "
              f"{r['peer']:>7.1f} {ratio_or_nan(r['ours'], r['peer']):>6.1f} "
              f"{r['violations']:>10} {r['inconsistent']:>12} {r['not_converged']:>11} "
              f"{r['pyramid_zero']:>5} {r['median_error']:>8.4f} {r['points']:>6.1f}")
    ratios = [ratio_or_nan(r["ours"], r["peer"]) for r in rows]
    print(f"least ratio {min(ratios):.1f} (target >= {TARGET_RATIO:g}); violations "
          f"{sum(r['violations'] for r in rows)}, inconsistencies "
          f"{sum(r['inconsistent'] for r in rows)}")
    print("(fc: share of force-closure grasps; pyr0: force-closure grasps whose pyramid Q1 "
          "is 0; med.err: median of (lower - Q1) / lower over force-closure grasps; points: "
          "mean support points per force-closure grasp)")


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--per-object", type=int, default=100,
                        help="grasps per object and cell")
    parser.add_argument("--objects", nargs="+", default=list(OBJECT_NAMES),
                        choices=OBJECT_NAMES)
    parser.add_argument("--rtol", type=float, default=1e-3)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quick", action="store_true",
                        help="8 grasps per object on three objects, one repeat")
    args = parser.parse_args(argv)
    if args.quick:
        args.per_object, args.objects, args.repeats = 8, ["box", "ellipsoid", "mug"], 1
    rows = []
    for n_fingers in FINGERS:
        positions, normals = cell_grasps(n_fingers, args.per_object, args.objects, args.seed)
        for mu in FRICTIONS:
            rows.append(measure(positions, normals, mu, args.rtol, args.repeats))
    print_rows(rows, args.rtol)


if __name__ == "__main__":
    main()
