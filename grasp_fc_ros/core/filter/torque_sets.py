"""The torque set of one friction cone (paper section IV-A).

For a contact at p with unit inward normal n and friction half-angle
theta = atan(mu), and an origin o with lever arm r = p - o, the torque set is
T = { r x f : f in the friction cone }. It lies in the plane perpendicular to r and is

* ``NULL``  -- {0}, when r = 0 (the contact sits at the origin);
* ``PLANE`` -- the whole plane perpendicular to r, when the line through r meets the
  interior of the cone (r *or* -r strictly inside it);
* ``FAN``   -- the conic hull of two boundary torques otherwise.

Closed form of the fan (equivalent to the paper's tangent-plane construction, and
valid for either sign of r . n): with r_hat = r / |r| and s = |r_hat x n|, the sine of
the angle between r and n, the fan exists when s >= sin(theta). Its centre direction is
c = (r_hat x n) / s, its half-angle beta = arcsin(sin(theta) / s), and its boundary
torques are cos(beta) c +/- sin(beta) (r_hat x c).

Derivation in short: r x f = |r| r_hat x f_perp, where f_perp is the projection of f
on the plane perpendicular to r. The cone projects onto that plane as a 2-D cone of
half-angle beta around the projection of n (a whole plane if r or -r is inside the
cone), and ``r_hat x`` rotates it by 90 degrees within the plane.

Soundness: every fan is widened by ``FAN_WIDEN_RAD``, and a fan within
``HALF_PLANE_MARGIN_RAD`` of a half-plane (where its two boundary torques become
opposite and stop describing it) becomes its plane. Both only enlarge the sets, which
can only make the filter pass more grasps.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from ..tolerances import FAN_WIDEN_RAD, HALF_PLANE_MARGIN_RAD


class TorqueSetKind(IntEnum):
    """Shape of the torque set of one friction cone."""

    NULL = 0
    FAN = 1
    PLANE = 2


@dataclass(frozen=True)
class TorqueSets:
    """Torque sets of many friction cones, each a null set, a fan or a plane.

    Vectors are stored component-first, shape (3, ...), so that the batch axis is the
    contiguous one and every operation is a long vector operation.

    Attributes
    ----------
    kind : ndarray of int8, shape (...)
        A :class:`TorqueSetKind` per cone.
    first, second : ndarray, shape (3, ...)
        Unit boundary torques of a fan. Zero for null sets and planes.
    axis : ndarray, shape (3, ...)
        Unit lever-arm direction r_hat: the normal of the plane holding the set.
        Zero for null sets.
    """

    kind: np.ndarray
    first: np.ndarray
    second: np.ndarray
    axis: np.ndarray

    def subset(self, index: tuple[slice | np.ndarray, ...]) -> TorqueSets:
        """The sets at ``index`` of the batch dimensions (shape (...))."""
        return TorqueSets(self.kind[index], self.first[(slice(None),) + index],
                          self.second[(slice(None),) + index],
                          self.axis[(slice(None),) + index])


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product of component-first vectors, shapes (3, ...) (broadcast)."""
    out = np.empty((3,) + np.broadcast_shapes(a.shape[1:], b.shape[1:]))
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        np.multiply(a[j], b[k], out=out[i])
        out[i] -= a[k] * b[j]
    return out


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dot product of component-first vectors, shapes (3, ...) -> (...)."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def friction_half_angle_sine(mu: np.ndarray) -> np.ndarray:
    """sin(atan(mu)), the sine of the friction cone's half-angle. Shape of ``mu``."""
    return mu / np.sqrt(1.0 + mu * mu)


def cone_torque_sets(lever_arms: np.ndarray, normals: np.ndarray,
                     sin_half_angle: np.ndarray) -> TorqueSets:
    """Torque sets of friction cones about an origin.

    Parameters
    ----------
    lever_arms : ndarray, shape (3, ...)
        r = p - o, contact position minus origin (any length unit), component-first.
    normals : ndarray, shape (3, ...)
        Unit inward normals, component-first.
    sin_half_angle : ndarray, shape (...)
        sin(atan(mu)) of each cone.

    Returns
    -------
    TorqueSets
        One set per cone, each widened slightly so that it contains the exact set.
    """
    # Scale first so that squaring cannot overflow or underflow at extreme scales.
    scale = np.maximum(np.maximum(np.abs(lever_arms[0]), np.abs(lever_arms[1])),
                       np.abs(lever_arms[2]))
    is_null = scale == 0.0
    r = lever_arms / np.where(is_null, 1.0, scale)
    r_hat = r / np.where(is_null, 1.0, np.sqrt(dot(r, r)))

    centre_unnormalised = cross(r_hat, normals)
    s = np.sqrt(dot(centre_unnormalised, centre_unnormalised))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = sin_half_angle / s
    half_angle = np.arcsin(np.minimum(ratio, 1.0)) + FAN_WIDEN_RAD
    is_plane = ~is_null & ~(half_angle < np.pi / 2 - HALF_PLANE_MARGIN_RAD)
    is_fan = ~is_null & ~is_plane

    centre = centre_unnormalised / np.where(is_fan, s, 1.0)
    across = cross(r_hat, centre)
    cos_b = np.where(is_fan, np.cos(half_angle), 0.0)
    sin_b = np.where(is_fan, np.sin(half_angle), 0.0)
    first = cos_b * centre + sin_b * across
    second = cos_b * centre - sin_b * across

    kind = np.full(is_null.shape, TorqueSetKind.NULL, dtype=np.int8)
    kind[is_fan] = TorqueSetKind.FAN
    kind[is_plane] = TorqueSetKind.PLANE
    return TorqueSets(kind, first, second, np.where(is_null, 0.0, r_hat))


def normal_lines(normals: np.ndarray, soft: np.ndarray) -> TorqueSets:
    """The torque sets of soft contacts' torsional moments: the lines along their normals.

    A soft contact's torque set about any origin lies in its fan (or plane, or {0} at
    the origin) plus the line {tau n}; for the positive span only generators matter, so
    each line enters as a "fan" with boundary torques n and -n, and a hard contact as a
    null set. Shapes as :func:`cone_torque_sets`.

    Parameters
    ----------
    normals : ndarray, shape (3, ...)
        Unit inward normals, component-first.
    soft : ndarray of bool, shape (...)
        Which contacts are soft (gamma > 0).
    """
    first = np.where(soft, normals, 0.0)
    kind = np.where(soft, TorqueSetKind.FAN, TorqueSetKind.NULL).astype(np.int8)
    return TorqueSets(kind, first, -first, np.zeros_like(first))


def concatenate(parts: list[TorqueSets]) -> TorqueSets:
    """Torque sets of several families of one batch, joined along the first set axis."""
    return TorqueSets(np.concatenate([part.kind for part in parts]),
                      np.concatenate([part.first for part in parts], axis=1),
                      np.concatenate([part.second for part in parts], axis=1),
                      np.concatenate([part.axis for part in parts], axis=1))
