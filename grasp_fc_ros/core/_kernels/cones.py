"""The second-order cone Q^3 = {x : x0 >= |(x1, x2)|} in interior-point steps (numba).

Jordan algebra of Q^3: x o y = (x . y, x0 y_t + y0 x_t), identity e = (1, 0, 0),
J = diag(1, -1, -1), det x = x0^2 - |x_t|^2. Nesterov-Todd scaling of an interior pair
(z, s): the W with W z = W^-1 s, W = eta Wbar, Wbar^2 = 2 v v^T - J, so
W^-1 = (1/eta) J Wbar J and W^-2 = (1/eta^2) (2 (Jv)(Jv)^T - J).
"""

from __future__ import annotations

import numpy as np

from .jit import jit

#: Fraction of the step to the cone boundary taken (the usual 0.99 of interior-point
#: methods: close enough to converge fast, far enough to keep the scaling well-defined).
STEP_FRACTION = 0.99

#: A step shorter than this means the iteration has stalled: hand the grasp over.
MIN_STEP = 1e-10

#: What :func:`max_step` and :func:`positive_step` return for a direction that never
#: leaves the cone.
NO_LIMIT = 1e30


@jit
def nt_scaling(z: np.ndarray, s: np.ndarray, scaling: np.ndarray,
               inverse_vector: np.ndarray) -> float:
    """Nesterov-Todd scaling of one 3-cone pair, for z, s interior.

    Parameters
    ----------
    z, s : ndarray, shape (3,)
    scaling : ndarray, shape (3, 3)
        Output: W = eta Wbar.
    inverse_vector : ndarray, shape (3,)
        Output: J v.

    Returns
    -------
    float
        1/eta^2, or NaN if z or s has left the cone interior.
    """
    z_det = z[0] * z[0] - z[1] * z[1] - z[2] * z[2]
    s_det = s[0] * s[0] - s[1] * s[1] - s[2] * s[2]
    if not (z_det > 0.0 and s_det > 0.0 and z[0] > 0.0 and s[0] > 0.0):
        return np.nan
    # Four reciprocals instead of fifteen divisions (the divider bounds this function;
    # tuned: docs/performance.md#exact-stage); rounding of the scaling only, which no
    # certificate uses.
    z_root, s_root = np.sqrt(z_det), np.sqrt(s_det)
    z_inv, s_inv = 1.0 / z_root, 1.0 / s_root
    gamma = np.sqrt(0.5 * (1.0 + (z[0] * s[0] + z[1] * s[1] + z[2] * s[2]) * (z_inv * s_inv)))
    half_inv_gamma = 0.5 / gamma
    v0 = (s[0] * s_inv + z[0] * z_inv) * half_inv_gamma
    v1 = (s[1] * s_inv - z[1] * z_inv) * half_inv_gamma
    v2 = (s[2] * s_inv - z[2] * z_inv) * half_inv_gamma
    eta = np.sqrt(s_root * z_inv)
    off = eta / (1.0 + v0)
    scaling[0, 0] = eta * v0
    scaling[0, 1] = scaling[1, 0] = eta * v1
    scaling[0, 2] = scaling[2, 0] = eta * v2
    scaling[1, 1] = eta + off * v1 * v1
    scaling[2, 2] = eta + off * v2 * v2
    scaling[1, 2] = scaling[2, 1] = off * v1 * v2
    inverse_vector[0], inverse_vector[1], inverse_vector[2] = v0, -v1, -v2
    return z_root * s_inv


@jit
def scaled_inverse_apply(scaling: np.ndarray, inv_eta2: float, x: np.ndarray,
                         out: np.ndarray) -> None:
    """out = W^-1 x = J W J x / eta^2.

    Parameters
    ----------
    scaling : ndarray, shape (3, 3)
        W = eta Wbar (from :func:`nt_scaling`).
    inv_eta2 : float
        Its 1/eta^2.
    x : ndarray, shape (3,)
    out : ndarray, shape (3,)
        Output; must not alias ``x``.
    """
    jx0, jx1, jx2 = x[0], -x[1], -x[2]
    for r in range(3):
        sign = 1.0 if r == 0 else -1.0
        out[r] = sign * inv_eta2 * (scaling[r, 0] * jx0 + scaling[r, 1] * jx1 + scaling[r, 2] * jx2)


@jit
def inverse_apply(scaling: np.ndarray, x: np.ndarray, out: np.ndarray) -> None:
    """out = W^-1 x from W = eta Wbar alone (1/eta^2 = 1 / det W).

    Parameters
    ----------
    scaling : ndarray, shape (3, 3)
    x : ndarray, shape (3,)
    out : ndarray, shape (3,)
        Output; must not alias ``x``.
    """
    inv_eta2 = 1.0 / (scaling[0, 0] ** 2 - scaling[0, 1] ** 2 - scaling[0, 2] ** 2)
    scaled_inverse_apply(scaling, inv_eta2, x, out)


@jit
def jordan_product_into(x: np.ndarray, y: np.ndarray, out: np.ndarray) -> None:
    """out = x o y.

    Parameters
    ----------
    x, y : ndarray, shape (3,)
    out : ndarray, shape (3,)
        Output; must not alias ``x`` or ``y``.
    """
    out0 = x[0] * y[0] + x[1] * y[1] + x[2] * y[2]
    out1 = x[0] * y[1] + y[0] * x[1]
    out2 = x[0] * y[2] + y[0] * x[2]
    out[0], out[1], out[2] = out0, out1, out2


@jit
def jordan_divide_into(lam: np.ndarray, r: np.ndarray, out: np.ndarray) -> None:
    """out with lam o out = r, for lam interior.

    Parameters
    ----------
    lam, r : ndarray, shape (3,)
    out : ndarray, shape (3,)
        Output; must not alias ``lam`` or ``r``.
    """
    det = lam[0] * lam[0] - lam[1] * lam[1] - lam[2] * lam[2]
    out[0] = (lam[0] * r[0] - lam[1] * r[1] - lam[2] * r[2]) / det
    out[1] = (r[1] - out[0] * lam[1]) / lam[0]
    out[2] = (r[2] - out[0] * lam[2]) / lam[0]


@jit
def max_step(x: np.ndarray, dx: np.ndarray) -> float:
    """Largest alpha with x + alpha dx in Q^3, for x interior.

    Parameters
    ----------
    x, dx : ndarray, shape (3,)

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
