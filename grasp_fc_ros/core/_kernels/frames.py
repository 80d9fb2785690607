"""Per-contact frames, wrench rows and the work a wrench does at a contact (numba).

Positions are those of a unit-size grasp (centred, largest coordinate 1); a wrench is
(force, torque about the origin), 6 floats. Per-contact vectors go in and out as tuples
(:data:`.jit.Vector3`; read a row with :func:`.jit.row`).
"""

from __future__ import annotations

import numpy as np

from .jit import Vector3, jit


@jit
def tangent_frames(normals: np.ndarray, first: np.ndarray, second: np.ndarray) -> None:
    """Tangents completing each unit normal to a right-handed orthonormal frame.

    Duff et al.'s branch-free construction ("Building an Orthonormal Basis, Revisited").

    Parameters
    ----------
    normals : ndarray, shape (n, 3)
        Unit normals.
    first, second : ndarray, shape (n, 3)
        Outputs: the two unit tangents of each contact.
    """
    n = normals.shape[0]
    for i in range(n):
        x, y, z = normals[i, 0], normals[i, 1], normals[i, 2]
        sign = 1.0 if z >= 0.0 else -1.0
        a = -1.0 / (sign + z)
        b = x * y * a
        first[i, 0], first[i, 1], first[i, 2] = 1.0 + sign * x * x * a, sign * b, -sign * x
        second[i, 0], second[i, 1], second[i, 2] = b, sign + y * y * a, -y


@jit
def wrench_rows(unit: np.ndarray, direction: np.ndarray, rows: np.ndarray) -> None:
    """Wrenches of unit forces along ``direction`` at the contacts.

    Parameters
    ----------
    unit : ndarray, shape (n, 3)
        Contact positions.
    direction : ndarray, shape (n, 3)
        One force direction per contact.
    rows : ndarray, shape (n, 6)
        Output: row i is (e_i, p_i x e_i).
    """
    for i in range(unit.shape[0]):
        u, e = unit[i], direction[i]
        rows[i, 0], rows[i, 1], rows[i, 2] = e[0], e[1], e[2]
        rows[i, 3] = u[1] * e[2] - u[2] * e[1]
        rows[i, 4] = u[2] * e[0] - u[0] * e[2]
        rows[i, 5] = u[0] * e[1] - u[1] * e[0]


@jit
def work_at(w: np.ndarray, point: Vector3) -> Vector3:
    """The work vector w_F + w_T x point of a wrench at a point: G_i^T w for the contact
    there (the work a unit force along each axis does on w).

    Parameters
    ----------
    w : ndarray, shape (6,)
        Wrench (force w_F, torque w_T).
    point : Vector3

    Returns
    -------
    Vector3
    """
    return (w[0] + w[4] * point[2] - w[5] * point[1],
            w[1] + w[5] * point[0] - w[3] * point[2],
            w[2] + w[3] * point[1] - w[4] * point[0])


@jit
def normal_split(x: Vector3, normal: Vector3) -> tuple[float, float]:
    """Normal component and tangential length of a vector.

    Parameters
    ----------
    x : Vector3
    normal : Vector3
        Unit normal.

    Returns
    -------
    (float, float)
        n . x and |x - (n . x) n|.
    """
    x0, x1, x2 = x
    x_n = x0 * normal[0] + x1 * normal[1] + x2 * normal[2]
    x_t = np.sqrt((x0 - x_n * normal[0]) ** 2 + (x1 - x_n * normal[1]) ** 2
                  + (x2 - x_n * normal[2]) ** 2)
    return x_n, x_t
