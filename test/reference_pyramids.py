"""Independent reference for the exact test (test-only): friction pyramids and an LP.

Each quadratic friction cone is replaced by an m-sided pyramid, either inscribed (inside
the cone: if its grasp is force closure, so is the true one) or circumscribed (around
the cone: if its grasp is not force closure, neither is the true one). A polyhedral
grasp is force closure iff its primitive wrenches W have rank 6 and some strictly
positive combination of them sums to zero, decided here with scipy's LP solver.
"""

import numpy as np
from scipy.optimize import linprog


def pyramid_edges(normal, mu, sides, inscribed):
    """Unit edge directions (sides, 3) of a pyramid inscribed in / circumscribing a cone."""
    helper = np.eye(3)[np.abs(normal).argmin()]
    t1 = np.cross(normal, helper)
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(normal, t1)
    radius = mu * (np.cos(np.pi / sides) if inscribed else 1.0 / np.cos(np.pi / sides))
    angle = 2 * np.pi * np.arange(sides) / sides
    edges = normal + radius * (np.cos(angle)[:, None] * t1 + np.sin(angle)[:, None] * t2)
    return edges / np.linalg.norm(edges, axis=1, keepdims=True)


def pyramid_margin(positions, normals, mu, sides=8, inscribed=True):
    """Largest s with W lam = 0, lam >= s, sum(lam) = 1; 0 if W has rank < 6.

    positions, normals: (n, 3); normals unit. Returns s (> 0 iff force closure).
    """
    centred = positions - positions.mean(axis=0)
    centred /= np.abs(centred).max()
    columns = []
    for p, n in zip(centred, normals):
        for f in pyramid_edges(n, mu, sides, inscribed):
            columns.append(np.concatenate([f, np.cross(p, f)]))
    wrenches = np.array(columns).T                                     # (6, n*sides)
    if np.linalg.matrix_rank(wrenches, tol=1e-9) < 6:
        return 0.0
    k = wrenches.shape[1]
    # Variables (lam_1..lam_k, s): maximise s.
    cost = np.zeros(k + 1)
    cost[-1] = -1.0
    a_eq = np.vstack([np.hstack([wrenches, np.zeros((6, 1))]),
                      np.hstack([np.ones(k), [0.0]])])
    b_eq = np.concatenate([np.zeros(6), [1.0]])
    a_ub = np.hstack([-np.eye(k), np.ones((k, 1))])                    # s - lam <= 0
    result = linprog(cost, A_ub=a_ub, b_ub=np.zeros(k), A_eq=a_eq, b_eq=b_eq,
                     bounds=[(0, None)] * k + [(None, None)], method="highs")
    if result.status == 2:        # infeasible: no equilibrium with sum(lam) = 1 at all
        return 0.0
    assert result.status == 0, result.message
    return max(result.x[-1], 0.0)
