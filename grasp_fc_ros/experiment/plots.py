"""PNG plots of the experiment (matplotlib, Agg backend: no display needed)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, TypeAlias

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after choosing the backend)
import numpy as np  # noqa: E402

from .paper import PAPER_AVG_SPECIFICITY, PAPER_AVG_SPEEDUP  # noqa: E402

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from ..objects import Contacts, ContactSurface
    from .epsilon_study import EpsilonComparison
    from .measure import FingerSweepRow, ObjectResult, SidesSweepRow
    from .quality import FrictionLabels, SoftRow
    from .robustness_study import ObjectRobustness

#: Where a PNG goes.
PlotPath: TypeAlias = str | os.PathLike[str]

DPI = 120
SEED_COLOUR = "#1f77b4"
ALL_COLOUR = "#ff7f0e"
PAPER_COLOUR = "#555555"
FC_COLOUR = "#2ca02c"
REJECTED_COLOUR = "#d62728"
LIGHT_DIRECTION = np.array([-0.4, -0.5, 0.77])
# Length of a drawn friction cone relative to the object's size.
CONE_LENGTH_FRACTION = 0.22


def _save(fig: Figure, path: PlotPath) -> None:
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)


def _grouped_bars(ax: Axes, names: list[str], seed_values: list[float],
                  all_values: list[float]) -> None:
    x = np.arange(len(names))
    width = 0.38
    ax.bar(x - width / 2, seed_values, width, label='origins="seed" (paper)', color=SEED_COLOUR)
    ax.bar(x + width / 2, all_values, width, label='origins="all"', color=ALL_COLOUR)
    ax.set_xticks(x, names, rotation=20)


def plot_speedup(results: Sequence[ObjectResult], path: PlotPath) -> None:
    """Unfiltered time / filtered time per object."""
    fig, ax = plt.subplots(figsize=(7, 4))
    _grouped_bars(ax, [r.name for r in results], [r.speedup for r in results],
                  [r.speedup_all for r in results])
    ax.axhline(PAPER_AVG_SPEEDUP, color=PAPER_COLOUR, linestyle="--",
               label=f"paper average ({PAPER_AVG_SPEEDUP:.2f})")
    ax.axhline(1.0, color="black", linewidth=0.8)
    tallest = max([PAPER_AVG_SPEEDUP] + [r.speedup_all for r in results]
                  + [r.speedup for r in results])
    ax.set_ylim(0.0, 1.3 * tallest)  # room for the legend above the bars
    ax.set_ylabel("speedup (unfiltered / filtered time)")
    ax.set_title(f"Table I: speedup from the torque filter "
                 f"({results[0].grasps:,} grasps per object, n = {results[0].n_fingers})")
    ax.legend(loc="upper center", ncol=3, fontsize=8)
    _save(fig, path)


def plot_specificity(results: Sequence[ObjectResult], path: PlotPath) -> None:
    """Share of non-force-closure grasps the filter rejects, per object."""
    fig, ax = plt.subplots(figsize=(7, 4))
    _grouped_bars(ax, [r.name for r in results], [r.seed.specificity for r in results],
                  [r.all_origins.specificity for r in results])
    ax.axhline(PAPER_AVG_SPECIFICITY, color=PAPER_COLOUR, linestyle="--",
               label=f"paper average ({PAPER_AVG_SPECIFICITY:.3f})")
    ax.set_ylim(0.0, 1.25)  # room for the legend above the bars
    ax.set_yticks(np.linspace(0.0, 1.0, 6))
    ax.set_ylabel("specificity (non-FC rejected / all non-FC)")
    ax.set_title("Table II: specificity of the torque filter")
    ax.legend(loc="upper center", ncol=3, fontsize=8)
    _save(fig, path)


def plot_finger_sweep(rows: Sequence[FingerSweepRow], path: PlotPath) -> None:
    """Throughput of both pipelines, and the filter's specificity, against n."""
    n = [r.n_fingers for r in rows]
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(7, 6), sharex=True,
                                      gridspec_kw={"height_ratios": [2, 1]})
    top.plot(n, [r.filtered_per_s for r in rows], "o-", color=SEED_COLOUR,
             label="filter + exact test")
    top.plot(n, [r.unfiltered_per_s for r in rows], "s-", color=PAPER_COLOUR,
             label="exact test only")
    top.set_yscale("log")
    top.set_ylabel("throughput (grasps / s)")
    top.set_title(f"Throughput against the number of fingers ({rows[0].grasps:,} grasps each)")
    top.legend(fontsize=8)
    top.grid(True, which="both", alpha=0.3)
    bottom.plot(n, [r.specificity for r in rows], "o-", color=SEED_COLOUR, label="specificity")
    bottom.plot(n, [r.force_closure / r.grasps for r in rows], "^-", color=FC_COLOUR,
                label="force-closure share")
    bottom.set_ylim(0.0, 1.0)
    bottom.set_xlabel("number of fingers n")
    bottom.set_xticks(n)
    bottom.legend(fontsize=8)
    bottom.grid(True, alpha=0.3)
    _save(fig, path)


def plot_peer_sides(rows: Sequence[SidesSweepRow], path: PlotPath) -> None:
    """Linearized peer: missed force-closure grasps and time against pyramid sides."""
    sides = [r.sides for r in rows]
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(sides, [100.0 * r.missed_share for r in rows], "o-", color=REJECTED_COLOUR,
            label="force-closure grasps the peer misses (%)")
    ax.set_xlabel("pyramid sides m")
    ax.set_ylabel("% of force-closure grasps", color=REJECTED_COLOUR)
    ax.set_xticks(sides)
    ax.set_ylim(bottom=0.0)
    ax.grid(True, alpha=0.3)
    time_axis = ax.twinx()
    time_axis.plot(sides, [r.ms_per_grasp for r in rows], "d:", color=SEED_COLOUR,
                   label="peer time (ms / grasp)")
    time_axis.set_ylabel("ms per grasp", color=SEED_COLOUR)
    time_axis.set_ylim(bottom=0.0)
    lines, labels = ax.get_legend_handles_labels()
    more_lines, more_labels = time_axis.get_legend_handles_labels()
    ax.legend(lines + more_lines, labels + more_labels, fontsize=8, loc="upper center")
    ax.set_title(f"Linearized peer vs exact test ({rows[0].fc_grasps:,} force-closure grasps)")
    _save(fig, path)


def _cone_mesh(apex: np.ndarray, axis: np.ndarray, half_angle: float, length: float,
               segments: int = 24) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Surface grid of a circular cone opening from apex along axis."""
    axis = axis / np.linalg.norm(axis)
    helper = np.eye(3)[np.argmin(np.abs(axis))]
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    angle = np.linspace(0.0, 2.0 * np.pi, segments)
    along = np.array([0.0, length])
    rim = (np.cos(angle)[:, None] * u + np.sin(angle)[:, None] * v) * np.tan(half_angle)
    directions = axis + rim  # (segments, 3)
    grid = apex + along[None, :, None] * directions[:, None, :]  # (segments, 2, 3)
    return grid[..., 0], grid[..., 1], grid[..., 2]


# ax: a 3-D Axes (mpl_toolkits.mplot3d, which has no type information).
def _draw_grasp(ax: Any, surface: ContactSurface, positions: np.ndarray, normals: np.ndarray,
                mu: float, colour: str, title: str) -> None:
    # shade the points by their outward normal against a light from above-front,
    # a cheap depth cue for a point cloud
    brightness = 0.5 + 0.4 * (-surface.normals @ LIGHT_DIRECTION)
    ax.scatter(*surface.points.T, s=1.5, c=brightness, cmap="Greys_r", vmin=0.0, vmax=1.0,
               alpha=0.5, depthshade=False)
    size = np.ptp(surface.points, axis=0).max()
    half_angle = np.arctan(mu)
    for p, n in zip(positions, normals, strict=True):
        # the finger pushes along n into the object; draw its cone on the finger's
        # side (outside the surface) so it is not hidden by the object
        xs, ys, zs = _cone_mesh(p, -n, half_angle, CONE_LENGTH_FRACTION * size)
        ax.plot_surface(xs, ys, zs, color=colour, alpha=0.35, linewidth=0)
        tip = p - CONE_LENGTH_FRACTION * size * n
        ax.plot(*np.column_stack([tip, p]), color=colour, linewidth=1.2)
    ax.scatter(*positions.T, s=30, color=colour, edgecolor="black", depthshade=False)
    centre = surface.points.mean(axis=0)
    reach = 0.5 * size + CONE_LENGTH_FRACTION * size
    for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre, strict=True):
        setter(c - reach, c + reach)
    ax.set_box_aspect((1, 1, 1), zoom=1.6)
    ax.set_axis_off()
    ax.set_title(title, fontsize=10)


def plot_grasp_example(surface: ContactSurface, fc_grasp: Contacts, rejected_grasp: Contacts,
                       mu: float, path: PlotPath) -> None:
    """An object with one force-closure grasp and one grasp the filter rejects."""
    fig = plt.figure(figsize=(11, 5.5))
    for index, ((positions, normals), colour, title) in enumerate((
            (fc_grasp, FC_COLOUR, "force closure (exact test)"),
            (rejected_grasp, REJECTED_COLOUR, "rejected by the torque filter"))):
        ax = fig.add_subplot(1, 2, index + 1, projection="3d")
        ax.view_init(elev=35, azim=-60)
        _draw_grasp(ax, surface, positions, normals, mu, colour, title)
    fig.suptitle(f"{surface.name}: {len(fc_grasp[0])}-finger grasps, mu = {mu:.3f}; friction "
                 "cones (half-angle atan mu) drawn on the finger's side of the surface",
                 fontsize=10, y=0.99)
    fig.subplots_adjust(left=0.0, right=1.0, bottom=0.0, top=0.88, wspace=0.0)
    fig.savefig(path, dpi=DPI)
    plt.close(fig)


# mu* histogram range: GraspNet labels grasps on mu = 0.1 .. 1.0.
LABEL_MU_MAX = 1.2
LABEL_BIN_WIDTH = 0.05


def plot_friction_labels(labels: Sequence[FrictionLabels], path: PlotPath) -> None:
    """Histogram of the minimum friction coefficient mu* per object."""
    columns = min(3, len(labels))
    rows = -(-len(labels) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(3.3 * columns, 2.6 * rows),
                             squeeze=False, sharex=True)
    bins = np.arange(0.0, LABEL_MU_MAX + LABEL_BIN_WIDTH / 2, LABEL_BIN_WIDTH)
    for ax, label in zip(axes.flat, labels, strict=True):
        mu_star = label.mu_star
        shown = mu_star[np.isfinite(mu_star) & (mu_star <= LABEL_MU_MAX)]
        beyond = int(np.count_nonzero(~np.isfinite(mu_star) | (mu_star > LABEL_MU_MAX)))
        ax.hist(shown, bins=bins, color=SEED_COLOUR)
        ax.set_title(f"{label.name}: {beyond} of {mu_star.size} above {LABEL_MU_MAX}",
                     fontsize=9)
        ax.set_xlabel("mu*")
    for ax in axes.flat[len(labels):]:
        ax.set_visible(False)
    fig.suptitle(f"Minimum friction coefficient of random {labels[0].n_fingers}-finger grasps")
    _save(fig, path)


def plot_soft_sweep(rows: Sequence[SoftRow], path: PlotPath) -> None:
    """Force-closure share against the torsional friction, one line per finger count."""
    fig, ax = plt.subplots(figsize=(6, 4))
    for n_fingers in sorted({r.n_fingers for r in rows}):
        mine = [r for r in rows if r.n_fingers == n_fingers]
        fractions = sorted({r.gamma_fraction for r in mine})
        shares = [sum(r.force_closure for r in mine if r.gamma_fraction == f)
                  / sum(r.grasps for r in mine if r.gamma_fraction == f) for f in fractions]
        ax.plot(fractions, shares, marker="o", label=f"{n_fingers} fingers")
    ax.set_xlabel("torsional friction gamma / object size (0: hard contacts)")
    ax.set_ylabel("force-closure share (all objects)")
    ax.set_title("Soft against hard fingers on the same random grasps")
    ax.legend(fontsize=8)
    _save(fig, path)


def plot_epsilon_comparison(comparisons: Sequence[EpsilonComparison], edge_counts: Sequence[int],
                            path: PlotPath) -> None:
    """Pyramid Q1 against the exact epsilon (left) and the relative error's cumulative
    distribution (right), over the force-closure grasps of all objects."""
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    exact = np.concatenate([c.exact[c.force_closure] for c in comparisons])
    floor = 0.5 * exact.min() if exact.size else 1e-6
    for edges, colour in zip(edge_counts, (ALL_COLOUR, SEED_COLOUR, FC_COLOUR), strict=False):
        q1 = np.concatenate([c.pyramid[edges][c.force_closure] for c in comparisons])
        left.scatter(exact, np.maximum(q1, floor), s=6, alpha=0.5, color=colour,
                     label=f"{edges} edges (Q1 = 0 drawn at the bottom)")
        errors = np.sort(np.concatenate([c.relative_errors(edges) for c in comparisons]))
        right.plot(100 * errors, np.arange(1, errors.size + 1) / max(errors.size, 1),
                   color=colour, label=f"{edges} edges")
    if exact.size:
        line = np.array([exact.min(), exact.max()])
        left.plot(line, line, color=PAPER_COLOUR, linewidth=1, label="Q1 = epsilon")
    left.set_xscale("log")
    left.set_yscale("log")
    left.set_xlabel("exact epsilon (certified)")
    left.set_ylabel("pyramid Q1")
    left.legend(fontsize=8)
    right.set_xscale("symlog", linthresh=1.0)
    right.set_xlabel("(epsilon - Q1) / epsilon  [%]")
    right.set_ylabel("share of force-closure grasps")
    right.legend(fontsize=8)
    c0 = comparisons[0]
    fig.suptitle(f"Pyramid Q1 against the exact epsilon: {c0.n_fingers} fingers, "
                 f"mu = {c0.mu:.3f}")
    _save(fig, path)


def plot_robustness(objects: Sequence[ObjectRobustness], path: PlotPath) -> None:
    """The probability of force closure against epsilon (left) and against the position
    radius (middle), one colour per object, and the measures' rank correlations (right),
    over the force-closure grasps."""
    from .robustness_study import MEASURES, correlations

    fig, (left, middle, right) = plt.subplots(1, 3, figsize=(15, 4.5))
    colours = plt.get_cmap("tab10")
    for k, o in enumerate(objects):
        for ax, measure in ((left, "epsilon"), (middle, "position_radius")):
            ax.scatter(o.measures[measure], o.measures["probability"], s=8, alpha=0.6,
                       color=colours(k % 10), label=o.name)
    left.set_xlabel("epsilon (certified, midpoint)")
    middle.set_xlabel("position_radius (m)")
    for ax in (left, middle):
        ax.set_ylabel("probability of force closure")
        ax.set_ylim(-0.03, 1.03)
    left.legend(fontsize=7, markerscale=2)
    matrix = correlations(objects)
    image = right.imshow(matrix, vmin=-1, vmax=1, cmap="RdBu")
    labels = [m.replace("_", "\n") for m in MEASURES]
    right.set_xticks(range(len(MEASURES)), labels, fontsize=7)
    right.set_yticks(range(len(MEASURES)), labels, fontsize=7)
    for (i, j), value in np.ndenumerate(matrix):
        right.text(j, i, "-" if value != value else f"{value:.2f}", ha="center",
                   va="center", fontsize=7)
    fig.colorbar(image, ax=right, label="Spearman rank correlation")
    fig.suptitle("Robustness against epsilon: force-closure grasps of the built-in objects")
    _save(fig, path)
