"""Console script ``grasp-fc-experiment``: the paper's Tables I and II, the peer, plots.

Example::

    grasp-fc-experiment --out bench_out            # paper size: 100,000 grasps per object
    grasp-fc-experiment --quick --out /tmp/quick   # small version (the test suite runs it)
    grasp-fc-experiment --objects mug --mesh part.stl --fingers 4 --grasps 20000
    grasp-fc-experiment --epsilon-only --epsilon-grasps 1000 --out bench_out/epsilon
    grasp-fc-experiment --robustness-only --out bench_out/robustness
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from grasp_fc_ros.cli_arguments import positive_float, positive_int
from grasp_fc_ros.objects import (
    OBJECT_NAMES,
    Contacts,
    ContactSurface,
    load_surface,
    make_object,
)

if TYPE_CHECKING:
    from .measure import ObjectResult

DEFAULT_OBJECTS = ("box", "ellipsoid", "torus", "l_block", "star_prism", "mug")
DEFAULT_MU = math.tan(math.radians(10.0))
DEFAULT_SIDES_SWEEP = (4, 6, 8, 12, 16)
FINGER_RANGE = (3, 12)
# Object drawn in the example figure when measured (its shape reads best in 3-D).
EXAMPLE_OBJECT = "torus"
# Grasps drawn to find the example force-closure and rejected grasps.
EXAMPLE_GRASPS = 400

# Full-size defaults, and the --quick ones (explicit flags override both).
FULL = {"grasps": 100_000, "points": 5000, "peer_grasps": 500, "sides_grasps": 50,
        "sides_pool": 1000, "sweep_grasps": 500, "label_grasps": 2000, "soft_grasps": 1000,
        "epsilon_grasps": 500, "robustness_grasps": 500, "robustness_samples": 1000,
        "reference_samples": 2000}
QUICK = {"grasps": 300, "points": 1000, "peer_grasps": 20, "sides_grasps": 4,
         "sides_pool": 100, "sweep_grasps": 30, "label_grasps": 20, "soft_grasps": 20,
         "epsilon_grasps": 12, "robustness_grasps": 16, "robustness_samples": 50,
         "reference_samples": 100}


def _finger_count(text: str) -> int:
    value = int(text)
    if value < 2:
        raise argparse.ArgumentTypeError(f"a grasp needs at least 2 fingers, got {value}")
    return value


def _int_list(text: str) -> list[int]:
    try:
        values = [int(part) for part in text.split(",") if part]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated integers, got {text!r}") from None
    if not values or min(values) < 3:
        raise argparse.ArgumentTypeError(f"need integers >= 3, got {text!r}")
    return values


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="grasp-fc-experiment",
        description="Reproduce the seed paper's experiment (Tables I and II): time the exact "
                    "force-closure test with and without the torque filter on random grasps, "
                    "compare with a linearized (pyramid + Qhull) peer, and plot the results.")
    parser.add_argument("--objects", nargs="*", choices=OBJECT_NAMES, default=None,
                        help=f"built-in objects (default: {' '.join(DEFAULT_OBJECTS)}; "
                             "pass no names with --mesh to use only meshes)")
    parser.add_argument("--mesh", action="append", default=[], metavar="PATH",
                        help="mesh (.obj/.stl/.ply) or point cloud with outward normals "
                             "(.npz/.ply) to add as an object; repeatable")
    parser.add_argument("--fingers", type=_finger_count, default=6,
                        help="contacts per grasp (default 6, as in the paper)")
    parser.add_argument("--mu", type=positive_float, default=DEFAULT_MU,
                        help="friction coefficient (default tan 10 deg = 0.1763)")
    parser.add_argument("--grasps", type=positive_int,
                        help=f"grasps per object (default {FULL['grasps']:,}; "
                             f"quick {QUICK['grasps']})")
    parser.add_argument("--points", type=positive_int,
                        help=f"surface points per object (default {FULL['points']})")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--out", type=Path, default=Path("bench_out"),
                        help="output folder (default ./bench_out)")
    parser.add_argument("--quick", action="store_true",
                        help="small, fast version (smoke test; numbers are not meaningful)")
    parser.add_argument("--peer-grasps", type=positive_int,
                        help="grasps per object given to the slow linearized peer "
                             f"(default {FULL['peer_grasps']}; milliseconds a grasp)")
    parser.add_argument("--peer-sides", type=positive_int, default=8,
                        help="pyramid sides of the peer in the main comparison (default 8)")
    parser.add_argument("--sides-sweep", type=_int_list, default=list(DEFAULT_SIDES_SWEEP),
                        help="pyramid sides for the peer sweep (default 4,6,8,12,16)")
    parser.add_argument("--sides-grasps", type=positive_int,
                        help="force-closure grasps per object in the pyramid-sides sweep, "
                             "plus a fifth as many others "
                             f"(default {FULL['sides_grasps']})")
    parser.add_argument("--sides-pool", type=positive_int,
                        help="random grasps per object the sides sweep picks them from "
                             f"(default {FULL['sides_pool']})")
    parser.add_argument("--jobs", type=positive_int, default=1,
                        help="objects measured in parallel processes (default 1; each timed "
                             "call stays single-threaded, so use at most one job per free core)")
    parser.add_argument("--sweep-grasps", type=positive_int,
                        help="grasps per object and finger count in the throughput sweep "
                             f"over n = {FINGER_RANGE[0]}..{FINGER_RANGE[1]} "
                             f"(default {FULL['sweep_grasps']})")
    parser.add_argument("--label-grasps", type=positive_int,
                        help="grasps per object labelled with their minimum friction mu* "
                             f"(default {FULL['label_grasps']})")
    parser.add_argument("--soft-grasps", type=positive_int,
                        help="grasps per object and finger count in the soft-finger sweep "
                             f"(default {FULL['soft_grasps']})")
    parser.add_argument("--epsilon-grasps", type=positive_int,
                        help="grasps per object whose exact Ferrari-Canny epsilon is compared "
                             "with the 4- and 8-edge pyramid Q1 of dataset tools "
                             f"(default {FULL['epsilon_grasps']})")
    parser.add_argument("--epsilon-only", action="store_true",
                        help="run only the epsilon comparison (writes "
                             "epsilon.csv, epsilon_vs_pyramids.png, epsilon_report.md)")
    parser.add_argument("--robustness-grasps", type=positive_int,
                        help="random 4-finger grasps per object in the robustness study "
                             "(radii, probability, margin and epsilon ranked; default "
                             f"{FULL['robustness_grasps']})")
    parser.add_argument("--robustness-samples", type=positive_int,
                        help="samples per grasp of its probability of force closure "
                             f"(default {FULL['robustness_samples']})")
    parser.add_argument("--reference-samples", type=positive_int,
                        help="samples of the reference labels against Dex-Net's 25 "
                             f"(default {FULL['reference_samples']})")
    parser.add_argument("--robustness-only", action="store_true",
                        help="run only the robustness study (writes robustness.csv, "
                             "robustness.png, robustness_report.md)")
    return parser


def resolve_settings(args: argparse.Namespace) -> argparse.Namespace:
    """Fill the size options left unset from the full or the quick defaults."""
    defaults = QUICK if args.quick else FULL
    for key, value in defaults.items():
        if getattr(args, key) is None:
            setattr(args, key, value)
    if args.objects is None:
        args.objects = list(DEFAULT_OBJECTS)
    if not args.objects and not args.mesh:
        raise SystemExit("grasp-fc-experiment: no objects (give --objects names or --mesh)")
    return args


def load_objects(args: argparse.Namespace) -> list[ContactSurface]:
    surfaces = [make_object(name, n_points=args.points, seed=args.seed) for name in args.objects]
    for path in args.mesh:
        try:
            surfaces.append(load_surface(path, n_points=args.points, seed=args.seed))
        except (OSError, ValueError) as error:
            raise SystemExit(f"grasp-fc-experiment: {error}") from error
    too_small = [s.name for s in surfaces if len(s) < args.fingers]
    if too_small:
        raise SystemExit(f"grasp-fc-experiment: fewer than {args.fingers} points on "
                         f"{', '.join(too_small)}")
    return surfaces


def _stream(seed: int, *keys: int) -> np.random.Generator:
    """Independent, reproducible random stream for one part of the experiment."""
    return np.random.default_rng([seed, *keys])


def pick_example(surfaces: Sequence[ContactSurface], n_fingers: int, mu: float,
                 seed: int) -> tuple[ContactSurface, Contacts, Contacts] | None:
    """A surface with one force-closure grasp and one filter-rejected grasp, or None."""
    from grasp_fc_ros.core import check_force_closure
    from grasp_fc_ros.objects import sample_grasps

    preferred = sorted(surfaces, key=lambda s: s.name != EXAMPLE_OBJECT)
    for surface in preferred:
        positions, normals = sample_grasps(surface, EXAMPLE_GRASPS, n_fingers,
                                           _stream(seed, 3))
        result = check_force_closure(positions, normals, mu, use_filter=True)
        fc = np.flatnonzero(result.force_closure)
        rejected = np.flatnonzero(result.filtered_out)
        if fc.size and rejected.size:
            return surface, (positions[fc[0]], normals[fc[0]]), \
                (positions[rejected[0]], normals[rejected[0]])
    return None


def _measure_one(surface: ContactSurface, index: int, args: argparse.Namespace) -> ObjectResult:
    from . import measure

    result = measure.measure_object(surface, args.fingers, args.mu, args.grasps,
                                    _stream(args.seed, 0, index), args.peer_grasps,
                                    args.peer_sides)
    print(f"[{surface.name}] unfiltered {result.unfiltered.wall_s:.1f} s, filtered "
          f"{result.seed.wall_s:.1f} s, speedup {result.speedup:.2f}, specificity "
          f"{result.seed.specificity:.3f}", file=sys.stderr, flush=True)
    return result


def measure_objects(surfaces: Sequence[ContactSurface],
                    args: argparse.Namespace) -> list[ObjectResult]:
    """Tables I and II for every surface, in args.jobs processes; results in input order."""
    print(f"{len(surfaces)} objects x {args.grasps:,} grasps, {args.jobs} job(s) ...",
          file=sys.stderr, flush=True)
    if args.jobs == 1:
        return [_measure_one(s, i, args) for i, s in enumerate(surfaces)]
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        futures = [pool.submit(_measure_one, s, i, args) for i, s in enumerate(surfaces)]
        return [future.result() for future in futures]


def run(args: argparse.Namespace) -> tuple[Path, list[str]]:
    """Run everything and write the outputs into args.out.

    Returns
    -------
    report_path : pathlib.Path
    problems : list of str
        Soundness violations found (the filter changed a verdict); empty when sound.
    """
    from . import measure, plots, quality, report

    start = time.perf_counter()
    surfaces = load_objects(args)
    args.out.mkdir(parents=True, exist_ok=True)
    results = measure_objects(surfaces, args)
    print("throughput against fingers ...", file=sys.stderr, flush=True)
    finger_rows = measure.finger_sweep(surfaces, range(FINGER_RANGE[0], FINGER_RANGE[1] + 1),
                                       args.mu, args.sweep_grasps, _stream(args.seed, 1))
    print("peer against pyramid sides ...", file=sys.stderr, flush=True)
    sides_rows = measure.sides_sweep(surfaces, args.fingers, args.mu, args.sides_sweep,
                                     args.sides_grasps, args.sides_pool, _stream(args.seed, 2))

    print("minimum friction labels, soft fingers ...", file=sys.stderr, flush=True)
    labels = quality.friction_labels(surfaces, args.label_grasps, _stream(args.seed, 4))
    soft_rows = quality.soft_sweep(surfaces, args.soft_grasps, _stream(args.seed, 5))
    epsilon_lines, epsilon_problems = _epsilon_part(surfaces, args)
    robustness_lines = _robustness_part(surfaces, args)

    out = args.out
    report.write_csv(out / report.FRICTION_LABELS_CSV, report.friction_label_rows(labels))
    report.write_csv(out / report.SOFT_SWEEP_CSV, [report.soft_row(r) for r in soft_rows])
    report.write_csv(out / report.RESULTS_CSV, [report.result_row(r) for r in results])
    report.write_csv(out / report.FINGERS_CSV, [report.finger_row(r) for r in finger_rows])
    report.write_csv(out / report.PEER_SIDES_CSV,
                     [report.sides_row(r) for r in sides_rows])
    names = dict(report.PLOTS)
    plots.plot_speedup(results, out / names["speedup"])
    plots.plot_specificity(results, out / names["specificity"])
    plots.plot_finger_sweep(finger_rows, out / names["fingers"])
    plots.plot_peer_sides(sides_rows, out / names["peer_sides"])
    plots.plot_friction_labels(labels, out / names["friction_labels"])
    plots.plot_soft_sweep(soft_rows, out / names["soft_sweep"])
    example = pick_example(surfaces, args.fingers, args.mu, args.seed)
    if example is None:
        del names["grasp_example"]
    else:
        plots.plot_grasp_example(*example, args.mu, out / names["grasp_example"])
    total = time.perf_counter() - start
    text = report.markdown_report(results, finger_rows, sides_rows,
                                  {"command": report.command_line(), "seed": args.seed,
                                   "jobs": args.jobs},
                                  total, names,
                                  report.quality_section(labels, soft_rows, quality.SOFT_SWEEP_MU)
                                  + epsilon_lines + robustness_lines)
    path = out / report.REPORT_MD
    path.write_text(text)
    problems = report.soundness_problems(results) + epsilon_problems
    for line in problems:
        print(f"SOUNDNESS VIOLATION: {line}", file=sys.stderr)
    print(f"report: {path} ({total:.1f} s)", file=sys.stderr)
    return path, problems


def _epsilon_part(surfaces: Sequence[ContactSurface],
                  args: argparse.Namespace) -> tuple[list[str], list[str]]:
    """The epsilon comparison: writes its CSV and plot into args.out; returns the report's
    markdown lines and the soundness problems (a pyramid Q1 above a certified upper
    bound)."""
    from . import epsilon_study, plots, report

    print("exact epsilon against pyramid Q1 ...", file=sys.stderr, flush=True)
    comparisons = epsilon_study.compare_objects(surfaces, args.epsilon_grasps, args.fingers,
                                                args.mu, _stream(args.seed, 6))
    rows = epsilon_study.summary_rows(comparisons)
    report.write_csv(args.out / report.EPSILON_CSV, [report.epsilon_row(r) for r in rows])
    plots.plot_epsilon_comparison(comparisons, epsilon_study.EDGE_COUNTS,
                                  args.out / report.PLOTS["epsilon"])
    problems = [f"{r['object']}, {r['edges']} edges: the pyramid Q1 exceeds the certified "
                f"upper bound on {r['above_upper']} grasps"
                for r in rows if r["object"] != "all" and r["above_upper"]]
    lines = report.epsilon_section(rows, args.fingers, args.mu)
    return lines + [f"![epsilon against pyramid Q1]({report.PLOTS['epsilon']})", ""], problems


def _robustness_part(surfaces: Sequence[ContactSurface], args: argparse.Namespace) -> list[str]:
    """The robustness study: writes its CSV and plot into args.out; returns the report's
    markdown lines."""
    from . import plots, report, robustness_study

    print("robustness: radii, probability, margin and epsilon ...", file=sys.stderr,
          flush=True)
    objects = robustness_study.measure_objects(
        surfaces, args.robustness_grasps, args.robustness_samples, _stream(args.seed, 7),
        args.reference_samples)
    rows = robustness_study.summary_rows(objects)
    report.write_csv(args.out / report.ROBUSTNESS_CSV, [report.epsilon_row(r) for r in rows])
    plots.plot_robustness(objects, args.out / report.PLOTS["robustness"])
    lines = report.robustness_section(objects, rows, args.robustness_samples,
                                      args.reference_samples)
    return lines + [f"![robustness against epsilon]({report.PLOTS['robustness']})", ""]


def run_epsilon_only(args: argparse.Namespace) -> tuple[Path, list[str]]:
    """Only the epsilon comparison, with its own short report; returns (path, problems)."""
    from . import report

    start = time.perf_counter()
    surfaces = load_objects(args)
    args.out.mkdir(parents=True, exist_ok=True)
    lines, problems = _epsilon_part(surfaces, args)
    path = _short_report(args.out / report.EPSILON_REPORT_MD,
                         "Exact epsilon against the pyramid Q1", lines, start)
    for line in problems:
        print(f"SOUNDNESS VIOLATION: {line}", file=sys.stderr)
    return path, problems


def run_robustness_only(args: argparse.Namespace) -> Path:
    """Only the robustness study, with its own short report; returns its path."""
    from . import report

    start = time.perf_counter()
    surfaces = load_objects(args)
    args.out.mkdir(parents=True, exist_ok=True)
    lines = _robustness_part(surfaces, args)
    return _short_report(args.out / report.ROBUSTNESS_REPORT_MD,
                         "Robustness of force closure: the study", lines, start)


def _short_report(path: Path, title: str, lines: list[str], start: float) -> Path:
    """Write a part's report: ``title``, its lines, the machine, the time, the command."""
    from . import report

    total = time.perf_counter() - start
    path.write_text("\n".join([f"# {title}", ""] + lines + [
        f"Machine: {report.machine_description()}; code: {report.code_version()}; "
        f"{total:.0f} s.", "", f"Reproduce: `{report.command_line()}`", ""]))
    print(f"report: {path} ({total:.1f} s)", file=sys.stderr)
    return path


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; exit status 1 if the filter changed any verdict or a pyramid Q1
    exceeded a certified epsilon bound, else 0."""
    args = resolve_settings(build_parser().parse_args(argv))
    if args.robustness_only:
        run_robustness_only(args)
        return 0
    _, problems = run_epsilon_only(args) if args.epsilon_only else run(args)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
