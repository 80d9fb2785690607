"""RViz markers for one answered grasp query: contacts, friction cones, verdict, wrench.

The geometry is computed by small ROS-free numpy functions (:func:`cone_axes`,
:func:`friction_cone_triangles`, :func:`separating_arrows`); :func:`grasp_markers` only
copies their results into a ``visualization_msgs/MarkerArray``.

Each query's markers live in their own namespace ``grasp_<id>`` with fixed ids:

===  ======================  ===================================================
 id  type                    what
===  ======================  ===================================================
  0  SPHERE_LIST             one sphere per contact (finite positions only)
  1  TRIANGLE_LIST           the friction cones' side surfaces
  2  ARROW                   separating wrench, force part at the centroid
  3  ARROW                   separating wrench, torque part (rotation axis)
  4  TEXT_VIEW_FACING        ``grasp <id>: <verdict>`` and the margin
===  ======================  ===================================================

Markers 2 and 3 are present only when a separating wrench is given (and that part of
it is not zero). All lengths are in the units of the positions (metres in ROS).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from builtin_interfaces.msg import Duration, Time
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from grasp_fc_ros.core import Status

#: RGBA per verdict: green, orange, red, grey, magenta, and white for UNKNOWN (a
#: zero-initialised verdict; colour-blind friendly enough with the text label beside it).
STATUS_COLORS: dict[Status, tuple[float, float, float, float]] = {
    Status.UNKNOWN: (0.95, 0.95, 0.95, 1.0),
    Status.FORCE_CLOSURE: (0.10, 0.70, 0.20, 1.0),
    Status.FILTERED_OUT: (1.00, 0.55, 0.00, 1.0),
    Status.NOT_FORCE_CLOSURE: (0.85, 0.10, 0.10, 1.0),
    Status.INVALID_INPUT: (0.50, 0.50, 0.50, 1.0),
    Status.SOLVER_FAILURE: (0.75, 0.00, 0.75, 1.0),
}
STATUS_LABELS: dict[Status, str] = {
    Status.UNKNOWN: "no verdict",
    Status.FORCE_CLOSURE: "force closure",
    Status.FILTERED_OUT: "rejected by the filter",
    Status.NOT_FORCE_CLOSURE: "not force closure",
    Status.INVALID_INPUT: "invalid input",
    Status.SOLVER_FAILURE: "solver failure",
}
#: Cones are drawn translucent so that the contacts and the object stay visible.
CONE_ALPHA = 0.45
WRENCH_FORCE_COLOR = (0.10, 0.30, 0.95, 1.0)
WRENCH_TORQUE_COLOR = (0.00, 0.75, 0.85, 1.0)

DEFAULT_CONE_LENGTH = 0.02      # slant length of a drawn cone (m)
DEFAULT_CONE_SEGMENTS = 12      # triangles per cone
DEFAULT_SPHERE_DIAMETER = 0.006  # m
DEFAULT_ARROW_LENGTH = 0.04     # m
DEFAULT_TEXT_HEIGHT = 0.008     # m
DEFAULT_LIFETIME_S = 10.0       # 0 means forever in RViz

# A wrench part shorter than this fraction of the whole wrench is not drawn: its
# direction is rounding noise.
_WRENCH_PART_RTOL = 1e-9

CONTACTS_ID, CONES_ID, FORCE_ARROW_ID, TORQUE_ARROW_ID, TEXT_ID = range(5)


def marker_namespace(query_id: int) -> str:
    """The namespace of one query's markers: ``"grasp_<id>"``."""
    return f"grasp_{int(query_id)}"


# --- geometry (ROS-free) ------------------------------------------------------------


def cone_axes(normals: np.ndarray) -> np.ndarray:
    """Unit axes of the drawn friction cones: ``-normal / |normal|``.

    Normals point into the object, so the cone of forces the finger may push with
    opens on the finger's side, away from the object.

    Parameters
    ----------
    normals : (n, 3) float array
        Inward contact normals, any non-zero length.

    Returns
    -------
    (n, 3) float array of unit vectors.
    """
    normals = np.asarray(normals, dtype=float)
    return -normals / np.linalg.norm(normals, axis=-1, keepdims=True)


def _orthonormal_frames(axes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (n, 3) each, orthogonal to each unit axis and to each other."""
    # Cross with the coordinate axis least aligned with the axis: never near-parallel.
    helper = np.eye(3)[np.argmin(np.abs(axes), axis=-1)]
    u = np.cross(axes, helper)
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    return u, np.cross(axes, u)


def friction_cone_rims(positions: np.ndarray, normals: np.ndarray, mu: np.ndarray,
                       length: float = DEFAULT_CONE_LENGTH,
                       segments: int = DEFAULT_CONE_SEGMENTS) -> np.ndarray:
    """Rim vertices of the drawn friction cones.

    Each rim vertex lies at slant distance ``length`` from the apex (the contact),
    at angle ``atan(mu)`` from the cone's axis :func:`cone_axes`.

    Parameters
    ----------
    positions, normals : (n, 3) float arrays
        Contact points and inward normals.
    mu : (n,) float array
        Friction coefficient per contact, finite and > 0.
    length : float
        Slant length of the drawn cone (units of ``positions``).
    segments : int
        Number of rim vertices (>= 3).

    Returns
    -------
    (n, segments, 3) float array.
    """
    if segments < 3:
        raise ValueError(f"segments must be >= 3, got {segments}")
    positions = np.asarray(positions, dtype=float)
    axes = cone_axes(normals)
    u, v = _orthonormal_frames(axes)
    half_angle = np.arctan(np.asarray(mu, dtype=float))[:, None, None]
    theta = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)[None, :, None]
    around = np.cos(theta) * u[:, None, :] + np.sin(theta) * v[:, None, :]
    direction = np.cos(half_angle) * axes[:, None, :] + np.sin(half_angle) * around
    return positions[:, None, :] + length * direction


def friction_cone_triangles(positions: np.ndarray, normals: np.ndarray, mu: np.ndarray,
                            length: float = DEFAULT_CONE_LENGTH,
                            segments: int = DEFAULT_CONE_SEGMENTS) -> np.ndarray:
    """Side surface of each drawn friction cone as triangles (apex, rim k, rim k+1).

    Parameters are those of :func:`friction_cone_rims`.

    Returns
    -------
    (n, segments, 3, 3) float array: cone, triangle, vertex, coordinate.
    """
    rims = friction_cone_rims(positions, normals, mu, length, segments)
    apexes = np.broadcast_to(np.asarray(positions, dtype=float)[:, None, :], rims.shape)
    return np.stack([apexes, rims, np.roll(rims, -1, axis=1)], axis=2)


def separating_arrows(wrench: np.ndarray, centroid: np.ndarray,
                      length: float = DEFAULT_ARROW_LENGTH) -> dict[int, np.ndarray]:
    """Arrows (start, end) of a separating wrench, drawn from the contacts' centroid.

    The wrench ``w = (force part, torque part)`` is about the frame origin, as the core
    reports it: at a point ``p`` it acts as ``w[:3] + w[3:] x p`` (see issue 9). The
    force arrow therefore shows ``w[:3] + w[3:] x centroid``; the torque arrow shows
    ``w[3:]``, which does not depend on the point. Both are drawn with the same
    display length: the wrench is a direction, its size means nothing.

    Parameters
    ----------
    wrench : (6,) float array
    centroid : (3,) float array
    length : float
        Display length of each arrow.

    Returns
    -------
    dict from marker id (:data:`FORCE_ARROW_ID`, :data:`TORQUE_ARROW_ID`) to a (2, 3)
    array (start, end); a part shorter than a tiny fraction of the wrench is left out.
    """
    wrench = np.asarray(wrench, dtype=float)
    centroid = np.asarray(centroid, dtype=float)
    scale = np.linalg.norm(wrench)
    parts = {FORCE_ARROW_ID: wrench[:3] + np.cross(wrench[3:], centroid),
             TORQUE_ARROW_ID: wrench[3:]}
    arrows = {}
    for marker_id, part in parts.items():
        size = np.linalg.norm(part)
        if scale > 0 and size > _WRENCH_PART_RTOL * scale:
            arrows[marker_id] = np.stack([centroid, centroid + length * part / size])
    return arrows


def _drawable_cones(positions: np.ndarray, normals: np.ndarray, mu: np.ndarray) -> np.ndarray:
    """(n,) bool: contacts whose cone can be drawn (finite, non-zero normal, mu > 0)."""
    with np.errstate(invalid="ignore", over="ignore"):
        return (np.isfinite(positions).all(-1) & np.isfinite(normals).all(-1)
                & (np.linalg.norm(normals, axis=-1) > 0) & np.isfinite(mu) & (mu > 0))


# --- messages ---------------------------------------------------------------------


def _points(vertices: np.ndarray) -> list[Point]:
    """geometry_msgs/Point per row of (..., 3) finite vertices.

    Fills the generated class's slots directly: its constructor's per-field checks cost
    several times as much (measured: docs/performance.md#markers). The values are
    Python floats from ``tolist()``, finite by construction, which is all those checks
    verify; test/markers/test_markers.py checks the points equal constructed ones.
    """
    points = []
    for x, y, z in vertices.reshape(-1, 3).tolist():
        point = _new_point(Point)
        point._x, point._y, point._z, point._check_fields = x, y, z, False
        points.append(point)
    return points


_new_point = Point.__new__


def _color(rgba: Sequence[float], alpha: float | None = None) -> ColorRGBA:
    r, g, b, a = rgba
    return ColorRGBA(r=r, g=g, b=b, a=a if alpha is None else alpha)


def _duration(seconds: float) -> Duration:
    nanoseconds = round(seconds * 1e9)
    return Duration(sec=nanoseconds // 1_000_000_000, nanosec=nanoseconds % 1_000_000_000)


def _marker(kind: int, marker_id: int, ns: str, frame_id: str, stamp: Time,
            lifetime: Duration, color: ColorRGBA) -> Marker:
    marker = Marker(type=kind, id=marker_id, ns=ns, action=Marker.ADD, lifetime=lifetime,
                    color=color)
    marker.header.frame_id = frame_id
    marker.header.stamp = stamp
    marker.pose.orientation.w = 1.0  # identity: the points are in the frame itself
    return marker


def _check_query(positions: np.ndarray, normals: np.ndarray, mu: np.ndarray | float,
                 wrench: np.ndarray | Sequence[float] | None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """The query's arrays as float arrays, mu broadcast to (n,); ValueError if malformed."""
    positions = np.asarray(positions, dtype=float)
    normals = np.asarray(normals, dtype=float)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise ValueError(f"positions must have shape (n, 3), got {positions.shape}")
    if normals.shape != positions.shape:
        raise ValueError(f"normals must have the shape of positions {positions.shape}, "
                         f"got {normals.shape}")
    mu = np.asarray(mu, dtype=float)
    if mu.shape not in ((), positions.shape[:1]):
        raise ValueError(f"mu must be a scalar or have shape ({len(positions)},), "
                         f"got {mu.shape}")
    mu = np.broadcast_to(mu, positions.shape[:1])
    if wrench is not None:
        wrench = np.asarray(wrench, dtype=float)
        if wrench.shape != (6,):
            raise ValueError(f"separating_wrench must have shape (6,), got {wrench.shape}")
        if not np.isfinite(wrench).all():
            raise ValueError("separating_wrench must be finite")
    return positions, normals, mu, wrench


def _check_sizes(**sizes: float) -> None:
    for name, value in sizes.items():
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be finite and > 0, got {value}")


def _text(query_id: int, status: Status, margin: float | None) -> str:
    text = f"grasp {int(query_id)}: {STATUS_LABELS[status]}"
    if margin is not None and math.isfinite(margin):
        text += f"\nmargin {margin:.3g}"
    return text


def grasp_markers(positions: np.ndarray, normals: np.ndarray, mu: np.ndarray | float,
                  status: int, *, query_id: int, frame_id: str, stamp: Time | None = None,
                  margin: float | None = None, separating_wrench: np.ndarray | None = None,
                  lifetime_s: float = DEFAULT_LIFETIME_S,
                  cone_length: float = DEFAULT_CONE_LENGTH,
                  cone_segments: int = DEFAULT_CONE_SEGMENTS,
                  sphere_diameter: float = DEFAULT_SPHERE_DIAMETER,
                  arrow_length: float = DEFAULT_ARROW_LENGTH,
                  text_height: float = DEFAULT_TEXT_HEIGHT) -> MarkerArray:
    """The markers of one answered query (see the module docstring for their ids).

    Contacts with a non-finite position get no sphere, and those whose cone cannot be
    drawn (non-finite or zero normal, mu not finite and > 0) no cone, so that an
    ``INVALID_INPUT`` query still shows what it can.

    Parameters
    ----------
    positions, normals : (n, 3) float arrays
        Contact points and inward normals in ``frame_id`` (units of the frame, m).
    mu : float or (n,) float array
        The friction coefficient each contact was decided with (the node's default
        already substituted).
    status : int
        A :class:`grasp_fc_ros.core.Status` code; it sets the colours.
    query_id : int
        The query's id; it names the namespace ``grasp_<id>``.
    frame_id : str
        Frame of every marker (the query's ``header.frame_id``).
    stamp : builtin_interfaces/Time, optional
        The query's stamp; zero (RViz: latest transform) if not given.
    margin : float, optional
        Shown in the text marker when finite.
    separating_wrench : (6,) float array, optional
        (force part, torque part) about the frame origin; drawn as arrows.
    lifetime_s : float
        Seconds until RViz drops the markers (0: never).
    cone_length, cone_segments, sphere_diameter, arrow_length, text_height
        Display sizes (units of the frame) and cone resolution.

    Returns
    -------
    visualization_msgs/MarkerArray
    """
    positions, normals, mu, wrench = _check_query(positions, normals, mu, separating_wrench)
    _check_sizes(cone_length=cone_length, sphere_diameter=sphere_diameter,
                 arrow_length=arrow_length, text_height=text_height)
    if not (math.isfinite(lifetime_s) and lifetime_s >= 0):
        raise ValueError(f"lifetime_s must be finite and >= 0, got {lifetime_s}")
    status = Status(int(status))
    ns, stamp = marker_namespace(query_id), stamp if stamp is not None else Time()
    lifetime, rgba = _duration(lifetime_s), STATUS_COLORS[status]

    def new(kind: int, marker_id: int, color: ColorRGBA) -> Marker:
        return _marker(kind, marker_id, ns, frame_id, stamp, lifetime, color)

    finite = np.isfinite(positions).all(-1)
    centroid = positions[finite].mean(0) if finite.any() else np.zeros(3)

    spheres = new(Marker.SPHERE_LIST, CONTACTS_ID, _color(rgba))
    spheres.scale.x = spheres.scale.y = spheres.scale.z = float(sphere_diameter)
    spheres.points = _points(positions[finite])
    markers = [spheres]

    cones = new(Marker.TRIANGLE_LIST, CONES_ID, _color(rgba, CONE_ALPHA))
    cones.scale.x = cones.scale.y = cones.scale.z = 1.0  # TRIANGLE_LIST: a scale factor
    drawable = _drawable_cones(positions, normals, mu)
    cones.points = _points(friction_cone_triangles(
        positions[drawable], normals[drawable], mu[drawable], cone_length, cone_segments))
    markers.append(cones)

    if wrench is not None:
        colors = {FORCE_ARROW_ID: WRENCH_FORCE_COLOR, TORQUE_ARROW_ID: WRENCH_TORQUE_COLOR}
        for marker_id, ends in separating_arrows(wrench, centroid, arrow_length).items():
            arrow = new(Marker.ARROW, marker_id, _color(colors[marker_id]))
            arrow.points = _points(ends)
            # ARROW with points: shaft diameter, head diameter, head length.
            arrow.scale.x, arrow.scale.y, arrow.scale.z = (
                0.05 * arrow_length, 0.12 * arrow_length, 0.25 * arrow_length)
            markers.append(arrow)

    text = new(Marker.TEXT_VIEW_FACING, TEXT_ID, _color(rgba))
    text.scale.z = float(text_height)
    top = positions[finite, 2].max() if finite.any() else 0.0
    text.pose.position = Point(x=float(centroid[0]), y=float(centroid[1]),
                               z=float(top + cone_length + 2 * text_height))
    text.text = _text(query_id, status, margin)
    markers.append(text)
    return MarkerArray(markers=markers)


def delete_all_markers(frame_id: str = "", stamp: Time | None = None) -> MarkerArray:
    """A MarkerArray whose one DELETEALL marker clears every marker of its topic.

    Parameters
    ----------
    frame_id : str
        Header frame (RViz ignores it for DELETEALL, some tools want one).
    stamp : builtin_interfaces/Time, optional

    Returns
    -------
    visualization_msgs/MarkerArray
    """
    marker = Marker(action=Marker.DELETEALL)
    marker.header.frame_id = frame_id
    marker.header.stamp = stamp if stamp is not None else Time()
    return MarkerArray(markers=[marker])
