"""CSV files and the markdown report of the experiment."""

from __future__ import annotations

import csv
import math
import os
import platform
import subprocess
import sys
from collections.abc import Iterable, Mapping, Sequence
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeAlias

import numpy as np

from .paper import (
    PAPER_AVG_FALSE_POSITIVES,
    PAPER_AVG_FC,
    PAPER_AVG_FILTERED_S,
    PAPER_AVG_SPECIFICITY,
    PAPER_AVG_SPEEDUP,
    PAPER_AVG_UNFILTERED_S,
    PAPER_EXACT_MS,
    PAPER_FILTER_MS,
    PAPER_GRASPS,
    PAPER_IMPLIED_PASSED_MS,
    PAPER_IMPLIED_REJECTED_MS,
    PAPER_PASSED_SHARE,
    PAPER_TABLE_I,
    PAPER_TABLE_II,
)

if TYPE_CHECKING:
    from .measure import FingerSweepRow, ObjectResult, SidesSweepRow
    from .quality import FrictionLabels, SoftRow
    from .robustness_study import ObjectRobustness

#: One CSV row (column name -> value), or one summary row of
#: :func:`.epsilon_study.summary_rows`.
Row: TypeAlias = dict[str, Any]

RESULTS_CSV = "results.csv"
FINGERS_CSV = "fingers.csv"
PEER_SIDES_CSV = "peer_sides.csv"
FRICTION_LABELS_CSV = "friction_labels.csv"
SOFT_SWEEP_CSV = "soft_sweep.csv"
EPSILON_CSV = "epsilon.csv"
ROBUSTNESS_CSV = "robustness.csv"
REPORT_MD = "report.md"
EPSILON_REPORT_MD = "epsilon_report.md"
ROBUSTNESS_REPORT_MD = "robustness_report.md"
PLOTS = {
    "speedup": "speedup.png",
    "specificity": "specificity.png",
    "fingers": "throughput_vs_fingers.png",
    "peer_sides": "peer_vs_sides.png",
    "grasp_example": "grasp_example.png",
    "friction_labels": "friction_labels.png",
    "soft_sweep": "soft_vs_hard.png",
    "epsilon": "epsilon_vs_pyramids.png",
    "robustness": "robustness.png",
}
# Friction values at which the report gives the share of force-closure grasps (mu* below).
LABEL_MU_LEVELS = (0.1, 0.2, 0.5, 1.0)


def exact_ms_split(r: ObjectResult) -> tuple[float, float]:
    """Exact-test ms per grasp on the grasps the filter passes and on those it rejects.

    Both runs time their exact stage: the filtered run's covers the passed grasps,
    the unfiltered run's all of them, so the difference is the rejected grasps' cost.
    """
    rejected = r.grasps - r.seed.passed
    passed_ms = 1e3 * r.seed.exact_s / r.seed.passed if r.seed.passed else float("nan")
    rejected_ms = (1e3 * (r.unfiltered.exact_s - r.seed.exact_s) / rejected
                   if rejected else float("nan"))
    return passed_ms, rejected_ms


def result_row(r: ObjectResult) -> Row:
    """One object's measurements as a flat CSV row (times in seconds)."""
    filter_ms = 1e3 * r.seed.filter_s / r.grasps
    exact_ms = 1e3 * r.unfiltered.exact_s / r.grasps
    pipeline_ms = 1e3 * r.seed.wall_s / r.grasps
    return {
        "object": r.name,
        "points": r.n_points,
        "fingers": r.n_fingers,
        "mu": f"{r.mu:.6f}",
        "grasps": r.grasps,
        "unfiltered_s": f"{r.unfiltered.wall_s:.6f}",
        "filtered_s": f"{r.seed.wall_s:.6f}",
        "speedup": f"{r.speedup:.3f}",
        "fc_unfiltered": r.force_closure,
        "fc_filtered": r.seed.force_closure,
        "passed_filter": r.seed.passed,
        "false_positives": r.seed.false_positives,
        "specificity": f"{r.seed.specificity:.4f}",
        "unsound": r.seed.unsound,
        "verdict_mismatches": r.seed.verdict_mismatches,
        "filtered_all_s": f"{r.all_origins.wall_s:.6f}",
        "speedup_all": f"{r.speedup_all:.3f}",
        "fc_filtered_all": r.all_origins.force_closure,
        "passed_filter_all": r.all_origins.passed,
        "false_positives_all": r.all_origins.false_positives,
        "specificity_all": f"{r.all_origins.specificity:.4f}",
        "unsound_all": r.all_origins.unsound,
        "verdict_mismatches_all": r.all_origins.verdict_mismatches,
        "solver_failures": (r.unfiltered.solver_failures + r.seed.solver_failures
                            + r.all_origins.solver_failures),
        "filter_ms_per_query": f"{filter_ms:.5f}",
        "exact_ms_per_query": f"{exact_ms:.5f}",
        "exact_over_filter": f"{exact_ms / filter_ms:.1f}" if filter_ms else "nan",
        "pipeline_ms_per_grasp": f"{pipeline_ms:.5f}",
        "exact_ms_passed": f"{exact_ms_split(r)[0]:.5f}",
        "exact_ms_rejected": f"{exact_ms_split(r)[1]:.5f}",
        "peer_sides": r.peer.sides,
        "peer_grasps": r.peer.grasps,
        "peer_ms_per_grasp": f"{r.peer.ms_per_grasp:.4f}",
        "peer_missed_fc": r.peer.missed_fc,
        "peer_false_fc": r.peer.false_fc,
        "peer_over_pipeline": f"{r.peer.ms_per_grasp / pipeline_ms:.1f}",
    }


def finger_row(row: FingerSweepRow) -> Row:
    return {
        "fingers": row.n_fingers,
        "grasps": row.grasps,
        "unfiltered_s": f"{row.unfiltered_s:.4f}",
        "filtered_s": f"{row.filtered_s:.4f}",
        "unfiltered_per_s": f"{row.unfiltered_per_s:.1f}",
        "filtered_per_s": f"{row.filtered_per_s:.1f}",
        "force_closure": row.force_closure,
        "specificity": f"{row.specificity:.4f}",
    }


def sides_row(row: SidesSweepRow) -> Row:
    return {
        "sides": row.sides,
        "fc_grasps": row.fc_grasps,
        "other_grasps": row.other_grasps,
        "ms_per_grasp": f"{row.ms_per_grasp:.4f}",
        "missed_fc": row.missed_fc,
        "missed_fc_share": f"{row.missed_share:.5f}",
        "false_fc": row.false_fc,
    }


def friction_label_rows(labels: Iterable[FrictionLabels]) -> list[Row]:
    """One row per labelled grasp: the object and its mu*."""
    return [{"object": label.name, "fingers": label.n_fingers, "grasp": i, "mu_star": mu}
            for label in labels for i, mu in enumerate(label.mu_star.tolist())]


def soft_row(row: SoftRow) -> Row:
    return {"object": row.name, "fingers": row.n_fingers,
            "gamma_over_size": row.gamma_fraction, "gamma": f"{row.gamma:.6g}",
            "grasps": row.grasps, "force_closure": row.force_closure}


def quality_section(labels: Sequence[FrictionLabels], soft_rows: Sequence[SoftRow],
                    soft_mu: float) -> list[str]:
    """Markdown lines of the grasp-quality part: mu* labels and the soft-finger sweep."""
    levels = LABEL_MU_LEVELS
    fractions = sorted({r.gamma_fraction for r in soft_rows})
    fingers = sorted({r.n_fingers for r in soft_rows})

    def share(n_fingers: int, fraction: float) -> float:
        mine = [r for r in soft_rows if r.n_fingers == n_fingers and r.gamma_fraction == fraction]
        return sum(r.force_closure for r in mine) / sum(r.grasps for r in mine)

    return [
        "## Grasp quality: minimum friction and soft fingers",
        "",
        f"mu* (`minimum_friction`) of {labels[0].mu_star.size:,} random "
        f"{labels[0].n_fingers}-finger grasps per object: the GraspNet-style label, certified "
        "instead of scanned on a grid. A grasp is force closure at friction mu exactly when "
        "mu > mu*.",
        "",
        _table(["object", "median mu*"] + [f"FC at mu = {m}" for m in levels]
               + ["no mu (inf)", "not certified", "grasps/s"],
               [[lab.name, f"{np.median(lab.mu_star):.3f}"]
                + [f"{lab.share_at_most(m):.3f}" for m in levels]
                + [int(np.count_nonzero(np.isposinf(lab.mu_star))),
                   int(np.count_nonzero(np.isnan(lab.mu_star))),
                   f"{lab.mu_star.size / lab.seconds:,.0f}"] for lab in labels]),
        "",
        f"Soft fingers (torsional friction gamma, a length) against hard ones on the same "
        f"random grasps, mu = {soft_mu}; force-closure share over all objects "
        "(gamma = 0 are hard contacts; two hard fingers are never force closure):",
        "",
        _table(["fingers"] + [f"gamma/size = {f:g}" for f in fractions],
               [[n] + [f"{share(n, f):.3f}" for f in fractions] for n in fingers]),
        "",
    ]


def epsilon_row(row: Row) -> Row:
    """A summary row of :func:`.epsilon_study.summary_rows` for the CSV (rounded)."""
    return {key: (f"{value:.6g}" if isinstance(value, float) else value)
            for key, value in row.items()}


def epsilon_section(rows: Sequence[Row], n_fingers: int, mu: float) -> list[str]:
    """Markdown lines of the epsilon part: exact epsilon against the pyramid Q1."""
    from .epsilon_study import EXACT_RTOL

    def share(value: float) -> str:
        return "-" if value != value else f"{100 * value:.1f}%"

    return [
        "## Ferrari-Canny epsilon: exact against the pyramid Q1 of dataset tools",
        "",
        f"Random {n_fingers}-finger grasps per object, mu = {mu:.4f}; epsilon certified to "
        f"rtol {EXACT_RTOL:g} (`epsilon_quality`) against the Q1 of the inscribed "
        "pyramid with 4 and 8 edges (Qhull, least facet offset; DexGraspBench q1.py, "
        "BODex chq1.py), both about the object's centre with L = the grasp's largest "
        "|p_i - c|. Errors are (epsilon - Q1) / epsilon over the force-closure grasps; a "
        "flip is a pair of force-closure grasps whose exact order is certain and which the "
        "pyramid orders the other way (ties: it scores them equal).",
        "",
        _table(["object", "edges", "FC grasps", "median error", "90% error", "max error",
                "FC scored 0", "flipped pairs", "tied pairs", "Q1 > upper"],
               [[r["object"], r["edges"], f"{r['force_closure']} / {r['grasps']}",
                 share(r["median_error"]), share(r["p90_error"]), share(r["max_error"]),
                 r["pyramid_zero"],
                 f"{r['flipped_pairs']} / {r['ordered_pairs']} ({share(r['flip_share'])})",
                 r["tied_pairs"], r["above_upper"]] for r in rows]),
        "",
    ]


def robustness_section(objects: Sequence[ObjectRobustness], rows: Sequence[Row],
                       samples: int, reference_samples: int) -> list[str]:
    """Markdown lines of the robustness part (``rows``: its
    :func:`.robustness_study.summary_rows`)."""
    from .robustness_study import (
        DEXNET_NOISE,
        DEXNET_SAMPLES,
        FINGERS,
        MEASURES,
        MU,
        NOISE,
        TOP_SHARE,
        correlations,
    )

    def rho(value: object) -> str:
        return "-" if not isinstance(value, float) or value != value else f"{value:+.2f}"

    def noise(values: dict[str, float]) -> str:
        return (f"positions {1e3 * values['position_sigma']:.1f} mm, normals "
                f"{math.degrees(values['normal_sigma']):.2f} deg, friction "
                f"{values['friction_sigma']:g}")

    matrix = correlations(objects)
    many = np.concatenate([o.many for o in objects])
    few = np.concatenate([o.few for o in objects])
    uncertain = (many > 0.2) & (many < 0.8)
    differ = (few > 0.5) != (many > 0.5)
    return [
        "## Robustness: radii, probability, margin and epsilon",
        "",
        f"Random {FINGERS}-finger grasps per object, mu = {MU:g}, the objects in metres. "
        "Over the force-closure grasps: the margin t*, the Ferrari-Canny epsilon (about "
        "the object's centre, L = the grasp's largest |p_i - c|), the certified radii "
        "`normal_angle` (rad), `position_radius` (m) and `friction_drop`, and the "
        f"probability of force closure under {noise(NOISE)} ({samples} samples a grasp; "
        "docs/robustness.md#probability-of-force-closure). Spearman's rank correlation "
        "over the force-closure grasps of all objects:",
        "",
        _table([""] + list(MEASURES),
               [[name] + [rho(float(v)) for v in matrix[k]] for k, name in enumerate(MEASURES)]),
        "",
        "Per object, the probability's rank correlation with each measure, and how many "
        f"of the top {100 * TOP_SHARE:.0f} % of its force-closure grasps by epsilon rank in "
        "the bottom half by probability:",
        "",
        _table(["object", "FC grasps"] + [f"rho(P, {m})" for m in MEASURES[:-1]]
               + ["top by epsilon in bottom half by P"],
               [[r["object"], f"{r['force_closure']} / {r['grasps']}"]
                + [rho(r[f"rho_probability_{m}"]) for m in MEASURES[:-1]]
                + [f"{r['top_epsilon_bottom_probability']} / {r['top_epsilon']}"]
                for r in rows]),
        "",
        f"Labels \"probability > 0.5\" with Dex-Net's noise sizes ({noise(DEXNET_NOISE)}, "
        f"mu = {MU:g}; see `robustness_study.DEXNET_NOISE` for the mapping) from "
        f"{DEXNET_SAMPLES} samples, as Dex-Net labels, against {reference_samples} samples "
        f"drawn apart, over all {differ.size} grasps: **{int(differ.sum())} differ "
        f"({100 * differ.mean() if differ.size else float('nan'):.1f} %)**; "
        f"among the {int(uncertain.sum())} grasps whose {reference_samples}-sample estimate "
        f"is in (0.2, 0.8), {int(differ[uncertain].sum())} differ"
        f" ({100 * differ[uncertain].mean() if uncertain.any() else float('nan'):.1f} %).",
        "",
    ]


def write_csv(path: str | os.PathLike[str], rows: Sequence[Row]) -> None:
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def machine_description() -> str:
    """One line naming the CPU, core count, OS and versions the run used."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as handle:
            names = [line.split(":", 1)[1].strip() for line in handle
                     if line.startswith("model name")]
        cpu = names[0] if names else cpu
    except OSError:
        pass
    versions = []
    for package in ("numpy", "clarabel", "scipy"):
        try:
            versions.append(f"{package} {metadata.version(package)}")
        except metadata.PackageNotFoundError:
            versions.append(f"{package} (not installed)")
    return (f"{cpu}, {os.cpu_count()} logical cores, {platform.system()} "
            f"{platform.release()}, Python {platform.python_version()}, {', '.join(versions)}")


def code_version() -> str:
    """The git commit of the package's checkout, marked '+ local changes' when dirty."""
    source = Path(__file__).resolve().parents[2]
    try:
        commit = subprocess.run(["git", "-C", str(source), "rev-parse", "--short", "HEAD"],
                                capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(source), "status", "--porcelain",
                                "--untracked-files=no", "grasp_fc_ros"],
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown (not a git checkout)"
    return f"git {commit}" + (" + local changes" if dirty else "")


def _mean(values: Iterable[float]) -> float:
    values = list(values)
    return sum(values) / len(values)


def _table(header: Sequence[str], rows: Iterable[Sequence[object]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(str(cell) for cell in row) + " |" for row in rows]
    return "\n".join(lines)


def soundness_problems(results: Iterable[ObjectResult]) -> list[str]:
    """Lines describing every object where the filter changed a verdict (empty if none)."""
    return [f"{r.name}, origins={stats.origins!r}: the filter rejected {stats.unsound} "
            f"force-closure grasps; {stats.verdict_mismatches} verdicts differ from the "
            "unfiltered run"
            for r in results for stats in (r.seed, r.all_origins)
            if stats.unsound or stats.verdict_mismatches]


def markdown_report(results: Sequence[ObjectResult], finger_rows: Sequence[FingerSweepRow],
                    sides_rows: Sequence[SidesSweepRow], settings: Mapping[str, object],
                    total_s: float, plots: Mapping[str, str],
                    quality_lines: Sequence[str] = ()) -> str:
    """The report as markdown text; ``quality_lines`` (from :func:`quality_section`) go
    before the plots."""
    r0 = results[0]
    pipeline_ms = [1e3 * r.seed.wall_s / r.grasps for r in results]
    filter_ms = [1e3 * r.seed.filter_s / r.grasps for r in results]
    exact_ms = [1e3 * r.unfiltered.exact_s / r.grasps for r in results]
    peer_ms = [r.peer.ms_per_grasp for r in results]
    peer_grasps = sum(r.peer.grasps for r in results)
    peer_fc_missed = sum(r.peer.missed_fc for r in results)
    peer_false = sum(r.peer.false_fc for r in results)
    peer_ratio = _mean(peer_ms) / _mean(pipeline_ms)
    splits = [exact_ms_split(r) for r in results]
    out = [
        "# Force-closure filter experiment (reproduction of the seed paper, section V)",
        "",
        f"- Command: `{settings['command']}`",
        f"- Machine: {machine_description()}",
        f"- Code: {code_version()}",
        f"- Setting: {r0.grasps:,} random {r0.n_fingers}-finger grasps per object "
        f"(distinct contacts drawn from {r0.n_points:,} surface points), mu = {r0.mu:.4f}, "
        f"seed {settings['seed']}",
        f"- Total wall time of this run: {total_s:.1f} s",
        "- Times are wall-clock seconds of `check_force_closure` on the whole batch "
        "(validation included); each timed call runs in one process on one core "
        f"({settings['jobs']} object(s) measured at a time).",
        "",
        "## Table I: running time",
        "",
        "Unfiltered: the exact (SOCP) test on every grasp. Filtered: the torque filter, "
        "then the exact test on the grasps it passes.",
        "",
        _table(["object", "unfiltered (s)", 'filtered, origins="seed" (s)', "speedup",
                'filtered, origins="all" (s)', "speedup (all)"],
               [[r.name, f"{r.unfiltered.wall_s:.2f}", f"{r.seed.wall_s:.2f}",
                 f"{r.speedup:.2f}", f"{r.all_origins.wall_s:.2f}", f"{r.speedup_all:.2f}"]
                for r in results]
               + [["**average**", f"{_mean(r.unfiltered.wall_s for r in results):.2f}",
                   f"{_mean(r.seed.wall_s for r in results):.2f}",
                   f"{_mean(r.speedup for r in results):.2f}",
                   f"{_mean(r.all_origins.wall_s for r in results):.2f}",
                   f"{_mean(r.speedup_all for r in results):.2f}"]]),
        "",
        f"Paper (C++, maxdet, Core 2 Quad Q6600): average {PAPER_AVG_UNFILTERED_S:.2f} s "
        f"unfiltered, {PAPER_AVG_FILTERED_S:.2f} s filtered, speedup {PAPER_AVG_SPEEDUP:.2f} "
        f"(per object: " + ", ".join(f"{k} {v[2]:.2f}" for k, v in PAPER_TABLE_I.items()) + ").",
        "",
        "## Table II: filter analysis",
        "",
        "Specificity = non-force-closure grasps the filter rejects / all non-force-closure "
        "grasps. False positives passed the filter but are not force closure. "
        "'FC rejected' counts force-closure grasps the filter rejected (soundness: must be 0); "
        "'verdicts differ' counts grasps whose filtered verdict differs from the unfiltered one.",
        "",
        _table(["object", "#FC", "#false pos. (seed)", "specificity (seed)",
                "#false pos. (all)", "specificity (all)", "FC rejected (seed/all)",
                "verdicts differ (seed/all)", "solver failures"],
               [[r.name, f"{r.force_closure:,}", f"{r.seed.false_positives:,}",
                 f"{r.seed.specificity:.3f}", f"{r.all_origins.false_positives:,}",
                 f"{r.all_origins.specificity:.3f}",
                 f"{r.seed.unsound}/{r.all_origins.unsound}",
                 f"{r.seed.verdict_mismatches}/{r.all_origins.verdict_mismatches}",
                 r.unfiltered.solver_failures + r.seed.solver_failures
                 + r.all_origins.solver_failures]
                for r in results]
               + [["**average**", f"{_mean(r.force_closure for r in results):,.0f}",
                   f"{_mean(r.seed.false_positives for r in results):,.0f}",
                   f"{_mean(r.seed.specificity for r in results):.3f}",
                   f"{_mean(r.all_origins.false_positives for r in results):,.0f}",
                   f"{_mean(r.all_origins.specificity for r in results):.3f}", "", "", ""]]),
        "",
        f"Paper: average {PAPER_AVG_FC:,} force-closure grasps, {PAPER_AVG_FALSE_POSITIVES:,} "
        f"false positives, specificity {PAPER_AVG_SPECIFICITY:.3f} (per object: "
        + ", ".join(f"{k} {v[2]:.3f}" for k, v in PAPER_TABLE_II.items()) + ").",
        "",
        "## Per-query cost",
        "",
        _table(["object", "filter (ms/query)", "exact test (ms/query)", "ratio exact/filter",
                "exact on passed (ms)", "exact on rejected (ms)",
                "filtered pipeline (ms/grasp)"],
               [[r.name, f"{f:.4f}", f"{e:.4f}", f"{e / f:.0f}" if f else "nan",
                 f"{split[0]:.4f}", f"{split[1]:.4f}", f"{p:.4f}"]
                for r, f, e, p, split in zip(results, filter_ms, exact_ms, pipeline_ms, splits,
                                             strict=True)]
               + [["**average**", f"{_mean(filter_ms):.4f}", f"{_mean(exact_ms):.4f}",
                   f"{_mean(exact_ms) / _mean(filter_ms):.0f}",
                   f"{_mean(s[0] for s in splits):.4f}", f"{_mean(s[1] for s in splits):.4f}",
                   f"{_mean(pipeline_ms):.4f}"]]),
        "",
        f"Paper: filter {PAPER_FILTER_MS} ms, exact test {PAPER_EXACT_MS} ms per query "
        f"(ratio {PAPER_EXACT_MS / PAPER_FILTER_MS:.0f}). Filter time is the pipeline's own "
        "'filter_s' stage time over all grasps; exact time is the unfiltered run's 'exact_s' "
        "over all grasps. 'Exact on passed' is the filtered run's exact stage per grasp it "
        "passed; 'exact on rejected' is what the unfiltered run spent, per grasp, on the "
        "grasps the filter rejects (difference of the two exact stages).",
        "",
        "If the exact test cost the same on every grasp, the speedup could not exceed "
        "1 / (share of grasps passing the filter + filter cost / exact cost): "
        + ", ".join(f"{r.name} {1.0 / (r.seed.passed / r.grasps + f / e):.2f}"
                    for r, f, e in zip(results, filter_ms, exact_ms, strict=True))
        + f". The paper's averages ({PAPER_PASSED_SHARE * PAPER_GRASPS:,.0f} of "
        f"{PAPER_GRASPS:,} grasps passing, "
        f"{PAPER_FILTER_MS} vs {PAPER_EXACT_MS} ms) give "
        f"{1.0 / (PAPER_PASSED_SHARE + PAPER_FILTER_MS / PAPER_EXACT_MS):.2f}, yet it reports "
        f"{PAPER_AVG_SPEEDUP}: its Table I implies the exact test cost about "
        f"{PAPER_IMPLIED_REJECTED_MS:.1f} ms on a rejected grasp and "
        f"{PAPER_IMPLIED_PASSED_MS:.1f} ms on a passed one.",
        "",
        "## The linearized peer (GraspIt!/Dex-Net style)",
        "",
        f"Each cone replaced by an inscribed {r0.peer.sides}-sided pyramid; force closure iff "
        "the origin is strictly inside the convex hull of the primitive wrenches (scipy "
        "ConvexHull / Qhull). It is slow (milliseconds a grasp, more with more sides), so it runs "
        "on a subsample: "
        f"the first {r0.peer.grasps:,} grasps of each object ({peer_grasps:,} in all), "
        "compared with the exact verdicts on the same grasps.",
        "",
        _table(["object", "grasps", "peer (ms/grasp)", "our filtered pipeline (ms/grasp)",
                "peer / ours", "FC missed by peer", "non-FC accepted by peer"],
               [[r.name, r.peer.grasps, f"{r.peer.ms_per_grasp:.2f}", f"{p:.4f}",
                 f"{r.peer.ms_per_grasp / p:.0f}x", r.peer.missed_fc, r.peer.false_fc]
                for r, p in zip(results, pipeline_ms, strict=True)]),
        "",
        f"Overall: peer {_mean(peer_ms):.2f} ms/grasp vs ours {_mean(pipeline_ms):.4f} "
        f"ms/grasp, ours is **{peer_ratio:.0f}x faster** (target: >= 50x). The peer's verdict "
        f"differs from the exact one on {peer_fc_missed + peer_false} of {peer_grasps:,} grasps "
        f"({100.0 * (peer_fc_missed + peer_false) / peer_grasps:.2f} %): {peer_fc_missed} "
        f"force-closure grasps missed, {peer_false} non-force-closure grasps accepted.",
        "",
        "### Peer against the number of pyramid sides",
        "",
        "An inscribed pyramid lies inside the cone, so the peer can only miss force closure. "
        "This sweep therefore runs the peer on force-closure grasps (picked by the exact test "
        "from random grasps of every object) plus a few non-force-closure ones.",
        "",
        _table(["sides", "FC grasps", "non-FC grasps", "ms/grasp", "FC missed",
                "FC missed (%)", "non-FC accepted"],
               [[s.sides, s.fc_grasps, s.other_grasps, f"{s.ms_per_grasp:.2f}", s.missed_fc,
                 f"{100.0 * s.missed_share:.1f}", s.false_fc] for s in sides_rows]),
        "",
        "## Throughput against the number of fingers",
        "",
        _table(["fingers", "grasps", "exact only (grasps/s)", "filter + exact (grasps/s)",
                "FC share", "specificity"],
               [[f.n_fingers, f.grasps, f"{f.unfiltered_per_s:,.0f}", f"{f.filtered_per_s:,.0f}",
                 f"{f.force_closure / f.grasps:.3f}", f"{f.specificity:.3f}"]
                for f in finger_rows]),
        "",
        *quality_lines,
        "## Plots",
        "",
    ]
    problems = soundness_problems(results)
    if problems:
        warning = ["**SOUNDNESS VIOLATION: the filter changed verdicts (it must never "
                   "reject a force-closure grasp):**", ""] + [f"- {line}" for line in problems]
        out[2:2] = warning + [""]
    out += [f"![{key}]({name})" for key, name in plots.items()]
    out.append("")
    return "\n".join(out)


def command_line() -> str:
    return " ".join(["grasp-fc-experiment"] + sys.argv[1:])
