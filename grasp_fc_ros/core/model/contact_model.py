"""Contact models: what one contact can transmit, in one place.

Two models, chosen per batch:

* ``HARD`` -- a hard point contact with Coulomb friction: a force f in the quadratic
  cone mu f_n >= |f_t|; wrench (f, p x f); 3 generalised force components per contact.
* ``SOFT`` -- a soft finger: a force f and a torsional moment tau about the normal in
  the elliptic cone f_n >= sqrt(|f_t|^2 / mu^2 + tau^2 / gamma^2); wrench
  (f, p x f + tau n). gamma >= 0 is the torsional friction coefficient, a length in the
  positions' unit (the largest |tau| per unit normal force).

The soft model is written with a fourth component rho scaled so that every contact of
a soft batch has the same four components x = (f_x, f_y, f_z, rho), the same 4-D
second-order cone and a bounded wrench column. With g = gamma in the unit-size grasp's
length, c = min(g, 1) and w = c / g = min(1, 1 / g):

    tau = c rho,  wrench column (0, c n),  cone (mu n . f, f_t, mu w rho) in Q^4,

which is f_n >= sqrt(|f_t|^2 / mu^2 + tau^2 / g^2). For g <= 1 rho is tau / g (w = 1);
a larger g keeps the column at unit size and makes the cone row small instead, so the
grasp map stays as well scaled as a hard one (a column of size g >> 1 would swamp its
singular values). A contact with gamma = 0 in a soft batch is exactly a hard contact
(its rho moves nothing), with no infinite coefficient.
A batch is ``HARD`` when no contact has gamma > 0; the hard path is then unchanged.

Everything that depends on the model reads it from here: the exact test's conic
program (:func:`cone_rows`, :func:`wrench_columns`), the certificates
(:func:`cone_depth`, :func:`largest_work`), the validation (:func:`torsional_checks`)
and the filter (a soft contact's torque set is its fan plus the line along its normal).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..tolerances import MAX_ABS_COORDINATE


@dataclass(frozen=True)
class ContactModel:
    """One contact model.

    Attributes
    ----------
    name : str
    components : int
        Generalised force components per contact (3 hard, 4 soft): also the size of
        its second-order cone.
    """

    name: str
    components: int


HARD = ContactModel("hard", 3)
SOFT = ContactModel("soft", 4)


def model_of(torsional: np.ndarray | None) -> ContactModel:
    """The model of a batch: ``SOFT`` if some contact has gamma > 0, else ``HARD``.

    Parameters
    ----------
    torsional : ndarray, shape (N, n), or None
        Torsional friction coefficients (None: all hard).
    """
    return HARD if torsional is None else SOFT


def torsional_or_none(torsional: np.ndarray) -> np.ndarray | None:
    """Validated gamma (N, n) as stored in a batch: None where every contact is hard, so
    that gamma = 0 everywhere runs the hard path bit for bit."""
    return np.ascontiguousarray(torsional) if (torsional > 0).any() else None


def torsional_checks(torsional: np.ndarray) -> tuple:
    """Per-contact checks of gamma (N, n) for the validation: (bad mask, what, values)
    triples.

    gamma must be finite, >= 0 and, being a length like the positions, at most
    ``MAX_ABS_COORDINATE``.
    """
    return (
        (~np.isfinite(torsional), "torsional friction is not finite", torsional),
        (~(torsional >= 0), "torsional friction must be >= 0 (0: a hard contact)", torsional),
        (torsional > MAX_ABS_COORDINATE,
         f"torsional friction exceeds {MAX_ABS_COORDINATE:.3g} (use a larger length unit)",
         torsional),
    )


def torsional_all_valid(torsional: np.ndarray) -> bool:
    """True iff :func:`torsional_checks` finds nothing (one whole-array reduction)."""
    with np.errstate(invalid="ignore"):
        return bool(((torsional >= 0) & (torsional <= MAX_ABS_COORDINATE)).all())


def torsion_scales(torsional_unit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The column scale c = min(g, 1) and cone weight w = min(1, 1 / g) of rho, (N, n)
    each, for gamma g in the unit grasp's length (see the module docstring)."""
    return np.minimum(torsional_unit, 1.0), 1.0 / np.maximum(torsional_unit, 1.0)


def cone_rows(normals: np.ndarray, tangent: np.ndarray, bitangent: np.ndarray,
              mu: np.ndarray, model: ContactModel,
              weight: np.ndarray | None = None) -> np.ndarray:
    """Each contact's cone coordinates as rows acting on its generalised force.

    Parameters
    ----------
    normals, tangent, bitangent : ndarray, shape (N, n, 3)
        Unit normal and two unit tangents per contact.
    mu : ndarray, shape (N, n)
    model : ContactModel
    weight : ndarray, shape (N, n), optional
        w of :func:`torsion_scales` (soft only; 1 if None).

    Returns
    -------
    ndarray, shape (N, n, d, d)
        Row 0 gives mu n . f, rows 1-2 the tangential force, and (soft) row 3 mu w rho:
        x is in the model's cone iff rows @ x is in Q^d.
    """
    hard = np.stack([mu[..., None] * normals, tangent, bitangent], axis=2)
    if model is HARD:
        return hard
    rows = np.zeros(mu.shape + (4, 4))
    rows[..., :3, :3] = hard
    rows[..., 3, 3] = mu if weight is None else mu * weight
    return rows


def wrench_columns(grasp_map: np.ndarray, normals: np.ndarray,
                   torsional_unit: np.ndarray | None) -> np.ndarray:
    """The generalised grasp map: hard grasp maps plus, when soft, the columns of rho.

    Parameters
    ----------
    grasp_map : ndarray, shape (N, 6, 3n)
        Hard grasp maps (force components of each contact).
    normals : ndarray, shape (N, n, 3)
    torsional_unit : ndarray, shape (N, n), or None
        gamma in the grasp map's length unit (None: hard).

    Returns
    -------
    ndarray, shape (N, 6, d n)
        Columns contact after contact, d per contact: (f, p x f), then (0, c n) with
        c of :func:`torsion_scales`.
    """
    if torsional_unit is None:
        return grasp_map
    n_grasps, n_contacts = normals.shape[:2]
    columns = np.zeros((n_grasps, 6, n_contacts, 4))
    columns[..., :3] = grasp_map.reshape(n_grasps, 6, n_contacts, 3)
    column_scale = torsion_scales(torsional_unit)[0]
    columns[:, 3:, :, 3] = (column_scale[..., None] * normals).transpose(0, 2, 1)
    return columns.reshape(n_grasps, 6, 4 * n_contacts)


def cone_depth(generalised: np.ndarray, normals: np.ndarray, mu: np.ndarray,
               weight: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """How deep generalised forces are in their cones, and their normal parts.

    Parameters
    ----------
    generalised : ndarray, shape (N, n, d)
        (f, rho) per contact (d = 4) or f alone (d = 3).
    normals : ndarray, shape (N, n, 3)
    mu : ndarray, shape (N, n)
    weight : ndarray, shape (N, n), optional
        w of :func:`torsion_scales` (soft; 1 if None).

    Returns
    -------
    depth : ndarray, shape (N, n)
        mu f_n - |(f_t, mu w rho)| (mu f_n - |f_t| when hard).
    normal_part : ndarray, shape (N, n)
    """
    force = generalised[..., :3]
    normal_part = (force * normals).sum(axis=-1)
    tangential = np.linalg.norm(force - normal_part[..., None] * normals, axis=-1)
    if generalised.shape[-1] == 4:
        twist = mu * generalised[..., 3]
        tangential = np.hypot(tangential, twist if weight is None else twist * weight)
    return mu * normal_part - tangential, normal_part


def depth_reach_factor(mu: np.ndarray, model: ContactModel) -> np.ndarray:
    """How much a contact's depth can fall per unit 2-norm change of its generalised
    force: mu + 1 (hard), mu + max(1, mu) (soft, for the mu w rho component, w <= 1)."""
    return mu + (1.0 if model is HARD else np.maximum(mu, 1.0))


def largest_work(a: np.ndarray, normals: np.ndarray, mu: np.ndarray,
                 torque: np.ndarray | None = None,
                 torsional: np.ndarray | None = None) -> np.ndarray:
    """The most work a contact wrench with unit normal force does on a wrench.

    Parameters
    ----------
    a : ndarray, shape (..., n, 3)
        a_i = w_force + w_torque x p_i: a force f at contact i does work a_i . f.
    normals : ndarray, shape (..., n, 3)
        Unit inward normals.
    mu : ndarray, shape (..., n)
    torque : ndarray, shape (..., 3), optional
        w_torque (soft contacts only): a moment tau n does work tau n . w_torque.
    torsional : ndarray, shape (..., n), optional
        gamma, in the unit of the positions ``a`` was computed with.

    Returns
    -------
    ndarray, shape (..., n)
        n_i . a_i + mu_i |a_t,i| (hard), or n_i . a_i + sqrt((mu_i |a_t,i|)^2 +
        (gamma_i n_i . w_torque)^2) (soft: the support function of the elliptic cone).
        At most 0 at every contact iff no contact wrench does positive work.
    """
    a_n = (a * normals).sum(axis=-1)
    tangential = mu * np.linalg.norm(a - a_n[..., None] * normals, axis=-1)
    if torsional is None:
        return a_n + tangential
    if torque is None:
        raise ValueError("largest_work: soft contacts (torsional) need the wrench's torque")
    twist = torsional * (normals * torque[..., None, :]).sum(axis=-1)
    return a_n + np.hypot(tangential, twist)
