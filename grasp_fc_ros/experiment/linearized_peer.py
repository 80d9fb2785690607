"""The linearized force-closure test a user would otherwise pick (GraspIt!/Dex-Net style).

Each friction cone is replaced by an inscribed m-sided pyramid; the grasp is
called force closure iff the origin of wrench space lies strictly inside the
convex hull of the n*m primitive wrenches, decided with Qhull
(scipy.spatial.ConvexHull). The inscribed pyramid is smaller than the cone, so
this test can miss force-closure grasps (more often with few sides) but cannot
accept a grasp the exact test rejects, up to the margin below.

Used only by the experiment, as the baseline our filter-then-exact pipeline is
compared with; scipy is imported here and never by grasp_fc_ros.core.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.spatial import ConvexHull, QhullError

DEFAULT_SIDES = 8

# Origin-to-facet distance (in wrench units scaled as below) that counts as
# "strictly inside"; Qhull's own round-off on these hulls is ~1e-15.
INSIDE_MARGIN = 1e-9


def pyramid_edges(normals: npt.ArrayLike, mu: float, sides: int = DEFAULT_SIDES) -> np.ndarray:
    """Edge directions of the pyramids inscribed in the friction cones.

    Parameters
    ----------
    normals : numpy.ndarray, shape (n, 3)
        Inward contact normals (any non-zero length).
    mu : float
        Friction coefficient, > 0.
    sides : int
        Number of pyramid edges m >= 3.

    Returns
    -------
    numpy.ndarray, shape (n, m, 3)
        Unit force directions on the cone boundary, evenly spaced around the normal.
    """
    unit = np.asarray(normals, dtype=np.float64)
    unit = unit / np.linalg.norm(unit, axis=-1, keepdims=True)
    # a tangent not parallel to n: cross with the coordinate axis least aligned with n
    helper = np.eye(3)[np.argmin(np.abs(unit), axis=-1)]
    t1 = np.cross(unit, helper)
    t1 /= np.linalg.norm(t1, axis=-1, keepdims=True)
    t2 = np.cross(unit, t1)
    angles = 2.0 * np.pi * np.arange(sides) / sides
    edges = (unit[:, None, :]
             + mu * (np.cos(angles)[None, :, None] * t1[:, None, :]
                     + np.sin(angles)[None, :, None] * t2[:, None, :]))
    return edges / np.linalg.norm(edges, axis=-1, keepdims=True)


def primitive_wrenches(positions: npt.ArrayLike, normals: npt.ArrayLike, mu: float,
                       sides: int = DEFAULT_SIDES) -> np.ndarray:
    """The n*m primitive wrenches (force, torque / length scale) of one grasp.

    Torques are taken about the contacts' centroid and divided by the largest
    contact distance from it, so forces and torques have comparable size; both
    are linear invertible changes of wrench space and do not change whether the
    origin is inside the hull.

    Returns
    -------
    numpy.ndarray, shape (n*m, 6)
    """
    positions = np.asarray(positions, dtype=np.float64)
    lever = positions - positions.mean(axis=0)
    scale = np.linalg.norm(lever, axis=1).max()
    if scale > 0.0:
        lever = lever / scale
    forces = pyramid_edges(normals, mu, sides)
    torques = np.cross(lever[:, None, :], forces)
    return np.concatenate([forces, torques], axis=-1).reshape(-1, 6)


def linearized_margin(positions: npt.ArrayLike, normals: npt.ArrayLike, mu: float,
                      sides: int = DEFAULT_SIDES) -> float:
    """Distance from the origin to the boundary of the primitive wrenches' hull.

    Positive when the origin is inside the hull (Qhull facet equations
    a.x + b <= 0 inside, with unit a, so the origin's distance to a facet is -b),
    negative when outside, 0.0 when the wrenches do not span wrench space.
    """
    wrenches = primitive_wrenches(positions, normals, mu, sides)
    try:
        hull = ConvexHull(wrenches)
    except QhullError:
        return 0.0  # flat hull: the wrenches lie in a hyperplane, no force closure
    return float(-hull.equations[:, -1].max())


def linearized_force_closure(positions: npt.ArrayLike, normals: npt.ArrayLike, mu: float,
                             sides: int = DEFAULT_SIDES) -> np.ndarray | np.bool_:
    """Linearized force-closure verdicts.

    Parameters
    ----------
    positions, normals : numpy.ndarray, shape (n, 3) or (N, n, 3)
        Contact positions and inward normals.
    mu : float
        Friction coefficient.
    sides : int
        Pyramid sides m.

    Returns
    -------
    numpy.ndarray of bool, shape () or (N,)
        True where the origin is strictly inside the hull (margin > INSIDE_MARGIN).
    """
    positions = np.asarray(positions, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    if positions.ndim == 2:
        return np.bool_(linearized_margin(positions, normals, mu, sides) > INSIDE_MARGIN)
    return np.array([linearized_margin(p, n, mu, sides) > INSIDE_MARGIN
                     for p, n in zip(positions, normals, strict=True)], dtype=bool)
