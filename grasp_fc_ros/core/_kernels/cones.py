"""The second-order cone Q^3 = {x : x0 >= |(x1, x2)|} in interior-point steps (numba).

Jordan algebra of Q^3: x o y = (x . y, x0 y_t + y0 x_t), identity e = (1, 0, 0),
J = diag(1, -1, -1), det x = x0^2 - |x_t|^2. Nesterov-Todd scaling of an interior pair
(z, s): the W with W z = W^-1 s, W = eta Wbar, Wbar^2 = 2 v v^T - J, so
W^-1 = (1/eta) J Wbar J and W^-2 = (1/eta^2) (2 (Jv)(Jv)^T - J).

Every function takes and returns plain floats and tuples of them (a 3-vector as
:data:`.jit.Vector3`, the symmetric W as :data:`Scaling`), never rows of arrays: a row view
made in a stage's per-contact loop costs an atomic reference count each way, which
numba cannot always remove (tuned: docs/performance.md#exact-stage).
"""

from __future__ import annotations

from typing import TypeAlias

import numpy as np

from .jit import Vector3, jit

#: The symmetric 3 x 3 scaling W by its entries (w00, w01, w02, w11, w12, w22).
Scaling: TypeAlias = tuple[float, float, float, float, float, float]

#: Fraction of the step to the cone boundary taken (the usual 0.99 of interior-point
#: methods: close enough to converge fast, far enough to keep the scaling well-defined).
STEP_FRACTION = 0.99

#: A step shorter than this means the iteration has stalled: hand the grasp over.
MIN_STEP = 1e-10

#: What :func:`max_step` and :func:`positive_step` return for a direction that never
#: leaves the cone.
NO_LIMIT = 1e30


@jit
def nt_scaling(z: Vector3, s: Vector3) -> tuple[float, Scaling, Vector3]:
    """Nesterov-Todd scaling of one 3-cone pair, for z, s interior.

    Parameters
    ----------
    z, s : Vector3

    Returns
    -------
    inv_eta2 : float
        1/eta^2, or NaN if z or s has left the cone interior (the rest is then 0).
    scaling : Scaling
        W = eta Wbar.
    inverse_vector : Vector3
        J v.
    """
    inv_eta2, unit, inverse_vector = nt_unit_scaling(z, s)
    if not np.isfinite(inv_eta2):
        return inv_eta2, unit, inverse_vector
    eta = 1.0 / np.sqrt(inv_eta2)
    return inv_eta2, (eta * unit[0], eta * unit[1], eta * unit[2], eta * unit[3],
                      eta * unit[4], eta * unit[5]), inverse_vector


@jit
def nt_unit_scaling(z: Vector3, s: Vector3) -> tuple[float, Scaling, Vector3]:
    """:func:`nt_scaling` without its factor eta: Wbar (det Wbar = 1) and 1/eta^2.

    A method that needs only 1/eta^2 (scaled points lam/eta = Wbar z, steps W^-1 ds / eta
    = J Wbar J ds / eta^2, and Jordan divisions by lam/eta) saves the fourth root eta.

    Parameters
    ----------
    z, s : Vector3

    Returns
    -------
    inv_eta2 : float
        1/eta^2, or NaN if z or s has left the cone interior (the rest is then 0).
    scaling : Scaling
        Wbar.
    inverse_vector : Vector3
        J v.
    """
    z0, z1, z2 = z
    s0, s1, s2 = s
    z_det = z0 * z0 - z1 * z1 - z2 * z2
    s_det = s0 * s0 - s1 * s1 - s2 * s2
    if not (z_det > 0.0 and s_det > 0.0 and z0 > 0.0 and s0 > 0.0):
        return np.nan, (0.0, 0.0, 0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    # Two reciprocals instead of fifteen divisions, each shared by two quotients (the
    # divider bounds this function; tuned: docs/performance.md#exact-stage); rounding of
    # the scaling only, which no certificate uses.
    z_root, s_root = np.sqrt(z_det), np.sqrt(s_det)
    root_inv = 1.0 / (z_root * s_root)
    z_inv, s_inv = s_root * root_inv, z_root * root_inv
    gamma = np.sqrt(0.5 * (1.0 + (z0 * s0 + z1 * s1 + z2 * s2) * root_inv))
    # 2 gamma v0 = s0/|s| + z0/|z|, and 1 + v0 = (2 gamma + that) / (2 gamma): one
    # reciprocal gives both 1/(2 gamma) and 1/(1 + v0).
    twice_v0 = s0 * s_inv + z0 * z_inv
    both_inv = 1.0 / (gamma * (2.0 * gamma + twice_v0))
    half_inv_gamma = 0.5 * (2.0 * gamma + twice_v0) * both_inv
    v0 = twice_v0 * half_inv_gamma
    v1 = (s1 * s_inv - z1 * z_inv) * half_inv_gamma
    v2 = (s2 * s_inv - z2 * z_inv) * half_inv_gamma
    off = 2.0 * gamma * gamma * both_inv                   # 1 / (1 + v0)
    scaling = (v0, v1, v2, 1.0 + off * v1 * v1, off * v1 * v2, 1.0 + off * v2 * v2)
    return z_root * s_inv, scaling, (v0, -v1, -v2)


@jit
def scaling_of(scalings: np.ndarray, i: int) -> Scaling:
    """Row ``i`` of an (n, 6) array of scalings, as :func:`nt_scaling` gives them.

    Parameters
    ----------
    scalings : ndarray, shape (n, 6)
    i : int

    Returns
    -------
    Scaling
    """
    return (scalings[i, 0], scalings[i, 1], scalings[i, 2], scalings[i, 3], scalings[i, 4],
            scalings[i, 5])


@jit
def scaled_apply(scaling: Scaling, x: Vector3) -> Vector3:
    """W x.

    Parameters
    ----------
    scaling : Scaling
    x : Vector3

    Returns
    -------
    Vector3
    """
    w00, w01, w02, w11, w12, w22 = scaling
    x0, x1, x2 = x
    return (w00 * x0 + w01 * x1 + w02 * x2, w01 * x0 + w11 * x1 + w12 * x2,
            w02 * x0 + w12 * x1 + w22 * x2)


@jit
def scaled_inverse_apply(scaling: Scaling, inv_eta2: float, x: Vector3) -> Vector3:
    """W^-1 x = J W J x / eta^2.

    Parameters
    ----------
    scaling : Scaling
        W = eta Wbar (from :func:`nt_scaling`).
    inv_eta2 : float
        Its 1/eta^2.
    x : Vector3

    Returns
    -------
    Vector3
    """
    w00, w01, w02, w11, w12, w22 = scaling
    jx0, jx1, jx2 = x[0], -x[1], -x[2]
    return (inv_eta2 * (w00 * jx0 + w01 * jx1 + w02 * jx2),
            -inv_eta2 * (w01 * jx0 + w11 * jx1 + w12 * jx2),
            -inv_eta2 * (w02 * jx0 + w12 * jx1 + w22 * jx2))


@jit
def inverse_apply(scaling: Scaling, x: Vector3) -> Vector3:
    """W^-1 x from W = eta Wbar alone (1/eta^2 = 1 / det W).

    Parameters
    ----------
    scaling : Scaling
    x : Vector3

    Returns
    -------
    Vector3
    """
    inv_eta2 = 1.0 / (scaling[0] ** 2 - scaling[1] ** 2 - scaling[2] ** 2)
    return scaled_inverse_apply(scaling, inv_eta2, x)


@jit
def inverse_square_apply(inverse_vector: Vector3, inv_eta2: float, x: Vector3) -> Vector3:
    """W^-2 x = (2 Jv (Jv . x) - J x) / eta^2.

    Parameters
    ----------
    inverse_vector : Vector3
        J v (from :func:`nt_scaling`).
    inv_eta2 : float
    x : Vector3

    Returns
    -------
    Vector3
    """
    v0, v1, v2 = inverse_vector
    x0, x1, x2 = x
    proj = v0 * x0 + v1 * x1 + v2 * x2
    return (inv_eta2 * (2.0 * v0 * proj - x0), inv_eta2 * (2.0 * v1 * proj + x1),
            inv_eta2 * (2.0 * v2 * proj + x2))


@jit
def jordan_product(x: Vector3, y: Vector3) -> Vector3:
    """x o y.

    Parameters
    ----------
    x, y : Vector3

    Returns
    -------
    Vector3
    """
    return (x[0] * y[0] + x[1] * y[1] + x[2] * y[2], x[0] * y[1] + y[0] * x[1],
            x[0] * y[2] + y[0] * x[2])


@jit
def jordan_divide(lam: Vector3, r: Vector3) -> Vector3:
    """The x with lam o x = r, for lam interior.

    Parameters
    ----------
    lam, r : Vector3

    Returns
    -------
    Vector3
    """
    det = lam[0] * lam[0] - lam[1] * lam[1] - lam[2] * lam[2]
    # One reciprocal for 1/det and 1/lam0 (tuned: docs/performance.md#exact-stage).
    both_inv = 1.0 / (det * lam[0])
    out0 = (lam[0] * r[0] - lam[1] * r[1] - lam[2] * r[2]) * (lam[0] * both_inv)
    inv_lam0 = det * both_inv
    return out0, (r[1] - out0 * lam[1]) * inv_lam0, (r[2] - out0 * lam[2]) * inv_lam0


@jit
def max_step(x: Vector3, dx: Vector3) -> float:
    """Largest alpha with x + alpha dx in Q^3, for x interior.

    Parameters
    ----------
    x, dx : Vector3

    Returns
    -------
    float
        The step to the boundary, NO_LIMIT where dx never leaves the cone.
    """
    a = dx[0] * dx[0] - dx[1] * dx[1] - dx[2] * dx[2]
    b = 2.0 * (x[0] * dx[0] - x[1] * dx[1] - x[2] * dx[2])
    c = x[0] * x[0] - x[1] * x[1] - x[2] * x[2]
    # The smallest positive root of a alpha^2 + b alpha + c (c > 0), one division:
    # 2c / (sqrt(D) - b) for b < 0 (both terms positive, no cancellation); for b >= 0 a
    # positive root needs a < 0, and is (-b - sqrt(D)) / (2a), again without cancellation.
    if b < 0.0:
        disc = b * b - 4.0 * a * c
        if disc < 0.0:
            return NO_LIMIT      # a > 0 and no real root: dx points into the cone
        return 2.0 * c / (np.sqrt(disc) - b)
    if a < 0.0:
        return (-b - np.sqrt(b * b - 4.0 * a * c)) / (2.0 * a)
    return NO_LIMIT          # both roots negative (or none): dx lies in the cone


@jit
def step_within(x: Vector3, dx: Vector3, limit: float) -> float:
    """min(limit, :func:`max_step` (x, dx)), for x interior and limit > 0, with its square
    root and division only where x + limit dx is not inside the cone.

    The steps from x inside Q^3 form an interval [0, max_step] (the cone is convex), so
    where x + limit dx is inside, the step to the boundary is at least limit. A minimum
    over contacts passes its running value as ``limit``: only the contacts that lower it
    pay for a root (tuned: docs/performance.md#exact-stage). Rounding may return limit
    for a boundary a few ulps short of it, which a step fraction of the result absorbs.

    Parameters
    ----------
    x, dx : Vector3
    limit : float

    Returns
    -------
    float
    """
    y0 = x[0] + limit * dx[0]
    y1 = x[1] + limit * dx[1]
    y2 = x[2] + limit * dx[2]
    if y0 > 0.0 and y0 * y0 - y1 * y1 - y2 * y2 > 0.0:
        return limit
    return min(limit, max_step(x, dx))


@jit
def positive_step(x: float, dx: float) -> float:
    """Largest alpha with x + alpha dx >= 0, for x > 0 (the cone R_+).

    Parameters
    ----------
    x, dx : float

    Returns
    -------
    float
        NO_LIMIT where dx >= 0.
    """
    return -x / dx if dx < 0.0 else NO_LIMIT
