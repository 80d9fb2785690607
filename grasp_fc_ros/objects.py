"""Test objects as contact surfaces, and random n-finger grasps on them.

An object is represented the way the seed paper's experiment sees it: a finite
set of candidate contact points on its boundary, each with the unit INWARD
surface normal (pointing into the material, the direction a finger pushes).

Built-in objects are made in code (no downloads) by sampling their boundary
uniformly by area; user objects come from mesh files (OBJ/STL/PLY) or from
point clouds with normals (.npz or .ply). Only numpy is imported at module
level; trimesh is imported lazily, for mesh and PLY files only.

Lengths are in metres.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TypeAlias, cast

import numpy as np
import numpy.typing as npt

__all__ = [
    "ContactSurface",
    "OBJECT_NAMES",
    "DEFAULT_N_POINTS",
    "make_object",
    "load_surface",
    "sample_grasps",
]

DEFAULT_N_POINTS = 5000

# A normal this short or shorter cannot be turned into a direction. Same value and test
# as grasp_fc_ros.core.tolerances.ZERO_NORMAL_NORM, not imported from there because
# importing the core loads clarabel and scipy, and this module needs only numpy.
_MIN_NORMAL_LENGTH = 1e-12
# First oversampling factor for shapes whose samplers reject candidates.
_OVERSAMPLE = 1.5
_MAX_OVERSAMPLE_ROUNDS = 8

#: Points (k, 3) and unit inward normals (k, 3).
Contacts: TypeAlias = tuple[np.ndarray, np.ndarray]

#: A patch's sampler: (rng, k) -> up to k contacts.
Sampler: TypeAlias = Callable[[np.random.Generator, int], Contacts]

_MESH_SUFFIXES = (".obj", ".stl", ".ply")
_CLOUD_SUFFIXES = (".npz", ".ply")


@dataclass(frozen=True)
class ContactSurface:
    """Candidate contacts of one object.

    Attributes
    ----------
    name : str
        Object name (built-in name or file stem).
    points : numpy.ndarray, shape (M, 3), float64
        Contact positions [m]. Read-only.
    normals : numpy.ndarray, shape (M, 3), float64
        Unit inward surface normals (into the object). Read-only.

    Normals given with any non-zero length are normalised; NaN/inf values,
    zero-length normals and shape mismatches raise ValueError.
    """

    name: str
    points: np.ndarray
    normals: np.ndarray

    def __post_init__(self) -> None:
        points = np.array(self.points, dtype=np.float64)
        normals = np.array(self.normals, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3 or points.shape[0] == 0:
            raise ValueError(f"{self.name}: points must have shape (M, 3) with M >= 1, "
                             f"got {points.shape}")
        if normals.shape != points.shape:
            raise ValueError(f"{self.name}: normals shape {normals.shape} differs from "
                             f"points shape {points.shape}")
        if not (np.all(np.isfinite(points)) and np.all(np.isfinite(normals))):
            raise ValueError(f"{self.name}: points and normals must be finite")
        lengths = np.linalg.norm(normals, axis=1)
        short = np.flatnonzero(lengths <= _MIN_NORMAL_LENGTH)
        if short.size:
            raise ValueError(f"{self.name}: normal of point {short[0]} has zero length "
                             f"({short.size} such points)")
        normals /= lengths[:, None]
        points.setflags(write=False)
        normals.setflags(write=False)
        # frozen dataclass: store the validated copies
        object.__setattr__(self, "points", points)
        object.__setattr__(self, "normals", normals)

    def __len__(self) -> int:
        return self.points.shape[0]


# --------------------------------------------------------------------------
# Surface patches. Each patch samples candidates uniformly over a "nominal"
# area and may reject some (clipping, or area-weight correction); keeping the
# survivors of all patches at one common candidate density gives a sample that
# is uniform by true surface area.
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class _Patch:
    nominal_area: float
    sample: Sampler  # (rng, k) -> (points (k', 3), inward normals (k', 3)), k' <= k


def _disk_patch(radius: float, z: float, normal_z: float, inner_radius: float = 0.0,
                center: tuple[float, float] = (0.0, 0.0)) -> _Patch:
    """Flat disk or annulus at height z, normal (0, 0, normal_z)."""

    def sample(rng: np.random.Generator, k: int) -> Contacts:
        r = np.sqrt(inner_radius**2 + rng.random(k) * (radius**2 - inner_radius**2))
        t = rng.random(k) * 2.0 * np.pi
        pts = np.column_stack([center[0] + r * np.cos(t), center[1] + r * np.sin(t),
                               np.full(k, z)])
        nrm = np.tile([0.0, 0.0, normal_z], (k, 1))
        return pts, nrm

    return _Patch(np.pi * (radius**2 - inner_radius**2), sample)


def _tube_patch(radius: float, z0: float, z1: float, inward_sign: float) -> _Patch:
    """Cylindrical wall about the z axis; inward_sign -1: material inside the wall radius."""

    def sample(rng: np.random.Generator, k: int) -> Contacts:
        t = rng.random(k) * 2.0 * np.pi
        radial = np.column_stack([np.cos(t), np.sin(t), np.zeros(k)])
        pts = radial * radius
        pts[:, 2] = z0 + rng.random(k) * (z1 - z0)
        return pts, inward_sign * radial

    return _Patch(2.0 * np.pi * radius * (z1 - z0), sample)


def _in_polygon(xy: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Even-odd rule point-in-polygon test, vectorised. xy (k, 2), polygon (V, 2)."""
    x, y = xy[:, 0:1], xy[:, 1:2]
    ax, ay = polygon[:, 0], polygon[:, 1]
    bx, by = np.roll(ax, -1), np.roll(ay, -1)
    straddles = (ay > y) != (by > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_cross = ax + (y - ay) * (bx - ax) / (by - ay)
    return np.count_nonzero(straddles & (x < x_cross), axis=1) % 2 == 1


def _prism_patches(polygon: npt.ArrayLike, height: float) -> list[_Patch]:
    """Boundary of a simple polygon (counter-clockwise, (V, 2)) extruded over z in [0, height]."""
    polygon = np.asarray(polygon, dtype=np.float64)
    patches: list[_Patch] = []
    for a, b in zip(polygon, np.roll(polygon, -1, axis=0), strict=True):
        edge = b - a
        length = float(np.hypot(*edge))
        # counter-clockwise boundary: the interior is on the left of each edge
        inward = np.array([-edge[1], edge[0], 0.0]) / length

        def side(rng: np.random.Generator, k: int, a: np.ndarray = a, edge: np.ndarray = edge,
                 inward: np.ndarray = inward) -> Contacts:
            s = rng.random(k)
            pts = np.column_stack([a[0] + s * edge[0], a[1] + s * edge[1],
                                   rng.random(k) * height])
            return pts, np.tile(inward, (k, 1))

        patches.append(_Patch(length * height, side))

    lo, hi = polygon.min(axis=0), polygon.max(axis=0)
    for z, normal_z in ((0.0, 1.0), (height, -1.0)):

        def cap(rng: np.random.Generator, k: int, z: float = z,
                normal_z: float = normal_z) -> Contacts:
            xy = lo + rng.random((k, 2)) * (hi - lo)
            xy = xy[_in_polygon(xy, polygon)]
            pts = np.column_stack([xy, np.full(len(xy), z)])
            return pts, np.tile([0.0, 0.0, normal_z], (len(xy), 1))

        patches.append(_Patch(float(np.prod(hi - lo)), cap))
    return patches


def _torus_frame_sample(rng: np.random.Generator, k: int, major: float,
                        minor: float) -> Contacts:
    """Area-uniform samples of a torus about the z axis through the origin.

    Returns points and OUTWARD normals (the caller flips or clips).
    """
    u = rng.random(k) * 2.0 * np.pi
    v = rng.random(k) * 2.0 * np.pi
    # area element is minor * (major + minor cos v): thin out the inner side
    keep = rng.random(k) * (major + minor) < major + minor * np.cos(v)
    u, v = u[keep], v[keep]
    outward = np.column_stack([np.cos(v) * np.cos(u), np.cos(v) * np.sin(u), np.sin(v)])
    centre_line = major * np.column_stack([np.cos(u), np.sin(u), np.zeros(len(u))])
    return centre_line + minor * outward, outward


def _torus_area_bound(major: float, minor: float) -> float:
    return 4.0 * np.pi**2 * minor * (major + minor)


# --------------------------------------------------------------------------
# Built-in shapes
# --------------------------------------------------------------------------

_BOX = (0.10, 0.06, 0.04)
_CYLINDER = (0.03, 0.12)  # radius, height
_ELLIPSOID = (0.06, 0.04, 0.03)  # semi-axes
_TORUS = (0.05, 0.015)  # major, minor radius
_L_BLOCK = ([(0.0, 0.0), (0.10, 0.0), (0.10, 0.03), (0.03, 0.03), (0.03, 0.08), (0.0, 0.08)],
            0.04)
_STAR = (5, 0.05, 0.022, 0.03)  # points, outer radius, inner radius, height
# mug: outer radius, inner radius, height, bottom thickness,
#      handle major radius, handle tube radius
_MUG = (0.04, 0.035, 0.09, 0.006, 0.025, 0.007)


def _star_polygon(n_tips: int, outer: float, inner: float) -> np.ndarray:
    angles = np.pi / 2 + np.arange(2 * n_tips) * np.pi / n_tips
    radii = np.where(np.arange(2 * n_tips) % 2 == 0, outer, inner)
    return np.column_stack([radii * np.cos(angles), radii * np.sin(angles)])


def _box_patches() -> list[_Patch]:
    x, y, z = _BOX
    return _prism_patches([(0, 0), (x, 0), (x, y), (0, y)], z)


def _cylinder_patches() -> list[_Patch]:
    radius, height = _CYLINDER
    return [_tube_patch(radius, 0.0, height, -1.0),
            _disk_patch(radius, 0.0, 1.0), _disk_patch(radius, height, -1.0)]


def _ellipsoid_patches() -> list[_Patch]:
    axes = np.array(_ELLIPSOID)

    def sample(rng: np.random.Generator, k: int) -> Contacts:
        u = rng.standard_normal((k, 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        # the map u -> axes*u stretches area by prod(axes)*|u/axes|; keep by that weight
        stretch = np.linalg.norm(u / axes, axis=1) * axes.min()
        u = u[rng.random(k) < stretch]
        outward = u / axes
        outward /= np.linalg.norm(outward, axis=1, keepdims=True)
        return u * axes, -outward

    return [_Patch(4.0 * np.pi * np.prod(axes) / axes.min(), sample)]


def _torus_patches() -> list[_Patch]:
    major, minor = _TORUS

    def sample(rng: np.random.Generator, k: int) -> Contacts:
        pts, outward = _torus_frame_sample(rng, k, major, minor)
        return pts, -outward

    return [_Patch(_torus_area_bound(major, minor), sample)]


def _l_block_patches() -> list[_Patch]:
    polygon, height = _L_BLOCK
    return _prism_patches(polygon, height)


def _star_prism_patches() -> list[_Patch]:
    n_tips, outer, inner, height = _STAR
    return _prism_patches(_star_polygon(n_tips, outer, inner), height)


def _mug_handle_centre() -> np.ndarray:
    r_out, _, height, _, handle_major, _ = _MUG
    return np.array([r_out + 0.3 * handle_major, 0.0, 0.5 * height])


def _distance_to_handle_core(points: np.ndarray) -> np.ndarray:
    """Distance from points to the centre circle of the handle (a circle in the x-z plane)."""
    _, _, _, _, handle_major, _ = _MUG
    rel = points - _mug_handle_centre()
    in_plane = np.hypot(rel[:, 0], rel[:, 2])
    return np.hypot(in_plane - handle_major, rel[:, 1])


def _mug_patches() -> list[_Patch]:
    r_out, r_in, height, bottom, handle_major, handle_minor = _MUG
    wall = _tube_patch(r_out, 0.0, height, -1.0)

    def outer_wall(rng: np.random.Generator, k: int) -> Contacts:
        # drop the wall where the handle's tube enters it
        pts, nrm = wall.sample(rng, k)
        keep = _distance_to_handle_core(pts) > handle_minor
        return pts[keep], nrm[keep]

    def handle(rng: np.random.Generator, k: int) -> Contacts:
        pts, outward = _torus_frame_sample(rng, k, handle_major, handle_minor)
        # torus about z -> torus about y (handle in the x-z plane), then move it
        pts = pts[:, [0, 2, 1]] + _mug_handle_centre()
        outward = outward[:, [0, 2, 1]]
        keep = np.hypot(pts[:, 0], pts[:, 1]) > r_out  # only the part outside the wall
        return pts[keep], -outward[keep]

    return [
        _Patch(wall.nominal_area, outer_wall),
        _tube_patch(r_in, bottom, height, 1.0),  # inner wall: material is outside it
        _disk_patch(r_out, 0.0, 1.0),  # underside
        _disk_patch(r_in, bottom, -1.0),  # floor inside the cup
        _disk_patch(r_out, height, -1.0, inner_radius=r_in),  # rim
        _Patch(_torus_area_bound(handle_major, handle_minor), handle),
    ]


_BUILDERS = {
    "box": _box_patches,
    "cylinder": _cylinder_patches,
    "ellipsoid": _ellipsoid_patches,
    "torus": _torus_patches,
    "l_block": _l_block_patches,
    "star_prism": _star_prism_patches,
    "mug": _mug_patches,
}

OBJECT_NAMES = tuple(_BUILDERS)
"""Names accepted by :func:`make_object`. torus, l_block, star_prism and mug are non-convex."""


def _sample_patches(patches: list[_Patch], n_points: int, rng: np.random.Generator) -> Contacts:
    """Uniform-by-area sample of n_points from the union of patches."""
    nominal = np.array([p.nominal_area for p in patches])
    factor = _OVERSAMPLE
    for _ in range(_MAX_OVERSAMPLE_ROUNDS):
        counts = rng.multinomial(int(np.ceil(factor * n_points)), nominal / nominal.sum())
        parts = [p.sample(rng, int(c)) for p, c in zip(patches, counts, strict=True)]
        points = np.concatenate([pts for pts, _ in parts])
        normals = np.concatenate([nrm for _, nrm in parts])
        if len(points) >= n_points:
            chosen = rng.choice(len(points), size=n_points, replace=False)
            return points[chosen], normals[chosen]
        factor *= 2.0
    raise RuntimeError("surface sampler rejected too many candidates")  # pragma: no cover


def make_object(name: str, n_points: int = DEFAULT_N_POINTS, seed: int = 0) -> ContactSurface:
    """Build a built-in object as a contact surface.

    Parameters
    ----------
    name : str
        One of :data:`OBJECT_NAMES`.
    n_points : int
        Number of contact points sampled uniformly by area on the boundary.
    seed : int
        Seed of the sampling; the same (name, n_points, seed) gives the same surface.

    Returns
    -------
    ContactSurface
        Points [m] centred on the object's bounding-box centre, unit inward normals.
    """
    if name not in _BUILDERS:
        raise ValueError(f"unknown object {name!r}; built-in objects: {', '.join(OBJECT_NAMES)}")
    if n_points < 1:
        raise ValueError(f"n_points must be >= 1, got {n_points}")
    rng = np.random.default_rng(seed)
    points, normals = _sample_patches(_BUILDERS[name](), n_points, rng)
    points = points - _bbox_centre(name)
    return ContactSurface(name, points, normals)


def _bbox_centre(name: str) -> np.ndarray:
    """Centre of the shape's bounding box in its construction frame."""
    if name == "box":
        return 0.5 * np.array(_BOX)
    if name == "cylinder":
        return np.array([0.0, 0.0, 0.5 * _CYLINDER[1]])
    if name == "l_block":
        polygon, height = _L_BLOCK
        return np.append(0.5 * (np.min(polygon, axis=0) + np.max(polygon, axis=0)), 0.5 * height)
    if name == "star_prism":
        n_tips, outer, inner, height = _STAR
        star = _star_polygon(n_tips, outer, inner)
        return np.append(0.5 * (star.min(axis=0) + star.max(axis=0)), 0.5 * height)
    if name == "mug":
        r_out, _, height, _, handle_major, handle_minor = _MUG
        x_max = _mug_handle_centre()[0] + handle_major + handle_minor
        return np.array([0.5 * (x_max - r_out), 0.0, 0.5 * height])
    return np.zeros(3)  # ellipsoid and torus are built centred


def _inside(name: str, points: npt.ArrayLike) -> np.ndarray:
    """True where points (k, 3) lie in the interior of built-in object `name`.

    An independent (solid, not surface) description of each shape, used by the
    tests to check that the sampled normals point inward.
    """
    p = np.asarray(points, dtype=np.float64) + _bbox_centre(name)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    if name == "box":
        return np.all((p > 0) & (p < np.array(_BOX)), axis=1)
    if name == "cylinder":
        radius, height = _CYLINDER
        return (np.hypot(x, y) < radius) & (z > 0) & (z < height)
    if name == "ellipsoid":
        return np.sum((p / np.array(_ELLIPSOID)) ** 2, axis=1) < 1.0
    if name == "torus":
        major, minor = _TORUS
        return np.hypot(np.hypot(x, y) - major, z) < minor
    if name == "l_block":
        polygon, height = _L_BLOCK
        return _in_polygon(p[:, :2], np.array(polygon)) & (z > 0) & (z < height)
    if name == "star_prism":
        n_tips, outer, inner, height = _STAR
        return _in_polygon(p[:, :2], _star_polygon(n_tips, outer, inner)) & (z > 0) & (z < height)
    if name == "mug":
        r_out, r_in, height, bottom, _, handle_minor = _MUG
        radial = np.hypot(x, y)
        cup = (radial < r_out) & (z > 0) & (z < height) & ~((radial < r_in) & (z > bottom))
        handle = (_distance_to_handle_core(p) < handle_minor) & (radial >= r_out)
        return cup | handle
    raise ValueError(f"unknown object {name!r}")


# --------------------------------------------------------------------------
# Files
# --------------------------------------------------------------------------


def load_surface(path: str | os.PathLike[str], n_points: int = DEFAULT_N_POINTS, seed: int = 0,
                 cloud_normals: str = "outward") -> ContactSurface:
    """Load an object from a mesh file or a point cloud with normals.

    Parameters
    ----------
    path : str or pathlib.Path
        - ``.obj``, ``.stl``, ``.ply`` with faces: a triangle mesh (loaded with
          trimesh). ``n_points`` points are sampled uniformly by area on the
          surface; each normal is its face's normal negated (faces must be wound
          counter-clockwise seen from outside, the usual convention; a closed
          mesh wound the other way round is detected by its negative volume and
          flipped).
        - ``.npz`` with arrays ``points`` (M, 3) and ``normals`` (M, 3), or a
          ``.ply`` without faces whose vertices carry ``nx, ny, nz``: a point
          cloud, used as is (all M points).
    n_points : int
        Number of points sampled on a mesh (ignored for point clouds).
    seed : int
        Seed of the mesh sampling.
    cloud_normals : {"outward", "inward"}
        Direction of the normals stored in a point cloud. "outward" (the usual
        convention of scanners, PCL and Open3D) negates them; "inward" keeps them.

    Returns
    -------
    ContactSurface
        Named after the file stem; points in the file's units (metres expected).

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    ValueError
        Unsupported suffix, empty mesh, point cloud without normals, missing
        arrays, or bad values (see :class:`ContactSurface`).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    if cloud_normals not in ("outward", "inward"):
        raise ValueError(f"cloud_normals must be 'outward' or 'inward', got {cloud_normals!r}")
    suffix = path.suffix.lower()
    if suffix not in _MESH_SUFFIXES + _CLOUD_SUFFIXES:
        raise ValueError(f"{path}: unsupported file type {suffix!r}; expected one of "
                         f"{', '.join(sorted(set(_MESH_SUFFIXES + _CLOUD_SUFFIXES)))}")
    sign = -1.0 if cloud_normals == "outward" else 1.0
    if suffix == ".npz":
        points, normals = _read_npz(path)
        return ContactSurface(path.stem, points, sign * normals)
    if suffix == ".ply":
        cloud = _read_ply_cloud(path)
        if cloud is not None:
            points, normals = cloud
            return ContactSurface(path.stem, points, sign * normals)
    return _sample_mesh(path, n_points, seed)


def _read_npz(path: Path) -> Contacts:
    with np.load(path) as data:
        missing = [key for key in ("points", "normals") if key not in data.files]
        if missing:
            raise ValueError(f"{path}: missing array(s) {', '.join(missing)}; a point cloud "
                             f".npz needs 'points' (M, 3) and 'normals' (M, 3), found "
                             f"{', '.join(data.files) or 'none'}")
        return data["points"], data["normals"]


def _read_ply_cloud(path: Path) -> Contacts | None:
    """(points, normals) if the PLY file is a point cloud, None if it has faces."""
    from trimesh.exchange.ply import load_ply  # heavy import, PLY files only

    with open(path, "rb") as handle:
        try:
            content = load_ply(handle)
        except Exception as error:  # trimesh raises several types on malformed files
            raise ValueError(f"{path}: cannot parse PLY file: {error}") from error
    faces = content.get("faces")
    if faces is not None and len(faces) > 0:
        return None
    normals = content.get("vertex_normals")
    if normals is None:
        raise ValueError(f"{path}: PLY point cloud has no normals (vertex properties "
                         "nx, ny, nz); contacts need normals")
    return content["vertices"], normals


def _sample_mesh(path: Path, n_points: int, seed: int) -> ContactSurface:
    import trimesh  # heavy import, mesh files only

    try:
        mesh = cast("trimesh.Trimesh", trimesh.load(path, force="mesh"))
    except Exception as error:  # trimesh raises several types on malformed files
        raise ValueError(f"{path}: cannot load mesh: {error}") from error
    if len(mesh.faces) == 0 or mesh.area <= 0.0:
        raise ValueError(f"{path}: mesh has no faces with positive area")
    points, faces = trimesh.sample.sample_surface(mesh, n_points, seed=seed)
    outward = mesh.face_normals[faces]
    if mesh.is_watertight and mesh.volume < 0.0:
        outward = -outward  # closed mesh wound inside out
    return ContactSurface(path.stem, points, -outward)


# --------------------------------------------------------------------------
# Grasps
# --------------------------------------------------------------------------


def sample_grasps(surface: ContactSurface, n_grasps: int, n_fingers: int,
                  rng: np.random.Generator) -> Contacts:
    """Draw random grasps: n_fingers distinct contacts of the surface per grasp.

    Parameters
    ----------
    surface : ContactSurface
        Candidate contacts (M points).
    n_grasps : int
        Number of grasps N.
    n_fingers : int
        Contacts per grasp n, 1 <= n <= M.
    rng : numpy.random.Generator
        Source of randomness; the same generator state gives the same grasps.

    Returns
    -------
    positions : numpy.ndarray, shape (N, n, 3), float64
        Contact positions [m].
    normals : numpy.ndarray, shape (N, n, 3), float64
        Unit inward normals.
    """
    n_available = len(surface)
    if not 1 <= n_fingers <= n_available:
        raise ValueError(f"n_fingers must be in [1, {n_available}] for {surface.name}, "
                         f"got {n_fingers}")
    if n_grasps < 0:
        raise ValueError(f"n_grasps must be >= 0, got {n_grasps}")
    index = _distinct_rows(n_grasps, n_fingers, n_available, rng)
    return surface.points[index], surface.normals[index]


def _distinct_rows(n_rows: int, n_cols: int, n_values: int,
                   rng: np.random.Generator) -> np.ndarray:
    """(n_rows, n_cols) integers in [0, n_values), distinct within each row.

    Rows are drawn independently and uniformly; rows with a repeat are redrawn
    (rare when n_cols << n_values), which keeps the draw exactly uniform over
    ordered distinct tuples. When repeats would be common, rows are prefixes of
    random permutations instead.
    """
    if n_cols * n_cols > n_values:
        return np.argsort(rng.random((n_rows, n_values)), axis=1)[:, :n_cols]
    index = rng.integers(0, n_values, size=(n_rows, n_cols))
    redo = _rows_with_repeats(index)
    while redo.size:
        index[redo] = rng.integers(0, n_values, size=(redo.size, n_cols))
        redo = redo[_rows_with_repeats(index[redo])]
    return index


def _rows_with_repeats(index: np.ndarray) -> np.ndarray:
    ordered = np.sort(index, axis=1)
    return np.flatnonzero(np.any(ordered[:, 1:] == ordered[:, :-1], axis=1))
