"""Perturbed grasps that break force closure: the adversary behind BREAKS.

A wrench u = (a, b) separates a grasp when no contact force does positive work on it:
every work vector v_i = a + b x p_i lies in the polar cone of contact i,
{v : v . n_i + mu_i |v_t| <= 0}. The constructions below move the contacts so that a
chosen u separates the perturbed grasp.

* Tilts (exact): if u separates the grasp whose cones are shrunk to half-angle
  alpha_i - delta_i, tilting each normal by delta_i towards -v_i (in the plane of n_i
  and v_i; onto -v_i if it is nearer) puts its full cone of half-angle alpha_i in
  {f : v_i . f <= 0}: angle(n', -v_i) + alpha_i <= angle(n, -v_i) - delta_i + alpha_i
  <= 90 degrees. So the shrunk grasp's separating wrench gives a tilt witness.
* Turned axes (a search): a tilt past a cone's half-angle leaves the cone tiny (the
  shrunk grasp of :mod:`.holds` keeps a half-angle of WITNESS_MIN_HALF_ANGLE) and the
  rest of the tilt spare: the tiny cone may turn about any axis within it
  (:func:`turned_axes_wrench`), and the tilt by the whole error towards -v_i still
  works for a wrench that separates the turned grasp.
* Frictionless (exact where it applies): where every friction coefficient may drop to
  nothing and the normal wrenches (n_i, p_i x n_i) are independent (at most six
  contacts), some wrench gets negative work from every normal force, and friction small
  enough keeps it separating (:func:`frictionless_wrench`).
* Moves (a search): moving contact i by d_i turns v_i into v_i + b x d_i, any vector
  of length <= r |b| across b. :mod:`.break_distance` finds the torque direction b that
  needs the least moves and, for it, the moves of length <= r that put the work vectors
  deepest into their polar cones; the exact test judges the moved grasp.
"""

from __future__ import annotations

import numpy as np

from ..exact.certificates import normalise_positions, verify_batch
from ..model.grasp_input import GraspBatch
from ..pipeline import run_pipeline
from ..quality.epsilon import epsilon_quality
from .break_distance import deepest_breaking_direction, deepest_moves

_EPS = float(np.finfo(np.float64).eps)

#: Moves whose depth (sigma / r) is at least minus this are judged by the exact test:
#: some least breaking moves keep every work vector on its cone's boundary (depth 0,
#: which Clarabel returns as a few -1e-10), and the moved grasp may still be certified.
DEPTH_SLACK = 1e-6

#: Rounds of :func:`turned_axes_wrench`, and the accuracy of its epsilon searches (only
#: a direction is needed). One round found every witness on the benchmark's grasps
#: (docs/robustness.md#holds-under); the others catch what a first turn overshoots.
AXIS_ROUNDS = 3
AXIS_RTOL = 1e-2

#: The least-norm wrench of :func:`frictionless_wrench` counts only where every normal
#: wrench's work on it is within this of -1 (rows of a unit-size grasp: a solution,
#: not a least-squares compromise).
FRICTIONLESS_RESIDUAL = 1e-9



def tilt_towards(normals: np.ndarray, work: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Each unit normal (N, n, 3) turned by ``angles`` (N, n) towards -work (N, n, 3), in
    the plane of the two, and onto -work/|work| where that is nearer; unchanged where
    work = 0. A normal opposite to -work turns about an arbitrary axis."""
    target = -work / np.maximum(np.linalg.norm(work, axis=-1, keepdims=True), np.finfo(float).tiny)
    cosine = np.clip(np.sum(normals * target, axis=-1), -1.0, 1.0)
    between = np.arccos(cosine)
    across = target - cosine[..., None] * normals
    length = np.linalg.norm(across, axis=-1)
    # Opposite (or no work): any direction across the normal.
    helper = np.where(np.abs(normals[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    fallback = np.cross(normals, helper)
    fallback /= np.linalg.norm(fallback, axis=-1, keepdims=True)
    across = np.where((length > 1e-12)[..., None], across / np.maximum(length, 1e-300)[..., None],
                      fallback)
    turn = np.minimum(angles, between)
    turned = np.cos(turn)[..., None] * normals + np.sin(turn)[..., None] * across
    turned = np.where(((between <= angles) & (angles > 0.0))[..., None], target, turned)
    no_work = ~(np.linalg.norm(work, axis=-1) > 0.0)
    return np.where(no_work[..., None], normals, turned)


def work_vectors(positions: np.ndarray, wrench: np.ndarray) -> np.ndarray:
    """v_i = w_force + w_torque x p_i (N, n, 3) of wrenches (N, 6) at positions (N, n, 3)."""
    return wrench[:, None, :3] + np.cross(wrench[:, None, 3:], positions)


def breaking_moves(grasps: GraspBatch, radius: np.ndarray, start: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Search moves of at most ``radius`` (N,) that break force closure of force-closure
    grasps: the torque direction whose moves of length <= r put every work vector
    deepest into its polar cone (:mod:`.break_distance`), where that depth is positive,
    and those moves.

    Parameters
    ----------
    grasps : GraspBatch
        N hard grasps.
    radius : ndarray, shape (N,)
        r > 0, the positions' unit.
    start : ndarray, shape (N, 3), optional
        A torque direction to try first (e.g. the torque inradius search's).

    Returns
    -------
    found : ndarray of bool, shape (N,)
        The exact test says the moved grasp is not force closure, and a separating
        wrench (its own, or the search's) checks out on it.
    moves : ndarray, shape (N, n, 3)
        The moves (NaN where not found).
    wrench : ndarray, shape (N, 6)
        That separating wrench (NaN where not found).
    """
    depth, direction = deepest_breaking_direction(grasps, radius, start)
    # Depth 0 up to Clarabel's accuracy is worth a try too: the exact test judges.
    return moves_towards(grasps, radius, direction[:, 3:], depth > -DEPTH_SLACK)


def moves_towards(grasps: GraspBatch, radius: np.ndarray, torque: np.ndarray,
                  tried: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The moves of at most ``radius`` (N,) that put every work vector deepest into its
    polar cone for the unit torque directions ``torque`` (N, 3) (:func:`.break_distance.
    deepest_moves`), judged by the exact test; only the grasps ``tried`` (N,) bool, or
    all. Returns what :func:`breaking_moves` does."""
    n_grasps, n_contacts = grasps.mu.shape
    found = np.zeros(n_grasps, dtype=bool)
    moves = np.full((n_grasps, n_contacts, 3), np.nan)
    wrench = np.full((n_grasps, 6), np.nan)
    near = np.arange(n_grasps) if tried is None else np.flatnonzero(tried)
    if not near.size:
        return found, moves, wrench
    torque = torque[near]
    unit, centre, size = normalise_positions(grasps.positions[near])
    _, force, step = deepest_moves(unit, grasps.normals[near], grasps.mu[near], torque,
                                   radius[near] / size)
    # Clarabel keeps |w_i| <= r only to its tolerance: shorten to the radius (rounded in).
    length = np.linalg.norm(step, axis=-1) * size[:, None]
    step *= (size[:, None] * np.minimum(1.0, radius[near, None] * (1.0 - 4.0 * _EPS)
                                        / np.maximum(length, np.finfo(float).tiny)))[..., None]
    # a + b x q_i with q_i = (p_i - c) / size is, times size, (size a - b x c) + b x p_i.
    searched = np.concatenate([size[:, None] * force - np.cross(torque, centre), torque],
                              axis=1)
    searched /= np.linalg.norm(searched, axis=1, keepdims=True)
    moved = grasps.positions[near] + step
    closed, separating = exact_verdicts(GraspBatch(moved, grasps.normals[near],
                                                   grasps.mu[near], False, None))
    own = ~np.isnan(separating).any(axis=1)
    _, searched_ok = verify_batch(moved, grasps.normals[near], grasps.mu[near],
                                  separating_wrench=searched)
    broken = ~closed & (own | searched_ok)
    found[near[broken]] = True
    moves[near[broken]] = step[broken]
    wrench[near[broken]] = np.where(own[:, None], separating, searched)[broken]
    return found, moves, wrench


def exact_verdicts(grasps: GraspBatch) -> tuple[np.ndarray, np.ndarray]:
    """The exact test's verdicts (N,) and verified separating wrenches (N, 6) (force,
    torque about the caller's origin; NaN where there is none: force closure, or
    marginal)."""
    verdict = run_pipeline(grasps, use_filter="auto", margin="bound", certificates=True)
    return np.asarray(verdict.force_closure), np.asarray(verdict.separating_wrench)


def turned_axes_wrench(grasps: GraspBatch, spare: np.ndarray) -> np.ndarray:
    """Separating wrenches (N, 6) (NaN where none was found) of grasps whose cones may
    also turn: contact i's cone (friction ``grasps.mu``) about any axis within
    ``spare`` (N, n) radians of its normal: grasps whose tilt errors exceed their cones
    (the shrunk cones are then tiny, and the rest of the tilt is spare). Each round
    turns every axis towards -v_i of the direction with the least support (the epsilon
    search's) and asks the exact test."""
    n_grasps = grasps.mu.shape[0]
    wrench = np.full((n_grasps, 6), np.nan)
    active = np.arange(n_grasps)
    axes = grasps.normals
    for _ in range(AXIS_ROUNDS):
        if not active.size:
            break
        positions = grasps.positions[active]
        centre = positions.mean(axis=1)
        least = epsilon_quality(positions, axes[active], grasps.mu[active], center=centre,
                                rtol=AXIS_RTOL)
        # (u_f, u_t) about c with torques over L: the work vector is
        # u_f + u_t / L x (p - c), so b = u_t / L, a = u_f - b x c.
        torque = least.direction[:, 3:] / least.torque_scale[:, None]
        direction = np.concatenate([least.direction[:, :3] - np.cross(torque, centre),
                                    torque], axis=1)
        turned = axes.copy()
        turned[active] = tilt_towards(grasps.normals[active],
                                      work_vectors(positions, direction), spare[active])
        _, separating = exact_verdicts(GraspBatch(positions, turned[active],
                                                  grasps.mu[active], False, None))
        separated = ~np.isnan(separating).any(axis=1)
        wrench[active[separated]] = separating[separated]
        axes = turned
        active = active[~separated]
    return wrench


def frictionless_wrench(grasps: GraspBatch, floor: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray]:
    """For grasps whose friction may drop to nothing: a wrench (N, 6) on which every
    normal force does negative work, the least-norm solution of
    (n_i, p_i x n_i) . u = -1 (NaN where the normal wrenches are dependent and it has
    none), and friction (N, n) small enough that no force of the cones does positive
    work on it: half of -a_n,i / |a_t,i|, at most ``floor`` (N, n)."""
    unit, centre, size = normalise_positions(grasps.positions)
    rows = np.concatenate([grasps.normals, np.cross(unit, grasps.normals)], axis=-1)
    target = -np.ones(rows.shape[:2])
    solution = np.linalg.pinv(rows) @ target[..., None]               # (N, 6, 1)
    solved = np.abs(rows @ solution + 1.0).max(axis=(1, 2)) <= FRICTIONLESS_RESIDUAL
    # a + b x q_i with q_i = (p_i - c) / size is a + (b / size) x (p_i - c).
    torque = solution[:, 3:, 0] / size[:, None]
    wrench = np.concatenate([solution[:, :3, 0] - np.cross(torque, centre), torque], axis=1)
    wrench /= np.linalg.norm(wrench, axis=1, keepdims=True)
    work = work_vectors(grasps.positions, wrench)
    normal = np.sum(work * grasps.normals, axis=-1)
    tangential = np.linalg.norm(work - normal[..., None] * grasps.normals, axis=-1)
    with np.errstate(divide="ignore"):
        mu = np.minimum(floor, 0.5 * -normal / tangential)
    wrench[~solved] = np.nan
    return wrench, mu
