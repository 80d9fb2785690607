"""Certificates behind the exact verdicts, checked in numpy.

Force closure is certified by an internal force: contact forces in exact equilibrium,
strictly inside every friction cone. Not force closure is certified by a wrench w that
bounds the margin from above:

    a_i = w[:3] + w[3:] x p_i,   l_i = n_i . a_i + mu_i |a_i - (n_i . a_i) n_i|,
    L >= max_i l_i,              S = sum_i (L - n_i . a_i) / mu_i,
    t* <= max(L, 0) / S.

(A force f_i with normal part c_i and |f_t,i| <= mu_i c_i - t does work
f_i . a_i <= c_i n_i.a_i + (mu_i c_i - t)(L - n_i.a_i)/mu_i = c_i L - t (L - n_i.a_i)/mu_i;
an equilibrium does no work on any wrench, so with sum_i c_i = 1: 0 <= L - t S.)
L <= 0 makes w a *separating wrench*: no contact force can do positive work against it,
so no equilibrium force is strictly inside the cones.

Internally both are computed on the grasp centred at its centroid and scaled to unit
size (``unit`` positions); :func:`verify_certificates` checks them again in the caller's
frame, about the caller's origin. A user can check a wrench by hand in five lines
(n unit normals, p positions, w = result.separating_wrench):

    a = w[:3] + np.cross(w[3:], p)                     # work vector at each contact
    a_n = np.sum(a * n, axis=1)
    a_t = np.linalg.norm(a - a_n[:, None] * n, axis=1)
    largest = np.linalg.norm(a, axis=1).max()
    assert np.all(a_n + mu * a_t <= 1e-6 * largest)    # no force does positive work

Rounding is accounted for explicitly: a projected force is only an *approximately*
equilibrated force, so its depth is lowered by how far the exact equilibrium force can be
(the projection residual over the smallest singular value of G, plus the rounding of
that residual), and the total normal force must stay positive after that correction.
Contacts that share one normal (whose equilibrium forces all have zero total normal
force) can therefore never pass on rounding noise.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from ..model.contact_model import HARD, ContactModel, cone_depth, depth_reach_factor, largest_work
from ..tolerances import CERTIFICATE_TOL, EQUILIBRIUM_TOL, ROUNDING_SLACK

_EPS = np.finfo(np.float64).eps


def normalise_positions(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centre each grasp at its centroid and scale it to unit size.

    Parameters
    ----------
    positions : ndarray, shape (N, n, 3)

    Returns
    -------
    unit : ndarray, shape (N, n, 3)
        ``(positions - centre) / size``, every coordinate in [-1, 1].
    centre : ndarray, shape (N, 3)
    size : ndarray, shape (N,)
        Largest absolute centred coordinate (1 where all contacts coincide).
    """
    # Divide by the largest coordinate first: the centroid of coordinates near the
    # float range (~1e308) would otherwise overflow in the sum.
    peak = np.abs(positions).max(axis=(1, 2))
    peak = np.where(peak > 0, peak, 1.0)[:, None, None]
    scaled = positions / peak
    centre = scaled.mean(axis=1, keepdims=True)
    centred = scaled - centre
    size = np.abs(centred).max(axis=(1, 2), keepdims=True)
    size = np.where(size > 0, size, 1.0)
    with np.errstate(over="ignore"):
        return centred / size, (centre * peak)[:, 0], (size * peak)[:, 0, 0]


def grasp_maps(unit: np.ndarray) -> np.ndarray:
    """Grasp maps G (N, 6, 3n) of unit-size grasps: rows (force, torque), columns the
    global force components of each contact."""
    n_grasps, n_contacts = unit.shape[:2]
    grasp_map = np.zeros((n_grasps, 6, n_contacts, 3))
    grasp_map[:, 0, :, 0] = grasp_map[:, 1, :, 1] = grasp_map[:, 2, :, 2] = 1.0
    x, y, z = unit[..., 0], unit[..., 1], unit[..., 2]
    # Torque rows: p x f = (y f_z - z f_y, z f_x - x f_z, x f_y - y f_x).
    grasp_map[:, 3, :, 1], grasp_map[:, 3, :, 2] = -z, y
    grasp_map[:, 4, :, 0], grasp_map[:, 4, :, 2] = z, -x
    grasp_map[:, 5, :, 0], grasp_map[:, 5, :, 1] = -y, x
    return grasp_map.reshape(n_grasps, 6, 3 * n_contacts)


def certified_internal_force(forces: np.ndarray, grasp_map: np.ndarray,
                             row_space: np.ndarray, sigma_min: np.ndarray,
                             normals: np.ndarray, mu: np.ndarray, model: ContactModel = HARD,
                             weight: np.ndarray | None = None
                             ) -> tuple[np.ndarray, np.ndarray]:
    """Project candidate forces onto equilibrium and certify how deep they are.

    Parameters
    ----------
    forces : ndarray, shape (N, n, d)
        Candidate generalised contact forces (any scale), global components: f (d = 3)
        or (f, rho) (d = 4, soft, see :mod:`.contact_model`).
    grasp_map : ndarray, shape (N, 6, d n)
        (Generalised) grasp maps of the unit-size grasps.
    row_space : ndarray, shape (N, 6, d n)
        Orthonormal bases of their row spaces.
    sigma_min : ndarray, shape (N,)
        Smallest singular values of the grasp maps (> 0).
    normals : ndarray, shape (N, n, 3)
        Unit inward normals.
    mu : ndarray, shape (N, n)
    model : ContactModel
        The batch's contact model (d = model.components).
    weight : ndarray, shape (N, n), optional
        Soft: the cone weight w of rho (:func:`.contact_model.torsion_scales`).

    Returns
    -------
    depth : ndarray, shape (N,)
        A lower bound, valid despite rounding, on min_i (mu_i f_n,i - |f_t,i|) / sum_i f_n,i
        (soft: mu_i f_n,i - |(f_t,i, mu_i w_i rho_i)|) of an exactly equilibrated force
        within reach of the projection; -inf where the total normal force is not
        certainly positive.
    equilibrium : ndarray, shape (N, n, d)
        The projected forces scaled so that their normal components sum to one (NaN
        where the total is not certainly positive).
    """
    flat = forces.reshape(forces.shape[0], -1)
    projected = flat - np.einsum("gkv,gk->gv", row_space,
                                 np.einsum("gkv,gv->gk", row_space, flat))
    residual = np.linalg.norm(np.einsum("gkv,gv->gk", grasp_map, projected), axis=1)
    size = np.linalg.norm(projected, axis=1)
    # An exact equilibrium force lies within `reach` of the projected one: the residual
    # over sigma_min, plus what rounding of the residual itself could hide.
    rounding = ROUNDING_SLACK * _EPS * flat.shape[1] * np.linalg.norm(grasp_map, axis=(1, 2))
    reach = (residual + rounding * size) / sigma_min
    per_contact = projected.reshape(forces.shape)
    depth, normal_part = cone_depth(per_contact, normals, mu, weight)
    depth = depth - depth_reach_factor(mu, model) * reach[:, None]
    total = normal_part.sum(axis=1)
    slack = np.sqrt(normal_part.shape[1]) * reach
    positive = total - slack > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        certified = np.where(positive, depth.min(axis=1) / (total + slack), -np.inf)
        scaled = per_contact / total[:, None, None]
    scaled[~positive] = np.nan
    return certified, scaled


def wrench_bound(wrench: np.ndarray, unit: np.ndarray, normals: np.ndarray,
                 mu: np.ndarray, torsional_unit: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Upper bounds on the margin t* from trial wrenches, valid despite rounding.

    Parameters
    ----------
    wrench : ndarray, shape (N, 6)
        Trial wrenches (force, torque) about the centroid of the unit-size grasps.
    unit, normals : ndarray, shape (N, n, 3)
    mu : ndarray, shape (N, n)
    torsional_unit : ndarray, shape (N, n), optional
        gamma in the unit grasp's length (soft batches): l_i gets the torsional term
        of :func:`.contact_model.largest_work`, and the same bound t* <= max(L, 0) / S
        holds (a soft contact's work is at most c_i L - t (L - n_i . a_i) / mu_i too).

    Returns
    -------
    bound : ndarray, shape (N,)
        t* <= bound (the trivial bound 1 / sum_i (1/mu_i) where the wrench proves
        nothing better).
    separating : ndarray of bool, shape (N,)
        The wrench certainly separates: L <= 0 with rounding.
    """
    force, torque = wrench[:, None, :3], wrench[:, None, 3:]
    work = force + np.cross(torque, unit)                               # a_i, (N, n, 3)
    normal_work = (work * normals).sum(axis=-1)
    error = ROUNDING_SLACK * _EPS * (np.linalg.norm(force, axis=-1)
                                     + 2.0 * np.linalg.norm(torque, axis=-1))   # (N, 1)
    if torsional_unit is None:
        tangential = np.linalg.norm(work - normal_work[..., None] * normals, axis=-1)
        level = ((normal_work + mu * tangential).max(axis=1)
                 + (1.0 + mu.max(axis=1)) * error[:, 0])
    else:
        twist_error = ROUNDING_SLACK * _EPS * torsional_unit * np.linalg.norm(torque, axis=-1)
        level = ((largest_work(work, normals, mu, wrench[:, 3:], torsional_unit)
                  + twist_error).max(axis=1) + (1.0 + mu.max(axis=1)) * error[:, 0])
    spread = ((level[:, None] - normal_work - error) / mu).sum(axis=1) * (1.0 - 1e-12)
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = np.where(spread > 0, np.maximum(level, 0.0) / spread, np.inf)
    # mu_i c_n,i >= t at every contact and sum_i c_n,i = 1 give t* <= 1 / sum_i (1/mu_i).
    bound = np.minimum(bound, (1.0 + 1e-12) / (1.0 / mu).sum(axis=1))
    return bound, (level <= 0) & np.all(np.isfinite(wrench), axis=1)


def to_caller_wrench(wrench: np.ndarray, centre: np.ndarray, size: np.ndarray) -> np.ndarray:
    """Map wrenches about the centroid of unit-size grasps to the caller's frame and
    origin, scaled to unit length.

    With u = (p - centre) / size, F + T x u = (F - T/size x centre) + (T/size) x p: the
    same work vector a_i at every contact.

    Parameters
    ----------
    wrench : ndarray, shape (N, 6)
    centre : ndarray, shape (N, 3)
    size : ndarray, shape (N,)

    Returns
    -------
    ndarray, shape (N, 6)
    """
    torque = wrench[:, 3:] / size[:, None]
    force = wrench[:, :3] - np.cross(torque, centre)
    caller = np.concatenate([force, torque], axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return caller / np.linalg.norm(caller, axis=1, keepdims=True)


def verify_certificates(positions: npt.ArrayLike, normals: npt.ArrayLike, mu: npt.ArrayLike,
                        contact_forces: npt.ArrayLike | None = None,
                        separating_wrench: npt.ArrayLike | None = None,
                        torsional_friction: npt.ArrayLike | None = None,
                        contact_torques: npt.ArrayLike | None = None
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Check certificates in the caller's frame, independently of how they were found.

    Parameters
    ----------
    positions, normals : array_like, shape (n, 3) or (N, n, 3)
        As given to :func:`check_force_closure` (normals of any non-zero length).
    mu : float or array_like broadcastable to (N, n)
    contact_forces : array_like, shape like ``positions``, optional
        Claimed internal forces (NaN rows: no claim).
    separating_wrench : array_like, shape (6,) or (N, 6), optional
        Claimed separating wrenches (force, torque about the origin; NaN: no claim).
    torsional_friction : float or array_like broadcastable to (N, n), optional
        gamma of soft contacts (positions' unit); None or 0: hard contacts.
    contact_torques : array_like, shape (n,) or (N, n), optional
        Claimed torsional moments tau_i about each normal (force x length), with
        ``contact_forces``; None: all zero.

    Returns
    -------
    forces_ok, wrench_ok : numpy bool for one grasp, ndarray of bool, shape (N,)
        ``forces_ok``: normal components sum to one (within EQUILIBRIUM_TOL), net force
        and net torque (sum p_i x f_i + tau_i n_i) about the origin vanish (relative to
        EQUILIBRIUM_TOL), every contact strictly inside its cone (mu f_n > |f_t| hard;
        mu f_n > |(f_t, mu tau / gamma)| soft; tau = 0 where gamma = 0).
        ``wrench_ok``: unit length, and for every contact n_i . a_i + mu_i |a_t,i|
        <= CERTIFICATE_TOL max_j |a_j| (soft: n_i . a_i + |(mu_i |a_t,i|, gamma_i
        n_i . w_torque)| <= CERTIFICATE_TOL max_j |(a_j, gamma_j |w_torque|)|). False
        where there is no claim (NaN) or it fails.
    """
    p = np.asarray(positions, dtype=np.float64)
    forces_ok, wrench_ok = verify_batch(p.reshape((-1,) + p.shape[-2:]), normals, mu,
                                        contact_forces, separating_wrench,
                                        torsional_friction, contact_torques)
    if p.ndim == 2:
        return forces_ok[0], wrench_ok[0]
    return forces_ok, wrench_ok


def verify_batch(p: np.ndarray, normals: npt.ArrayLike, mu: npt.ArrayLike,
                 contact_forces: npt.ArrayLike | None = None,
                 separating_wrench: npt.ArrayLike | None = None,
                 torsional_friction: npt.ArrayLike | None = None,
                 contact_torques: npt.ArrayLike | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`verify_certificates` on a batch: positions ``p`` (N, n, 3), the other
    arguments as there (reshaped to the batch); both results of shape (N,)."""
    n = np.asarray(normals, dtype=np.float64).reshape(p.shape)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    friction = np.broadcast_to(np.asarray(mu, dtype=np.float64), p.shape[:2])
    gamma = None
    if torsional_friction is not None:
        gamma = np.broadcast_to(np.asarray(torsional_friction, dtype=np.float64),
                                p.shape[:2])
    forces_ok = np.zeros(p.shape[0], dtype=bool)
    wrench_ok = np.zeros(p.shape[0], dtype=bool)
    if contact_forces is not None:
        f = np.asarray(contact_forces, dtype=np.float64).reshape(p.shape)
        tau = (np.zeros(p.shape[:2]) if contact_torques is None
               else np.asarray(contact_torques, dtype=np.float64).reshape(p.shape[:2]))
        f_n = (f * n).sum(axis=-1)
        f_t = np.linalg.norm(f - f_n[..., None] * n, axis=-1)
        scale = np.linalg.norm(f, axis=-1).sum(axis=1)
        lever = np.abs(p).max(axis=(1, 2))
        with np.errstate(invalid="ignore", divide="ignore"):
            if gamma is None:
                inside = (friction * f_n - f_t > 0) & (tau == 0)
            else:
                twist = np.where(gamma > 0, friction * tau / gamma, np.where(tau == 0, 0, np.inf))
                inside = friction * f_n - np.hypot(f_t, twist) > 0
            net_torque = (np.cross(p, f) + tau[..., None] * n).sum(axis=1)
            forces_ok = (np.all(inside, axis=1)
                         & (np.abs(f_n.sum(axis=1) - 1.0) <= EQUILIBRIUM_TOL)
                         & (np.linalg.norm(f.sum(axis=1), axis=1) <= EQUILIBRIUM_TOL * scale)
                         & (np.linalg.norm(net_torque, axis=1)
                            <= EQUILIBRIUM_TOL * (scale * lever + np.abs(tau).sum(axis=1))))
    if separating_wrench is not None:
        w = np.asarray(separating_wrench, dtype=np.float64).reshape(-1, 6)
        work = w[:, None, :3] + np.cross(w[:, None, 3:], p)
        size = np.linalg.norm(work, axis=-1)
        if gamma is not None:
            size = np.hypot(size, gamma * np.linalg.norm(w[:, None, 3:], axis=-1))
        largest = size.max(axis=1)
        with np.errstate(invalid="ignore"):
            most = (largest_work(work, n, friction) if gamma is None
                    else largest_work(work, n, friction, w[:, 3:], gamma))
            wrench_ok = (np.all(most <= CERTIFICATE_TOL * largest[:, None], axis=1)
                         & (np.abs(np.linalg.norm(w, axis=1) - 1.0) <= EQUILIBRIUM_TOL))
    return forces_ok, wrench_ok
