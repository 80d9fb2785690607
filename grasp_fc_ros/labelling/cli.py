"""Console script ``grasp-fc-label``: force-closure labels for many grasps, on Dask.

Examples::

    grasp-fc-label grasps.npz more.parquet --out labels/            # local cluster
    grasp-fc-label big.npz --out labels.parquet --scheduler tcp://10.0.0.5:8786
    grasp-fc-label --mesh part.stl --objects mug --grasps-per-object 100000 \\
        --fingers 4 --mu 0.5 --out dataset/
    grasp-fc-label grasps.npz --quality --out labels/        # + certified epsilon (Q1)
    grasp-fc-label grasps.npz --robustness --normal-sigma 0.05 --position-sigma 0.002 \
        --out labels/                    # + robustness radii and probability of closure

Exit status: 0 done, 2 bad input or usage (nothing written), 1 a failure while running
(the parts written so far are kept; the same command resumes).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING

from grasp_fc_ros.cli_arguments import (
    non_negative_float,
    non_negative_int,
    positive_float,
    positive_int,
)
from grasp_fc_ros.objects import DEFAULT_N_POINTS, OBJECT_NAMES

from .robustness import DEFAULT_CONFIDENCE, DEFAULT_SAMPLES, ERRORS, SIGMAS
from .runner import CHUNK_WORK, DEFAULT_CHUNK_SIZE

if TYPE_CHECKING:
    from .output import OutputConflict
    from .robustness import Robustness
    from .runner import Plan, Summary

#: --filter's choices, as check_force_closure's use_filter.
FILTER_CHOICES = {"auto": "auto", "on": True, "off": False}

PROG = "grasp-fc-label"
# The experiment's friction coefficient: tan 10 degrees.
DEFAULT_MU = 0.17632698070846498
DEFAULT_FINGERS = 6
DEFAULT_QUALITY_RTOL = 1e-3
#: The options behind each setting a run's manifest records (an output made with other
#: values is refused naming these, not the manifest's keys), in the order they are named.
SETTING_OPTIONS = {
    "sources": "the INPUT files (or --objects, --mesh and the options drawing on them)",
    "use_filter": "--filter", "origins": "--origins",
    "quality_rtol": "--quality/--quality-rtol", "robustness": "--robustness",
    **{f"robustness.{name}": "--" + name.replace("_", "-")
       for name in (*ERRORS, *SIGMAS, "samples", "confidence", "seed")},
    "chunk_size": "--chunk-size", "draw_block": "--chunk-size",
    "format": "the grasp-fc-label version that wrote it", "layout": "its layout"}
#: Settings whose default follows other options (the chunk size follows the columns):
#: not named when those differ too and the user left them to their default.
DERIVED_SETTINGS = ("chunk_size", "draw_block")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Label grasps as force closure or not, in chunks on a Dask cluster, "
                    "into Parquet. Inputs are .npz or Parquet files of grasps, or random "
                    "grasps drawn on objects (--objects/--mesh). See docs/labelling.md.")
    parser.add_argument("inputs", nargs="*", metavar="INPUT",
                        help=".npz (positions, normals, mu, optional ids) or .parquet "
                             "files; without ids, a grasp's id is its running index across "
                             "all inputs")
    parser.add_argument("--out", required=True,
                        help="output: a directory of Parquet parts, or a file ending in "
                             ".parquet; a re-run of the same command resumes it")
    objects = parser.add_argument_group("grasps drawn on objects (instead of INPUT files)")
    objects.add_argument("--mesh", nargs="+", default=[], metavar="FILE",
                         help="meshes (.obj/.stl/.ply) or point clouds with outward normals "
                              "(.npz/.ply)")
    objects.add_argument("--objects", nargs="+", default=[], choices=OBJECT_NAMES,
                         metavar="NAME", help=f"built-in objects: {', '.join(OBJECT_NAMES)}")
    objects.add_argument("--grasps-per-object", type=positive_int, metavar="K")
    objects.add_argument("--fingers", type=positive_int, default=DEFAULT_FINGERS,
                         help=f"contacts per grasp (default {DEFAULT_FINGERS})")
    objects.add_argument("--mu", type=positive_float, default=DEFAULT_MU,
                         help=f"friction coefficient (default tan 10 deg = {DEFAULT_MU:.4f})")
    objects.add_argument("--seed", type=non_negative_int, default=0,
                         help="random seed of the grasps drawn and of the probability's "
                              "noise (default 0)")
    objects.add_argument("--points", type=positive_int, default=DEFAULT_N_POINTS,
                         help=f"surface points sampled per object (default {DEFAULT_N_POINTS})")
    cluster = parser.add_argument_group("cluster and chunks")
    cluster.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                         help="an existing Dask scheduler (default: a local cluster)")
    cluster.add_argument("--scheduler-file", metavar="FILE",
                         help="an existing Dask scheduler, by the file that `dask scheduler "
                              "--scheduler-file FILE` wrote")
    cluster.add_argument("--workers", type=positive_int,
                         help="worker processes of the local cluster (default: the cores)")
    cluster.add_argument("--chunk-size", type=positive_int,
                         help=f"grasps per chunk and output part (default: by the columns' "
                              f"cost, {DEFAULT_CHUNK_SIZE:,} for the verdicts alone, "
                              f"{CHUNK_WORK:,} verdicts' worth for costlier columns: "
                              "docs/labelling.md); also the grasps drawn per random stream "
                              f"with --objects/--mesh (default {DEFAULT_CHUNK_SIZE:,})")
    cluster.add_argument("--filter", choices=sorted(FILTER_CHOICES), default="auto",
                         help="run the torque filter before the exact test: where it pays "
                              "for the contact count (auto, the default), always (on: "
                              "rejected grasps are labelled FILTERED_OUT) or never (off); "
                              "the verdicts are the same")
    cluster.add_argument("--origins", choices=("seed", "all"), default="seed",
                         help="torque origins of the filter (default seed)")
    cluster.add_argument("--no-progress", action="store_true", help="no progress line")
    quality = parser.add_argument_group("grasp quality")
    quality.add_argument("--quality", action="store_true",
                         help="also write the certified Ferrari-Canny epsilon (Q1 with "
                              "circular friction cones, normal forces summing to <= 1; torques "
                              "about the origin of the grasps' frame divided by each grasp's "
                              "largest contact distance from it): columns epsilon_lower and "
                              "epsilon_upper (lower <= epsilon <= upper, upper - lower <= "
                              "rtol * upper; lower 0 where not force closure) and "
                              "epsilon_direction (6 floats: the unit wrench whose support "
                              "value is upper). Its cost: docs/epsilon.md")
    quality.add_argument("--quality-rtol", type=positive_float, default=DEFAULT_QUALITY_RTOL,
                         help=f"relative accuracy of epsilon (default {DEFAULT_QUALITY_RTOL:g}; "
                              "down to 1e-6 and below, slower)")
    robust = parser.add_argument_group(
        "robustness to contact errors (docs/robustness.md)",
        "--robustness writes the certified radii normal_angle (rad), position_radius "
        "(positions' unit) and friction_drop; with errors, whether each grasp holds under "
        "them (holds, holds_name, holds_bound); with noise, its probability of force "
        "closure (probability_estimate, _lower, _upper, _successes, _undecided, "
        "_normal_lower_bound), each grasp's noise drawn from --seed and its id")
    robust.add_argument("--robustness", action="store_true",
                        help="also write the robustness columns")
    for name, unit in zip(ERRORS, ("positions' unit", "rad", "mu"), strict=True):
        robust.add_argument("--" + name.replace("_", "-"), type=non_negative_float,
                            metavar="E", help=f"{unit}: holds columns under this error")
    for name, unit in zip(SIGMAS, ("positions' unit", "rad", "mu"), strict=True):
        robust.add_argument("--" + name.replace("_", "-"), type=non_negative_float,
                            metavar="SIGMA", help=f"{unit}: probability columns under this "
                                                  "noise")
    robust.add_argument("--samples", type=positive_int,
                        help=f"Monte-Carlo samples per grasp (default {DEFAULT_SAMPLES:,})")
    robust.add_argument("--confidence", type=positive_float,
                        help=f"of the probability's Clopper-Pearson interval (default "
                             f"{DEFAULT_CONFIDENCE})")
    return parser


#: The options that only --robustness reads.
ROBUSTNESS_OPTIONS = (*ERRORS, *SIGMAS, "samples", "confidence")


def robustness_settings(args: argparse.Namespace) -> Robustness | None:
    """The :class:`~grasp_fc_ros.labelling.robustness.Robustness` of the parsed
    arguments, None without --robustness."""
    from .robustness import Robustness

    if not args.robustness:
        return None
    given = {name: getattr(args, name) for name in ROBUSTNESS_OPTIONS
             if getattr(args, name) is not None}
    return Robustness(**given, seed=args.seed)


def make_plan(args: argparse.Namespace) -> Plan:
    """The :class:`~grasp_fc_ros.labelling.runner.Plan` of the parsed arguments.

    Raises
    ------
    InputError
        A bad input file or object (checked on the client: keys, shapes, meshes).
    """
    from .runner import Plan
    from .sources import object_sources

    settings = {"chunk_size": args.chunk_size, "use_filter": FILTER_CHOICES[args.filter],
                "origins": args.origins,
                "quality_rtol": args.quality_rtol if args.quality else None,
                "robustness": robustness_settings(args)}
    if args.inputs:
        return Plan.from_files(args.inputs, **settings)
    return Plan(object_sources(args.objects, args.mesh, args.grasps_per_object, args.fingers,
                               args.mu, args.seed, args.points,
                               args.chunk_size or DEFAULT_CHUNK_SIZE), **settings)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    drawing = bool(args.mesh or args.objects)
    if args.inputs and drawing:
        parser.error("give INPUT files or --objects/--mesh, not both")
    if not args.inputs and not drawing:
        parser.error("nothing to label: give INPUT files, or --objects/--mesh")
    if drawing and args.grasps_per_object is None:
        parser.error("--objects/--mesh need --grasps-per-object")
    if args.scheduler and args.scheduler_file:
        parser.error("give --scheduler or --scheduler-file, not both")
    if (args.scheduler or args.scheduler_file) and args.workers:
        parser.error("--workers sets up a local cluster; it cannot go with a scheduler")
    if args.quality and not 1e-9 <= args.quality_rtol < 1:
        parser.error(f"--quality-rtol must be in [1e-9, 1), got {args.quality_rtol:g}")
    for name in ROBUSTNESS_OPTIONS:
        if getattr(args, name) is not None and not args.robustness:
            parser.error(f"--{name.replace('_', '-')} needs --robustness")
    if args.confidence is not None and not args.confidence < 1:
        parser.error(f"--confidence must be in (0, 1), got {args.confidence:g}")

    from .output import OutputConflict
    from .runner import TaskFailed, dask_client, run
    from .sources import InputError

    try:
        plan = make_plan(args)
        with dask_client(args.scheduler, args.workers, args.scheduler_file) as client:
            summary = run(plan, args.out, client, progress=not args.no_progress)
    except OutputConflict as error:
        print(f"{PROG}: error: {_conflict_message(error, args)}", file=sys.stderr)
        return 2
    except InputError as error:
        print(f"{PROG}: error: {error}", file=sys.stderr)
        return 2
    except (TaskFailed, OSError, TimeoutError) as error:
        print(f"{PROG}: failed: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted; the same command resumes", file=sys.stderr)
        return 130
    _report(summary)
    return 0


def _conflict_message(error: OutputConflict, args: argparse.Namespace) -> str:
    """Why ``--out`` is refused, naming the options in which its run differs."""
    if not error.differing:
        return str(error)
    keys = list(error.differing)
    if args.chunk_size is None and set(keys) - set(DERIVED_SETTINGS):
        keys = [key for key in keys if key not in DERIVED_SETTINGS]
    order = list(SETTING_OPTIONS)
    keys.sort(key=lambda key: order.index(key) if key in order else len(order))
    options = "; ".join(dict.fromkeys(SETTING_OPTIONS.get(key, key) for key in keys))
    return (f"--out {args.out} holds labels of a run with other options ({options}); "
            "remove it, choose another --out, or repeat that run's options to resume it")


def _report(summary: Summary) -> None:
    counts = ", ".join(f"{name} {n:,}" for name, n in summary.status_counts.items() if n)
    rate = summary.grasps_written / summary.seconds if summary.seconds else 0.0
    print(f"{PROG}: {summary.grasps_written:,} grasps labelled in {summary.chunks_written} "
          f"chunk(s) ({summary.chunks_skipped} already written) in {summary.seconds:.1f} s "
          f"({rate:,.0f} grasps/s){': ' + counts if counts else ''} -> {summary.out}",
          file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
