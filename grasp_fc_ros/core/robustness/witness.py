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
  needs the least moves; for it the deepest moves of length <= r are found contact by
  contact (:func:`best_moves`), and the exact test judges the moved grasp.
"""

from __future__ import annotations

import numpy as np

from ..certificates import normalise_positions
from ..epsilon import epsilon_quality
from ..grasp_input import GraspBatch
from ..pipeline import run_pipeline
from .break_distance import least_breaking_direction

#: A direction whose r*(b) is up to this much (relative) over the radius is still tried:
#: Clarabel's optimum is accurate to ~1e-8, and the exact test judges the witness.
BREAK_SLACK = 1e-6

#: Rounds of :func:`turned_axes_wrench`, and the accuracy of its epsilon searches (only
#: a direction is needed). One round found every witness on the benchmark's grasps
#: (docs/robustness.md#holds-under); the others catch what a first turn overshoots.
AXIS_ROUNDS = 3
AXIS_RTOL = 1e-2

#: The least-norm wrench of :func:`frictionless_wrench` counts only where every normal
#: wrench's work on it is within this of -1 (rows of a unit-size grasp: a solution,
#: not a least-squares compromise).
FRICTIONLESS_RESIDUAL = 1e-9

#: Directions on the circle of moves of length r tried per contact, before the best is
#: refined by golden-section steps (MOVE_REFINEMENTS).
MOVE_ANGLES = 48
MOVE_REFINEMENTS = 16

_GOLDEN = 0.5 * (np.sqrt(5.0) - 1.0)


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
    turned = np.where((between <= angles)[..., None], target, turned)
    no_work = ~(np.linalg.norm(work, axis=-1) > 0.0)
    return np.where(no_work[..., None], normals, turned)


def work_vectors(positions: np.ndarray, wrench: np.ndarray) -> np.ndarray:
    """v_i = w_force + w_torque x p_i (N, n, 3) of wrenches (N, 6) at positions (N, n, 3)."""
    return wrench[:, None, :3] + np.cross(wrench[:, None, 3:], positions)


def polar_excess(work: np.ndarray, normals: np.ndarray, mu: np.ndarray) -> np.ndarray:
    """v . n + mu |v_t| (...): the largest work of a unit-normal force of the cone on v,
    <= 0 exactly where v lies in the cone's polar."""
    normal = np.sum(work * normals, axis=-1)
    return normal + mu * np.linalg.norm(work - normal[..., None] * normals, axis=-1)


def best_moves(grasps: GraspBatch, direction: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """Per contact a move d_i, |d_i| <= r, that makes v_i + b x d_i as deep in the polar
    cone as found (the least :func:`polar_excess`), for directions (a, b) (N, 6) with
    |b| = 1 and radii r (N,). Returns d (N, n, 3)."""
    torque = direction[:, 3:]
    work = work_vectors(grasps.positions, direction)                      # (N, n, 3)
    first = np.cross(torque, np.where(np.abs(torque[:, :1]) < 0.9, [1.0, 0.0, 0.0],
                                      [0.0, 1.0, 0.0]))
    first /= np.linalg.norm(first, axis=1, keepdims=True)
    second = np.cross(torque, first)

    def excess(angle: np.ndarray, scale: np.ndarray) -> np.ndarray:
        across = (np.cos(angle)[..., None] * first[:, None, None, :]
                  + np.sin(angle)[..., None] * second[:, None, None, :])
        moved = work[:, :, None, :] + (radius[:, None, None] * scale)[..., None] * across
        return polar_excess(moved, grasps.normals[:, :, None, :], grasps.mu[:, :, None])

    n_grasps, n_contacts = grasps.mu.shape
    angles = np.broadcast_to(2 * np.pi * np.arange(MOVE_ANGLES) / MOVE_ANGLES,
                             (n_grasps, n_contacts, MOVE_ANGLES))
    ring = excess(angles, np.ones(angles.shape))
    best = np.take_along_axis(angles, ring.argmin(axis=-1)[..., None], axis=-1)
    low, high = best - 2 * np.pi / MOVE_ANGLES, best + 2 * np.pi / MOVE_ANGLES
    one = np.ones(best.shape)
    for _ in range(MOVE_REFINEMENTS):
        left, right = high - _GOLDEN * (high - low), low + _GOLDEN * (high - low)
        keep_left = excess(left, one) <= excess(right, one)
        high = np.where(keep_left, right, high)
        low = np.where(keep_left, low, left)
    angle = 0.5 * (low + high)[..., 0]
    # The move that stays (length 0) where it is better than every move of length r.
    stay = (polar_excess(work, grasps.normals, grasps.mu)
            < excess(angle[..., None], one)[..., 0])
    across = (np.cos(angle)[..., None] * first[:, None, :]
              + np.sin(angle)[..., None] * second[:, None, :])
    change = np.where(stay[..., None], 0.0, radius[:, None, None] * across)   # b x d
    return np.cross(change, torque[:, None, :])                               # d = w x b


def breaking_moves(grasps: GraspBatch, radius: np.ndarray, start: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Search moves of at most ``radius`` (N,) that break force closure of force-closure
    grasps: the direction of the least r*(b) found (:mod:`.break_distance`), where it is
    at most the radius, then the deepest moves of length <= r for it (:func:`best_moves`).

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
        The exact test certified the moved grasp not force closure (a verified
        separating wrench).
    moves : ndarray, shape (N, n, 3)
        The moves (NaN where not found).
    wrench : ndarray, shape (N, 6)
        The exact test's separating wrench of the moved grasp (NaN where not found).
    """
    n_grasps, n_contacts = grasps.mu.shape
    found = np.zeros(n_grasps, dtype=bool)
    moves = np.full((n_grasps, n_contacts, 3), np.nan)
    wrench = np.full((n_grasps, 6), np.nan)
    distance, direction = least_breaking_direction(grasps, start)
    # Clarabel's r*(b) is accurate to ~1e-8 relative: a little over the radius may
    # still break with moves of the whole radius.
    near = np.flatnonzero(distance <= radius * (1.0 + BREAK_SLACK))
    if near.size:
        batch = GraspBatch(grasps.positions[near], grasps.normals[near], grasps.mu[near],
                           False, None)
        step = best_moves(batch, direction[near], radius[near])
        closed, separating = exact_verdicts(GraspBatch(batch.positions + step, batch.normals,
                                                       batch.mu, False, None))
        broken = ~closed & ~np.isnan(separating).any(axis=1)
        found[near[broken]] = True
        moves[near[broken]] = step[broken]
        wrench[near[broken]] = separating[broken]
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
