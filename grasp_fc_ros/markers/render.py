"""Draw ``visualization_msgs/MarkerArray`` messages to a PNG with matplotlib (3-D axes).

RViz cannot run without a display; this renderer shows roughly what RViz would show
for the marker types :mod:`grasp_fc_ros.markers.build` publishes: SPHERE_LIST, SPHERE,
TRIANGLE_LIST, ARROW (given by two points) and TEXT_VIEW_FACING. It draws one 3-D
panel per MarkerArray, optionally over a grey point cloud of the object. matplotlib is
imported here only (it is not a dependency of the node).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from geometry_msgs.msg import Quaternion
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from mpl_toolkits.mplot3d import Axes3D
from mpl_toolkits.mplot3d.art3d import Poly3DCollection
from visualization_msgs.msg import Marker, MarkerArray

from grasp_fc_ros.core import Status
from grasp_fc_ros.markers.build import STATUS_LABELS, grasp_markers

#: The verdicts :func:`render_verdict_examples` shows, one panel each, in this order.
EXAMPLE_STATUSES = (Status.FORCE_CLOSURE, Status.FILTERED_OUT, Status.NOT_FORCE_CLOSURE)

# Matplotlib sizes scatter points in points^2 of the figure, not in data units: a
# sphere's diameter relative to the panel's extent is mapped onto this many points.
_PANEL_POINTS = 160.0
PANEL_SIZE_IN = 4.0


def _quaternion_matrix(q: Quaternion) -> np.ndarray:
    """Rotation matrix (3, 3) of a geometry_msgs/Quaternion (normalised here)."""
    x, y, z, w = q.x, q.y, q.z, q.w
    norm = np.sqrt(x * x + y * y + z * z + w * w)
    if norm == 0:
        return np.eye(3)  # RViz treats an all-zero quaternion as identity too
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def marker_points(marker: Marker) -> np.ndarray:
    """The marker's points (k, 3) in its header frame (its pose applied)."""
    local = np.array([[p.x, p.y, p.z] for p in marker.points], dtype=float).reshape(-1, 3)
    position = marker.pose.position
    offset = np.array([position.x, position.y, position.z])
    return local @ _quaternion_matrix(marker.pose.orientation).T + offset


def _rgba(marker: Marker) -> tuple[float, float, float, float]:
    c = marker.color
    return (c.r, c.g, c.b, c.a)


def _draw_marker(ax: Axes3D, marker: Marker, extent: float) -> None:
    color = _rgba(marker)
    if marker.type in (Marker.SPHERE_LIST, Marker.SPHERE):
        points = (marker_points(marker) if marker.type == Marker.SPHERE_LIST
                  else _pose_position(marker)[None])
        size = (_PANEL_POINTS * marker.scale.x / extent) ** 2
        ax.scatter(*points.T, s=size, color=color, depthshade=False, edgecolors="k",
                   linewidths=0.3)
    elif marker.type == Marker.TRIANGLE_LIST:
        triangles = marker_points(marker).reshape(-1, 3, 3)
        ax.add_collection3d(Poly3DCollection(triangles, facecolor=color,
                                             edgecolor=(*color[:3], min(1.0, 2 * color[3])),
                                             linewidths=0.3))
    elif marker.type == Marker.ARROW:
        if len(marker.points) != 2:
            raise ValueError(f"marker {marker.ns}/{marker.id}: only ARROW markers given by "
                             f"two points are drawn, got {len(marker.points)} points")
        start, end = marker_points(marker)
        width = max(1.5, _PANEL_POINTS * marker.scale.x / extent)  # shaft diameter
        ax.quiver(*start, *(end - start), color=color, linewidth=width,
                  arrow_length_ratio=marker.scale.z / max(np.linalg.norm(end - start), 1e-300))
    elif marker.type == Marker.TEXT_VIEW_FACING:
        ax.text(*_pose_position(marker), marker.text, color=color[:3], ha="center",
                va="bottom", fontsize=9)
    else:
        raise ValueError(f"marker {marker.ns}/{marker.id}: type {marker.type} is not drawn "
                         f"by this renderer")


def _pose_position(marker: Marker) -> np.ndarray:
    p = marker.pose.position
    return np.array([p.x, p.y, p.z])


def _panel_bounds(array: MarkerArray, cloud: np.ndarray | None) -> tuple[np.ndarray, float]:
    """Centre (3,) and half-width of a cube holding every point of the panel."""
    parts = [marker_points(m) for m in array.markers if m.action == Marker.ADD]
    parts += [_pose_position(m)[None] for m in array.markers
              if m.action == Marker.ADD and m.type in (Marker.TEXT_VIEW_FACING, Marker.SPHERE)]
    if cloud is not None:
        parts.append(np.asarray(cloud, dtype=float).reshape(-1, 3))
    points = np.concatenate(parts) if parts else np.zeros((1, 3))
    low, high = points.min(0), points.max(0)
    return (low + high) / 2, max(float((high - low).max()) / 2, 1e-9) * 1.05


def render_marker_arrays(arrays: Sequence[MarkerArray], path: str | Path, *,
                         titles: Sequence[str] | None = None,
                         clouds: Sequence[np.ndarray | None] | None = None,
                         dpi: int = 110) -> Path:
    """Draw each MarkerArray in its own 3-D panel and write one PNG.

    Markers whose action is not ADD (DELETE, DELETEALL) draw nothing. The frames of
    the markers are not resolved: each panel shows its markers' header frame.

    Parameters
    ----------
    arrays : sequence of visualization_msgs/MarkerArray
        One panel each, in a row.
    path : str or Path
        The PNG to write (its folder must exist).
    titles : sequence of str, optional
        A title per panel.
    clouds : sequence of (k, 3) float arrays or None, optional
        Points drawn in light grey under a panel's markers (e.g. the object's surface).
    dpi : int
        Resolution of the PNG.

    Returns
    -------
    Path of the written PNG.
    """
    if not arrays:
        raise ValueError("render_marker_arrays needs at least one MarkerArray")
    for name, values in (("titles", titles), ("clouds", clouds)):
        if values is not None and len(values) != len(arrays):
            raise ValueError(f"{name} has {len(values)} entries for {len(arrays)} panels")
    figure = Figure(figsize=(PANEL_SIZE_IN * len(arrays), PANEL_SIZE_IN + 0.4))
    FigureCanvasAgg(figure)
    for k, array in enumerate(arrays):
        ax = figure.add_subplot(1, len(arrays), k + 1, projection="3d")
        cloud = clouds[k] if clouds is not None else None
        centre, half = _panel_bounds(array, cloud)
        if cloud is not None:
            ax.scatter(*np.asarray(cloud, dtype=float).reshape(-1, 3).T, s=1.0,
                       color=(0.55, 0.55, 0.55, 0.35), depthshade=False)
        for marker in array.markers:
            if marker.action == Marker.ADD:
                _draw_marker(ax, marker, 2 * half)
        for axis, c in zip("xyz", centre, strict=True):
            getattr(ax, f"set_{axis}lim")(c - half, c + half)
        ax.set_box_aspect((1, 1, 1))
        ax.tick_params(labelsize=6)
        if titles is not None:
            ax.set_title(titles[k], fontsize=10)
    figure.tight_layout()
    path = Path(path)
    figure.savefig(path, dpi=dpi)
    return path


def render_verdict_examples(path: str | Path, positions: np.ndarray, normals: np.ndarray,
                            mu: np.ndarray | float, status: np.ndarray, margin: np.ndarray,
                            *, ids: np.ndarray | None = None,
                            separating_wrench: np.ndarray | None = None,
                            frame_id: str = "object", cloud: np.ndarray | None = None,
                            statuses: Sequence[Status] = EXAMPLE_STATUSES) -> list[int]:
    """Draw the markers of the first grasp of each verdict in ``statuses`` to one PNG.

    Verdicts that no grasp has are left out (no panel).

    Parameters
    ----------
    path : str or Path
        The PNG to write.
    positions, normals : (N, n, 3) float arrays
        Decided grasps (one contact count), in ``frame_id``.
    mu : float or (N, n) float array
        Friction coefficients the grasps were decided with.
    status, margin : (N,) arrays
        Their verdicts (:class:`Status` codes) and margins.
    ids : (N,) int array, optional
        Query ids shown in the markers (default: the grasp's index).
    separating_wrench : (N, 6) float array, optional
        Drawn where finite.
    frame_id : str
        Frame of the markers.
    cloud : (k, 3) float array, optional
        Points drawn in grey in every panel (e.g. the object's surface).
    statuses : sequence of Status
        Verdicts to look for, one panel each.

    Returns
    -------
    list of int: the index of the grasp drawn in each panel (empty: nothing written).
    """
    status = np.asarray(status)
    mu_per_contact = np.broadcast_to(np.asarray(mu, dtype=float), np.shape(positions)[:2])
    arrays, titles, chosen = [], [], []
    for wanted in statuses:
        found = np.flatnonzero(status == wanted)
        if not found.size:
            continue
        k = int(found[0])
        query_id = int(ids[k]) if ids is not None else k
        wrench = None
        if separating_wrench is not None and np.isfinite(separating_wrench[k]).all():
            wrench = separating_wrench[k]
        arrays.append(grasp_markers(positions[k], normals[k], mu_per_contact[k], wanted,
                                    query_id=query_id, frame_id=frame_id,
                                    margin=float(margin[k]), separating_wrench=wrench))
        titles.append(f"{STATUS_LABELS[wanted]} (grasp {query_id})")
        chosen.append(k)
    if arrays:
        render_marker_arrays(arrays, path, titles=titles,
                             clouds=None if cloud is None else [cloud] * len(arrays))
    return chosen
