"""Independent references for the robustness radii (test-only): Clarabel directly, and the
perturbations an adversary tries.

The position radius rho is the inradius, about the origin, of the set of pure torques
the grasp applies with zero net force and total contact force at most 1:
S = {sum_i p_i x f_i : sum_i f_i = 0, f_i in K_i, sum_i |f_i| <= 1}. Its support
function g(b) is one small conic program (:func:`torque_support`), solved here with
Clarabel's own API (not the core's stacked solves), and rho = min over unit b of g(b).
"""

import clarabel
import numpy as np
from scipy import sparse
from scipy.optimize import minimize


def _frame(normal):
    helper = np.eye(3)[np.abs(normal).argmin()]
    first = np.cross(normal, helper)
    first /= np.linalg.norm(first)
    return first, np.cross(normal, first)


def torque_support(positions, normals, mu, b):
    """g(b) = max b . sum_i p_i x f_i over sum f_i = 0, f_i in K_i, sum |f_i| <= 1.

    positions, normals (n, 3) (normals unit), mu (n,) or a number, b (3,) unit.
    Variables: f_i (3 each), s_i (1 each); maximise sum_i f_i . (b x p_i).
    """
    positions = positions - positions.mean(axis=0)
    n = len(positions)
    mu = np.broadcast_to(np.asarray(mu, float), (n,))
    n_vars = 4 * n
    rows, rhs, cones = [], [], []
    for k in range(3):                                          # sum f_i = 0
        row = np.zeros(n_vars)
        row[k:3 * n:3] = 1.0
        rows.append(row)
        rhs.append(0.0)
    cones.append(clarabel.ZeroConeT(3))
    row = np.zeros(n_vars)                                      # sum s_i <= 1
    row[3 * n:] = 1.0
    rows.append(row)
    rhs.append(1.0)
    cones.append(clarabel.NonnegativeConeT(1))
    for i in range(n):
        t1, t2 = _frame(normals[i])
        block = np.zeros((3, n_vars))                           # (mu n.f, t1.f, t2.f) in Q3
        block[0, 3 * i:3 * i + 3] = -mu[i] * normals[i]
        block[1, 3 * i:3 * i + 3] = -t1
        block[2, 3 * i:3 * i + 3] = -t2
        rows.extend(block)
        rhs.extend([0.0] * 3)
        cones.append(clarabel.SecondOrderConeT(3))
        block = np.zeros((4, n_vars))                           # (s_i, f_i) in Q4
        block[0, 3 * n + i] = -1.0
        block[1:, 3 * i:3 * i + 3] = -np.eye(3)
        rows.extend(block)
        rhs.extend([0.0] * 4)
        cones.append(clarabel.SecondOrderConeT(4))
    cost = np.zeros(n_vars)
    cost[:3 * n] = -np.cross(b, positions).ravel()
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    settings.tol_gap_abs = settings.tol_gap_rel = settings.tol_feas = 1e-10
    solver = clarabel.DefaultSolver(sparse.csc_matrix((n_vars, n_vars)), cost,
                                    sparse.csc_matrix(np.array(rows)), np.array(rhs), cones,
                                    settings)
    solution = solver.solve()
    assert solution.status in (clarabel.SolverStatus.Solved,
                               clarabel.SolverStatus.AlmostSolved), solution.status
    return -solution.obj_val


def sphere_points(count):
    """``count`` unit vectors (count, 3) spread evenly (a Fibonacci lattice)."""
    index = np.arange(count) + 0.5
    polar = np.arccos(1.0 - 2.0 * index / count)
    azimuth = np.pi * (1.0 + np.sqrt(5.0)) * index
    return np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar),
                     np.cos(polar)], axis=1)


def torque_inradius_reference(positions, normals, mu, samples=60, refine=3):
    """min over unit b of g(b): the least of ``samples`` lattice directions, refined by
    Nelder-Mead (on the sphere's angles) from the ``refine`` best. An upper bound on rho
    (a minimum over some directions), close to it."""
    directions = sphere_points(samples)
    values = np.array([torque_support(positions, normals, mu, b) for b in directions])

    def g(angles):
        polar, azimuth = angles
        b = np.array([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth),
                      np.cos(polar)])
        return torque_support(positions, normals, mu, b)

    best = values.min()
    for k in np.argsort(values)[:refine]:
        x, y, z = directions[k]
        start = np.array([np.arccos(np.clip(z, -1, 1)), np.arctan2(y, x)])
        found = minimize(g, start, method="Nelder-Mead",
                         options={"xatol": 1e-7, "fatol": 1e-12, "maxiter": 300})
        best = min(best, found.fun)
    return best


def random_tilts(rng, normals, angle):
    """Each unit normal (..., 3) turned by exactly ``angle`` (broadcast) about a random
    axis across it."""
    helper = rng.normal(size=normals.shape)
    across = np.cross(normals, helper)
    across /= np.linalg.norm(across, axis=-1, keepdims=True)
    angle = np.broadcast_to(angle, normals.shape[:-1])[..., None]
    return np.cos(angle) * normals + np.sin(angle) * across


def random_moves(rng, shape, radius):
    """Moves (..., 3) of shape ``shape``, uniform in the ball of ``radius`` (broadcast
    over the leading axes), half of them on its surface."""
    direction = rng.normal(size=shape)
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    length = rng.uniform(size=shape[:-1]) ** (1.0 / 3.0)
    length[..., ::2] = 1.0
    return direction * (np.broadcast_to(radius, shape[:-1]) * length)[..., None]


def separates(positions, normals, mu, wrench, tol=1e-6):
    """No contact force does more than ``tol`` (relative) positive work on ``wrench``
    (force, torque about the origin): the definition, in five lines."""
    work = wrench[:3] + np.cross(wrench[3:], positions)
    normal = np.sum(work * normals, axis=1)
    tangential = np.linalg.norm(work - normal[:, None] * normals, axis=1)
    largest = np.linalg.norm(work, axis=1).max()
    return bool(np.all(normal + mu * tangential <= tol * largest))
