"""Positive span of R^3 by fans and planes, against a linear-programming reference."""

import numpy as np
import pytest
from scipy.optimize import linprog

from grasp_fc_ros.core import positive_span
from grasp_fc_ros.core.positive_span import positively_spans
from grasp_fc_ros.core.torque_sets import TorqueSetKind, TorqueSets


def spans_by_lp(vectors):
    """Reference: vectors (K, 3) positively span R^3 iff each of +-e_i is a
    non-negative combination of them."""
    if len(vectors) == 0:
        return False
    for target in np.vstack([np.eye(3), -np.eye(3)]):
        result = linprog(np.zeros(len(vectors)), A_eq=vectors.T, b_eq=target,
                         bounds=[(0, None)] * len(vectors), method="highs")
        if result.status != 0:
            return False
    return True


def random_sets(rng, n_sets, plane_probability):
    """One problem of random fans, planes and null sets, and its generating vectors."""
    kind, first, second, axis, generators = [], [], [], [], []
    for _ in range(n_sets):
        normal = rng.normal(size=3)
        normal /= np.linalg.norm(normal)
        u = np.cross(normal, rng.normal(size=3))
        u /= np.linalg.norm(u)
        v = np.cross(normal, u)
        draw = rng.uniform()
        if draw < plane_probability:
            kind.append(TorqueSetKind.PLANE)
            first.append(np.zeros(3))
            second.append(np.zeros(3))
            generators += [u, -u, v, -v]
        elif draw < plane_probability + 0.05:
            kind.append(TorqueSetKind.NULL)
            first.append(np.zeros(3))
            second.append(np.zeros(3))
            normal = np.zeros(3)
        else:
            half = rng.uniform(0.01, 1.5)
            a = np.cos(half) * u + np.sin(half) * v
            b = np.cos(half) * u - np.sin(half) * v
            kind.append(TorqueSetKind.FAN)
            first.append(a)
            second.append(b)
            generators += [a, b]
        axis.append(normal)
    return (np.array(kind), np.array(first).T, np.array(second).T, np.array(axis).T,
            np.array(generators).reshape(-1, 3))


@pytest.mark.parametrize("triple_loop_from", [0, 10**9], ids=["triple-loop", "broadcast"])
@pytest.mark.parametrize("plane_probability", [0.0, 0.15, 0.5])
@pytest.mark.parametrize("n_sets", [1, 2, 3, 5, 8])
def test_agrees_with_linear_programming(n_sets, plane_probability, triple_loop_from,
                                        monkeypatch):
    """Both forms of the pair test (chosen by batch size) against the LP."""
    monkeypatch.setattr(positive_span, "_TRIPLE_LOOP_MIN_PROBLEMS", triple_loop_from)
    rng = np.random.default_rng(n_sets * 100 + int(plane_probability * 10))
    problems = [random_sets(rng, n_sets, plane_probability) for _ in range(60)]
    sets = TorqueSets(np.stack([p[0] for p in problems], axis=1),
                      np.stack([p[1] for p in problems], axis=2),
                      np.stack([p[2] for p in problems], axis=2),
                      np.stack([p[3] for p in problems], axis=2))
    expected = np.array([spans_by_lp(p[4]) for p in problems])
    assert np.array_equal(positively_spans(sets), expected)
    if 3 <= n_sets <= 5 and plane_probability < 0.5:
        assert expected.any() and not expected.all(), "cases must cover both outcomes"


def test_two_non_parallel_planes_span_but_parallel_ones_do_not():
    def planes(*normals):
        normals = np.array(normals, float).T[:, :, None]
        zeros = np.zeros_like(normals)
        return TorqueSets(np.full((normals.shape[1], 1), TorqueSetKind.PLANE, np.int8),
                          zeros, zeros, normals)
    assert positively_spans(planes([0, 0, 1], [0, 1, 0]))[0]
    assert not positively_spans(planes([0, 0, 1], [0, 0, -1]))[0]


def test_only_null_sets_do_not_span():
    zeros = np.zeros((3, 4, 1))
    sets = TorqueSets(np.zeros((4, 1), np.int8), zeros, zeros, zeros)
    assert not positively_spans(sets)[0]
