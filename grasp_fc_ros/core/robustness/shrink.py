"""Shrunk friction cones, and the largest shrink at which a grasp stays force closure.

Tilt lemma: if angle(n', n) <= delta <= alpha, the cone K(n', alpha) contains
K(n, alpha - delta) (the triangle inequality for angles on the sphere). So a grasp that
is force closure with half-angles alpha_i - delta at its own normals is force closure
for every choice of normals each within delta of its own; with friction coefficients
dropped by d it is the cone of mu_i - d that shrinks. Force closure only grows with the
cones, so "force closure at shrink s" is monotone in s, and the largest such s is
bracketed by exact tests (:func:`largest_closed_shrink`). A cone shrunk away (delta
past alpha_i, or d past mu_i) is left out: force closure without a contact implies it
with the contact, wherever its normal points.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..exact.exact_test import solve_exact
from ..model.grasp_input import GraspBatch

#: A shrunk friction coefficient is lowered by this relative amount after it is
#: computed, so that it is never above the exact tan(arctan(mu) - delta) (or mu - d):
#: tan and arctan are correct to an ulp or two, but near the largest accepted mu (1e3,
#: a half-angle within 1e-3 of pi/2) tan magnifies an ulp of the angle ~1.6e3 times.
#: The radii move by far less than their bracket (BRACKET_RTOL).
SHRINK_ROUNDING = 1e-10

#: The bisection stops once its bracket [lower, upper] is this narrow relative to
#: lower: the radius reported is lower (tested force closure), and a shrink of
#: upper <= (1 + BRACKET_RTOL) lower is tested not force closure (or is the limit).
#: Each halving costs one batched exact test (~2 us per grasp), so a tight bracket is
#: cheap (docs/robustness.md#cost).
BRACKET_RTOL = 1e-3

#: Halvings at most. Where the nominal grasp is force closure only just (margin near
#: MARGIN_TOL), every shrink may fail; after this many halvings (limit / 2^60) the
#: radius is 0, which is always sound.
MAX_HALVINGS = 60


def tilted_friction(mu: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """Friction coefficients tan(arctan(mu) - delta), rounded down (SHRINK_ROUNDING);
    0 where delta >= arctan(mu). ``delta`` broadcasts against ``mu``."""
    angle = np.arctan(mu) - delta
    return np.where(angle > 0.0, np.tan(np.maximum(angle, 0.0)) * (1.0 - SHRINK_ROUNDING),
                    0.0)


def dropped_friction(mu: np.ndarray, drop: np.ndarray) -> np.ndarray:
    """Friction coefficients mu - drop, rounded down (SHRINK_ROUNDING), 0 at most."""
    return np.maximum((mu - drop) * (1.0 - SHRINK_ROUNDING), 0.0)


def with_friction(grasps: GraspBatch, index: np.ndarray, mu: np.ndarray) -> GraspBatch:
    """The grasps ``index`` of a hard batch with friction ``mu`` (len(index), n)."""
    return GraspBatch(grasps.positions[index], grasps.normals[index],
                      np.ascontiguousarray(mu), False, None)


def without_vanished(grasps: GraspBatch, index: np.ndarray, mu: np.ndarray
                     ) -> tuple[GraspBatch, np.ndarray]:
    """The grasps ``index`` with friction ``mu`` (len(index), n), where a contact whose
    cone has shrunk away (mu 0) is left out: it becomes a copy of the grasp's first
    contact that keeps a cone, which adds no wrench of its own, so every grasp keeps n
    contacts (one batch). Leaving a contact out only shrinks the wrenches a grasp can
    apply, so force closure without it implies force closure with it, whatever its
    normal. Returns the batch and which grasps keep a cone at all (N,)."""
    kept = mu > 0.0
    any_kept = kept.any(axis=1)
    first = kept.argmax(axis=1)
    rows = np.arange(index.size)[:, None]
    source = np.where(kept, np.arange(mu.shape[1])[None, :], first[:, None])
    return GraspBatch(grasps.positions[index[:, None], source],
                      grasps.normals[index[:, None], source],
                      np.ascontiguousarray(mu[rows, source]), False, None), np.asarray(any_kept)


def closed_under(grasps: GraspBatch, index: np.ndarray, mu: np.ndarray) -> np.ndarray:
    """The exact test's verdicts (len(index),) on the grasps ``index`` with friction
    ``mu``, contacts of friction 0 (cones shrunk away) left out (:func:`without_vanished`)."""
    closed = np.zeros(index.size, dtype=bool)
    batch, any_kept = without_vanished(grasps, index, mu)
    tested = np.flatnonzero(any_kept)
    if tested.size:
        closed[tested] = solve_exact(with_friction(batch, tested, batch.mu[tested]),
                                     "bound").force_closure
    return closed


def largest_closed_shrink(grasps: GraspBatch, closed: np.ndarray,
                          shrunk: Callable[[np.ndarray, np.ndarray], np.ndarray],
                          limit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per grasp, a bracket [lower, upper] of the largest shrink s in [0, limit) at which
    the grasp with friction ``shrunk(mu, s)`` is force closure by the exact test.

    Parameters
    ----------
    grasps : GraspBatch
        N hard grasps.
    closed : ndarray of bool, shape (N,)
        The nominal verdicts (shrink 0); grasps that are not force closure get [0, 0].
    shrunk : callable
        (mu (k, n), s (k, 1)) -> friction (k, n), decreasing in s.
    limit : ndarray, shape (N,)
        Shrinks are tried below it (where the last cone would vanish).

    Returns
    -------
    lower : ndarray, shape (N,)
        The largest shrink tested force closure (0 where only the nominal grasp was).
    upper : ndarray, shape (N,)
        The least shrink tested not force closure, or ``limit`` where none was;
        upper <= (1 + BRACKET_RTOL) lower unless MAX_HALVINGS ran out.
    """
    lower = np.zeros(closed.shape)
    upper = np.where(closed, limit, 0.0)
    active = np.flatnonzero(closed)
    for _ in range(MAX_HALVINGS):
        if not active.size:
            break
        middle = 0.5 * (lower[active] + upper[active])
        holds = closed_under(grasps, active, shrunk(grasps.mu[active], middle[:, None]))
        lower[active[holds]] = middle[holds]
        upper[active[~holds]] = middle[~holds]
        active = active[upper[active] - lower[active] > BRACKET_RTOL * lower[active]]
    return lower, upper
