"""How far contacts must move for a given torque direction b to separate the grasp: one
small second-order cone program per (grasp, b), and a search over b.

A moved grasp (contact i at p_i + d_i) is not force closure iff some wrench (a, b)
separates it: every work vector a + b x (p_i + d_i) lies in the polar cone
K_i° = {x : -n_i . x >= mu_i |x_t|}. With |b| = 1, b x d_i is any vector w_i across b
of length |d_i| (d_i = w_i x b), so for a fixed b the least largest move is

    r*(b) = min t  s.t.  a + b x p_i + w_i in K_i°,  w_i . b = 0,  |w_i| <= t  (all i)

over a in R^3 and the w_i: a second-order cone program, convex in (a, w, t). The least
move that breaks force closure is min over unit b of r*(b), a search over the 2-sphere
(:func:`least_breaking_direction`: a fixed grid, then a local refinement around the
best). Every answer only proposes a direction: the witness built from it is certified
by the exact test (:mod:`.holds`).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from ..certificates import normalise_positions
from ..grasp_input import GraspBatch
from ..stacked_socp import SOLVE_BATCH, BlockShape, solve_stacked, tangent_bases

#: Directions b of the first grid (a Fibonacci lattice of the sphere: ~0.6 rad apart).
GRID_DIRECTIONS = 32

#: Local refinement around the best b: neighbours tried per step (on a circle of the
#: step's angle), and steps (each halves the angle after a step that found nothing
#: better), from a first angle of about half the grid's spacing.
NEIGHBOURS = 6
REFINE_STEPS = 8
FIRST_STEP_RAD = 0.3

#: Grasps per chunk of stacked solves (bounds the memory of the constraint matrices).
GRASPS_PER_CHUNK = 64


def _fibonacci_sphere(count: int) -> np.ndarray:
    """``count`` unit vectors (count, 3) spread evenly over the sphere."""
    index = np.arange(count) + 0.5
    polar = np.arccos(1.0 - 2.0 * index / count)
    azimuth = np.pi * (1.0 + np.sqrt(5.0)) * index
    return np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar),
                     np.cos(polar)], axis=1)


GRID = _fibonacci_sphere(GRID_DIRECTIONS)


@lru_cache(maxsize=16)
def _block_shape(n_contacts: int) -> BlockShape:
    """Variables (a (3), w_i in the plane's basis (2 each), t); rows: per contact its
    polar cone (3), then per contact the ball |w_i| <= t (3)."""
    n_vars = 3 + 2 * n_contacts + 1
    pattern = np.zeros((6 * n_contacts, n_vars), dtype=bool)
    for i in range(n_contacts):
        w = slice(3 + 2 * i, 5 + 2 * i)
        pattern[3 * i:3 * i + 3, :3] = True
        pattern[3 * i:3 * i + 3, w] = True
        ball = 3 * n_contacts + 3 * i
        pattern[ball, -1] = True
        pattern[ball + 1, w.start] = pattern[ball + 2, w.start + 1] = True
    return BlockShape(pattern, 0, 0, (3,) * (2 * n_contacts))


def break_distances(unit: np.ndarray, normals: np.ndarray, mu: np.ndarray,
                    b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """r*(b) and its a for K (grasp, b) pairs of unit-size grasps (module docstring).

    Parameters
    ----------
    unit, normals : ndarray, shape (K, n, 3)
        Contact positions (centred, unit size) and unit normals.
    mu : ndarray, shape (K, n)
    b : ndarray, shape (K, 3)
        Unit torque directions.

    Returns
    -------
    distance : ndarray, shape (K,)
        r*(b) as Clarabel found it (inf where its solve failed).
    force : ndarray, shape (K, 3)
        The force part a of the separating direction (a, b).
    """
    n_pairs, n_contacts = mu.shape
    first, second = tangent_bases(b)      # the plane across b
    plane = np.stack([first, second], axis=-1)                          # (K, 3, 2)
    lever = np.cross(b[:, None, :], unit)                               # b x p_i
    tangent, bitangent = tangent_bases(normals)
    # Rows (A x + s = c, s in Q^3) of the polar cones, for directions n, mu t1, mu t2:
    # s = (-n . x_i, mu t1 . x_i, mu t2 . x_i) with x_i = a + b x p_i + plane y_i.
    directions = np.stack([-normals, mu[..., None] * tangent, mu[..., None] * bitangent],
                          axis=2)                                       # (K, n, 3, 3)
    shape = _block_shape(n_contacts)
    n_vars = shape.pattern.shape[1]
    a_values = np.zeros((n_pairs,) + shape.pattern.shape)
    offsets = np.zeros((n_pairs, 6 * n_contacts))
    on_plane = np.einsum("kirc,kcj->kirj", directions, plane)           # (K, n, 3, 2)
    for i in range(n_contacts):
        rows = slice(3 * i, 3 * i + 3)
        a_values[:, rows, :3] = -directions[:, i]
        a_values[:, rows, 3 + 2 * i:5 + 2 * i] = -on_plane[:, i]
        offsets[:, rows] = np.einsum("krc,kc->kr", directions[:, i], lever[:, i])
        ball = 3 * n_contacts + 3 * i
        a_values[:, ball, -1] = -1.0
        a_values[:, ball + 1, 3 + 2 * i] = a_values[:, ball + 2, 4 + 2 * i] = -1.0
    cost = np.zeros((n_pairs, n_vars))
    cost[:, -1] = 1.0
    distance, force = np.full(n_pairs, np.inf), np.zeros((n_pairs, 3))
    for start in range(0, n_pairs, SOLVE_BATCH):
        chunk = slice(start, start + SOLVE_BATCH)
        solution = solve_stacked(shape, a_values[chunk], offsets[chunk], cost[chunk])
        if solution.converged:
            distance[chunk], force[chunk] = solution.x[:, -1], solution.x[:, :3]
    return distance, force


def least_breaking_direction(grasps: GraspBatch, start: np.ndarray | None = None
                             ) -> tuple[np.ndarray, np.ndarray]:
    """Per grasp the least r*(b) found over the sphere of b, and its direction.

    Parameters
    ----------
    grasps : GraspBatch
        N hard grasps.
    start : ndarray, shape (N, 3), optional
        A torque direction to try besides the grid (e.g. the torque inradius search's).

    Returns
    -------
    distance : ndarray, shape (N,)
        The least r*(b) found, in the positions' unit (an upper bound on the least move
        that breaks force closure, up to Clarabel's accuracy: the exact test judges).
    direction : ndarray, shape (N, 6)
        (a, b), |b| = 1, force and torque about the caller's origin, attaining it.
    """
    n_grasps = grasps.mu.shape[0]
    distance, direction = np.full(n_grasps, np.inf), np.zeros((n_grasps, 6))
    for begin in range(0, n_grasps, GRASPS_PER_CHUNK):
        chunk = np.arange(begin, min(begin + GRASPS_PER_CHUNK, n_grasps))
        distance[chunk], direction[chunk] = _search_chunk(
            grasps, chunk, None if start is None else start[chunk])
    return distance, direction


def _search_chunk(grasps: GraspBatch, chunk: np.ndarray,
                  start: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`least_breaking_direction` on the grasps ``chunk``."""
    unit, centre, size = normalise_positions(grasps.positions[chunk])
    normals, mu = grasps.normals[chunk], grasps.mu[chunk]
    n_grasps = chunk.size
    candidates = np.broadcast_to(GRID, (n_grasps,) + GRID.shape)
    if start is not None:
        usable = np.where(np.linalg.norm(start, axis=1, keepdims=True) > 0, start, GRID[0])
        usable = usable / np.linalg.norm(usable, axis=1, keepdims=True)
        candidates = np.concatenate([candidates, usable[:, None, :]], axis=1)
    best, best_b, best_a = _evaluate(unit, normals, mu, candidates)
    step = np.full(n_grasps, FIRST_STEP_RAD)
    ring = 2.0 * np.pi * np.arange(NEIGHBOURS) / NEIGHBOURS
    for _ in range(REFINE_STEPS):
        first, second = tangent_bases(best_b)
        offsets = (np.cos(ring)[None, :, None] * first[:, None, :]
                   + np.sin(ring)[None, :, None] * second[:, None, :])
        neighbours = (np.cos(step)[:, None, None] * best_b[:, None, :]
                      + np.sin(step)[:, None, None] * offsets)
        value, b, a = _evaluate(unit, normals, mu, neighbours)
        better = value < best
        best[better], best_b[better], best_a[better] = value[better], b[better], a[better]
        step = np.where(better, step, 0.5 * step)
    # Back to the caller's frame: a + b x q_i (q_i = (p_i - c) / size) is, times size,
    # (size a - b x c) + b x p_i.
    force = size[:, None] * best_a - np.cross(best_b, centre)
    return best * size, np.concatenate([force, best_b], axis=1)


def _evaluate(unit: np.ndarray, normals: np.ndarray, mu: np.ndarray,
              candidates: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The best of ``candidates`` (N, C, 3) unit b per grasp: r*(b) (N,), b (N, 3), a (N, 3)."""
    n_grasps, count = candidates.shape[:2]
    pairs = np.repeat(np.arange(n_grasps), count)
    b = candidates.reshape(-1, 3)
    distance, force = break_distances(unit[pairs], normals[pairs], mu[pairs], b)
    distance = distance.reshape(n_grasps, count)
    choice = np.argmin(distance, axis=1)
    rows = np.arange(n_grasps)
    return (distance[rows, choice], candidates[rows, choice].copy(),
            force.reshape(n_grasps, count, 3)[rows, choice])
