"""Positive span of R^3 by fans and planes, against a linear-programming reference."""

import functools

import numpy as np
import pytest
from scipy.optimize import linprog

from grasp_fc_ros.core.filter import positive_span
from grasp_fc_ros.core.filter.positive_span import positively_spans
from grasp_fc_ros.core.filter.torque_sets import TorqueSetKind, TorqueSets


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


@functools.cache
def lp_cases(n_sets, plane_probability):
    """60 random problems, as TorqueSets, and their LP verdicts (shared by all paths)."""
    rng = np.random.default_rng(n_sets * 100 + int(plane_probability * 10))
    problems = [random_sets(rng, n_sets, plane_probability) for _ in range(60)]
    sets = TorqueSets(np.stack([p[0] for p in problems], axis=1),
                      np.stack([p[1] for p in problems], axis=2),
                      np.stack([p[2] for p in problems], axis=2),
                      np.stack([p[3] for p in problems], axis=2))
    return problems, sets, np.array([spans_by_lp(p[4]) for p in problems])


PATHS = {"pair-test": 10**9, "hull": 0}


@pytest.mark.parametrize("path", PATHS)
@pytest.mark.parametrize("plane_probability", [0.0, 0.15, 0.5])
@pytest.mark.parametrize("n_sets", [1, 2, 3, 5, 8])
def test_agrees_with_linear_programming(n_sets, plane_probability, path, monkeypatch):
    """Both forms of the test (chosen by vector count) against the LP, and every
    separating direction it returns really separates."""
    monkeypatch.setattr(positive_span, "HULL_MIN_VECTORS", PATHS[path])
    problems, sets, expected = lp_cases(n_sets, plane_probability)
    assert np.array_equal(positively_spans(sets), expected)
    spans, direction = positively_spans(sets, directions=True)
    assert np.array_equal(spans, expected)
    assert np.isnan(direction[:, spans]).all()
    for problem in np.flatnonzero(~spans):
        c = direction[:, problem]
        assert np.linalg.norm(c) == pytest.approx(1.0)
        generators = problems[problem][4]
        if len(generators):
            assert (generators @ c).min() >= -1e-12
    if 3 <= n_sets <= 5 and plane_probability < 0.5:
        assert expected.any() and not expected.all(), "cases must cover both outcomes"


@pytest.mark.parametrize("n_vectors", [30, 200, 3000])
def test_hull_test_on_many_vectors_agrees_with_linear_programming(n_vectors):
    """Many fans: near a half-space (tilted so that a few cross it) or on a cap."""
    rng = np.random.default_rng(n_vectors)
    verdicts = []
    for tilt in np.linspace(-0.6, 0.05, 14):
        v = rng.normal(size=(n_vectors, 3))
        v[:, 2] = np.abs(v[:, 2]) + tilt
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        found = positive_span._hull_direction(v)
        verdicts.append(spans_by_lp(v))
        assert np.isnan(found).all() == verdicts[-1]
        if not verdicts[-1]:
            assert (v @ found).min() >= -1e-12
    assert any(verdicts) and not all(verdicts)


def test_flat_and_tiny_inputs_of_the_hull_test():
    flat = np.array([[1.0, 0, 0], [0, 1, 0], [-1, -1, 0], [0.3, -0.5, 0], [-0.2, 0.9, 0]])
    c = positive_span._hull_direction(flat)
    assert np.allclose(np.abs(c), [0, 0, 1])
    off_origin = flat + [0, 0, 1.0]                      # a plane the origin is not on
    c = positive_span._hull_direction(off_origin)
    assert (off_origin @ c).min() >= 0
    assert np.allclose(positive_span._hull_direction(np.zeros((4, 3))), [1, 0, 0])
    corners = np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 1]])
    assert (corners @ positive_span._hull_direction(corners)).min() >= 0 or np.isnan(
        positive_span._hull_direction(corners)).all()


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
