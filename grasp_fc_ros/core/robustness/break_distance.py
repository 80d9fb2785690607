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

from ..exact.certificates import normalise_positions
from ..exact.stacked_socp import SOLVE_BATCH, BlockShape, solve_stacked, tangent_bases
from ..model.grasp_input import GraspBatch

#: Directions b of the coarse grid (a Fibonacci lattice of the sphere: ~0.6 rad apart)
#: and of the fine one, and the fine search's refined tracks (its best directions):
#: r*(b) has several valleys, and one refined track from 32 directions missed the least
#: one by over 1% on a third of the box, mug, ... grasps (n = 4); the fine search
#: against a 1,000-direction search: docs/robustness.md#holds-under.
GRID_DIRECTIONS = 32
FINE_GRID_DIRECTIONS = 128
FINE_TRACKS = 3

#: Local refinement around the best b: neighbours tried per step (on a circle of the
#: step's angle), and steps (each halves the angle after a step that found nothing
#: better), from a first angle of about half the grid's spacing.
NEIGHBOURS = 6
REFINE_STEPS = 8
FIRST_STEP_RAD = 0.3

#: The coarse search of :func:`deepest_breaking_direction` settles a grasp once it finds
#: moves that put every work vector this deep (over r) into its polar cone: room enough
#: for the exact test's certificate (CERTIFICATE_TOL is 1e-6 of the work vectors).
ENOUGH_DEPTH = 1e-3

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
FINE_GRID = _fibonacci_sphere(FINE_GRID_DIRECTIONS)


@lru_cache(maxsize=32)
def _block_shape(n_contacts: int, deepest: bool) -> BlockShape:
    """Variables (a (3), w_i in the plane's basis (2 each), t or sigma); rows: per contact
    its polar cone (3), then per contact the ball |w_i| <= t (3). ``deepest``: sigma
    enters the polar cones' first rows and the balls have a fixed radius."""
    n_vars = 3 + 2 * n_contacts + 1
    pattern = np.zeros((6 * n_contacts, n_vars), dtype=bool)
    for i in range(n_contacts):
        w = slice(3 + 2 * i, 5 + 2 * i)
        pattern[3 * i:3 * i + 3, :3] = True
        pattern[3 * i:3 * i + 3, w] = True
        ball = 3 * n_contacts + 3 * i
        pattern[3 * i if deepest else ball, -1] = True
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
    distance, force, _ = _solve(unit, normals, mu, b, None)
    return distance, force


def deepest_moves(unit: np.ndarray, normals: np.ndarray, mu: np.ndarray, b: np.ndarray,
                  radius: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For K (grasp, b) pairs of unit-size grasps, the moves of length <= ``radius`` (K,)
    that put every a + b x (p_i + d_i) deepest in its polar cone:
    max sigma s.t. -n_i . x_i - mu_i |x_t,i| >= sigma, |w_i| <= r.

    Returns
    -------
    depth : ndarray, shape (K,)
        sigma (> 0: the moved grasp is separated by (a, b) with room to spare; -inf
        where the solve failed).
    force : ndarray, shape (K, 3)
        a.
    moves : ndarray, shape (K, n, 3)
        d_i = w_i x b, in the unit grasp's length.
    """
    value, force, moves = _solve(unit, normals, mu, b, radius)
    return -value, force, moves


def _solve(unit: np.ndarray, normals: np.ndarray, mu: np.ndarray, b: np.ndarray,
           radius: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The conic program of :func:`break_distances` (``radius`` None: min t) or of
    :func:`deepest_moves` (min -sigma). Returns (optimum, a, moves), inf where failed."""
    n_pairs, n_contacts = mu.shape
    first, second = tangent_bases(b)      # the plane across b
    plane = np.stack([first, second], axis=-1)                          # (K, 3, 2)
    lever = np.cross(b[:, None, :], unit)                               # b x p_i
    tangent, bitangent = tangent_bases(normals)
    # Rows (A x + s = c, s in Q^3) of the polar cones, for directions n, mu t1, mu t2:
    # s = (-n . x_i [- sigma], mu t1 . x_i, mu t2 . x_i), x_i = a + b x p_i + plane y_i.
    directions = np.stack([-normals, mu[..., None] * tangent, mu[..., None] * bitangent],
                          axis=2)                                       # (K, n, 3, 3)
    shape = _block_shape(n_contacts, radius is not None)
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
        if radius is None:
            a_values[:, ball, -1] = -1.0               # (t, w_i) in Q^3
        else:
            a_values[:, 3 * i, -1] = 1.0               # -n . x_i - sigma
            offsets[:, ball] = radius                  # (r, w_i) in Q^3
        a_values[:, ball + 1, 3 + 2 * i] = a_values[:, ball + 2, 4 + 2 * i] = -1.0
    cost = np.zeros((n_pairs, n_vars))
    cost[:, -1] = 1.0 if radius is None else -1.0
    optimum, force = np.full(n_pairs, np.inf), np.zeros((n_pairs, 3))
    moves = np.zeros((n_pairs, n_contacts, 3))
    for start in range(0, n_pairs, SOLVE_BATCH):
        chunk = slice(start, start + SOLVE_BATCH)
        solution = solve_stacked(shape, a_values[chunk], offsets[chunk], cost[chunk])
        if solution.converged:
            optimum[chunk], force[chunk] = solution.x @ cost[0], solution.x[:, :3]
            across = np.einsum("kcj,kij->kic", plane[chunk],
                               solution.x[:, 3:-1].reshape(-1, n_contacts, 2))
            moves[chunk] = np.cross(across, b[chunk, None, :])   # d = w x b
    return optimum, force, moves


def least_breaking_direction(grasps: GraspBatch, start: np.ndarray | None = None
                             ) -> tuple[np.ndarray, np.ndarray]:
    """Per grasp the least r*(b) found over the sphere of b, and its direction (the
    fine search: FINE_GRID_DIRECTIONS, FINE_TRACKS refined tracks; r*(b) has several
    valleys on the sphere).

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
    value, direction = _search(grasps, start, None, [(FINE_GRID, FINE_TRACKS)])
    return value * normalise_positions(grasps.positions)[2], direction


def deepest_breaking_direction(grasps: GraspBatch, radius: np.ndarray,
                               start: np.ndarray | None = None
                               ) -> tuple[np.ndarray, np.ndarray]:
    """Per grasp the torque direction b whose moves of at most ``radius`` (N,) put the
    work vectors deepest into their polar cones (the most of :func:`deepest_moves`'s
    sigma found over the sphere), and that depth: > 0 where those moves break force
    closure with room to spare. A coarse search (GRID_DIRECTIONS, one refined track),
    then the fine one where it found no depth of ENOUGH_DEPTH r.

    Returns
    -------
    depth : ndarray, shape (N,)
        sigma / r at the best direction found (dimensionless).
    direction : ndarray, shape (N, 6)
        (a, b), |b| = 1, force and torque about the caller's origin.
    """
    value, direction = _search(grasps, start, radius,
                               [(GRID, 1), (FINE_GRID, FINE_TRACKS)])
    return -value, direction


def _search(grasps: GraspBatch, start: np.ndarray | None, radius: np.ndarray | None,
            stages: list[tuple[np.ndarray, int]]) -> tuple[np.ndarray, np.ndarray]:
    """The least objective (r*(b) of the unit grasp, or -sigma / r with a radius) found
    by the grid stages, each on the grasps no earlier stage settled, and its direction."""
    n_grasps = grasps.mu.shape[0]
    value, direction = np.full(n_grasps, np.inf), np.zeros((n_grasps, 6))
    for grid, tracks in stages:
        todo = np.flatnonzero(value > (-ENOUGH_DEPTH if radius is not None else -np.inf))
        for begin in range(0, todo.size, GRASPS_PER_CHUNK):
            chunk = todo[begin:begin + GRASPS_PER_CHUNK]
            found, towards = _search_chunk(grasps, chunk, None if start is None
                                           else start[chunk], None if radius is None
                                           else radius[chunk], grid, tracks)
            better = found < value[chunk]
            value[chunk[better]], direction[chunk[better]] = found[better], towards[better]
    return value, direction


def _search_chunk(grasps: GraspBatch, chunk: np.ndarray, start: np.ndarray | None,
                  radius: np.ndarray | None, grid: np.ndarray, tracks: int
                  ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_search` on the grasps ``chunk`` with one grid, refining its ``tracks``
    best directions."""
    unit, centre, size = normalise_positions(grasps.positions[chunk])
    problem = (unit, grasps.normals[chunk], grasps.mu[chunk],
               None if radius is None else radius / size)
    n_grasps = chunk.size
    candidates = np.broadcast_to(grid, (n_grasps,) + grid.shape)
    if start is not None:
        usable = np.where(np.linalg.norm(start, axis=1, keepdims=True) > 0, start, grid[0])
        usable = usable / np.linalg.norm(usable, axis=1, keepdims=True)
        candidates = np.concatenate([candidates, usable[:, None, :]], axis=1)
    value, force = _values(problem, candidates)
    order = np.argsort(value, axis=1)[:, :tracks]
    best = np.take_along_axis(value, order, axis=1)                       # (N, k)
    best_b = np.take_along_axis(candidates, order[..., None], axis=1)     # (N, k, 3)
    best_a = np.take_along_axis(force, order[..., None], axis=1)
    step = np.full(best.shape, FIRST_STEP_RAD)
    ring = 2.0 * np.pi * np.arange(NEIGHBOURS) / NEIGHBOURS
    for _ in range(REFINE_STEPS):
        first, second = tangent_bases(best_b)
        offsets = (np.cos(ring)[:, None] * first[..., None, :]
                   + np.sin(ring)[:, None] * second[..., None, :])        # (N, k, R, 3)
        neighbours = (np.cos(step)[..., None, None] * best_b[..., None, :]
                      + np.sin(step)[..., None, None] * offsets)
        value, force = _values(problem, neighbours.reshape(n_grasps, -1, 3))
        value = value.reshape(neighbours.shape[:3])
        choice = np.argmin(value, axis=2)[..., None]
        found = np.take_along_axis(value, choice, axis=2)[..., 0]
        better = found < best
        best = np.where(better, found, best)
        best_b = np.where(better[..., None], np.take_along_axis(
            neighbours, choice[..., None], axis=2)[:, :, 0], best_b)
        best_a = np.where(better[..., None], np.take_along_axis(
            force.reshape(neighbours.shape), choice[..., None], axis=2)[:, :, 0], best_a)
        step = np.where(better, step, 0.5 * step)
    track = np.argmin(best, axis=1)
    rows = np.arange(n_grasps)
    b, a = best_b[rows, track], best_a[rows, track]
    # Back to the caller's frame: a + b x q_i (q_i = (p_i - c) / size) is, times size,
    # (size a - b x c) + b x p_i.
    return best[rows, track], np.concatenate([size[:, None] * a - np.cross(b, centre), b],
                                             axis=1)


def _values(problem: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None],
            candidates: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The objective (N, C) and a (N, C, 3) of ``candidates`` (N, C, 3) unit b per
    grasp: r*(b), or -sigma / r of :func:`deepest_moves` where a radius r (N,) is given."""
    unit, normals, mu, radius = problem
    n_grasps, count = candidates.shape[:2]
    pairs = np.repeat(np.arange(n_grasps), count)
    b = candidates.reshape(-1, 3)
    if radius is None:
        value, force = break_distances(unit[pairs], normals[pairs], mu[pairs], b)
    else:
        depth, force, _ = deepest_moves(unit[pairs], normals[pairs], mu[pairs], b,
                                        radius[pairs])
        value = -depth / radius[pairs]
    return value.reshape(n_grasps, count), force.reshape(n_grasps, count, 3)
