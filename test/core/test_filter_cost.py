"""The filter's cost is bounded for every contact count, and the pipeline's policy."""

import tracemalloc

import numpy as np
import pytest

from grasp_cases import ellipsoid_grasps
from grasp_fc_ros.core import check_force_closure, exact_force_closure, torque_filter
from grasp_fc_ros.core.filter import positive_span, torque_space_filter
from grasp_fc_ros.core.filter.torque_space_filter import (
    FILTER_PAYS_UP_TO_CONTACTS,
    filter_worthwhile,
    resolve_use_filter,
)


def peak_bytes(function):
    """Peak memory numpy (and Python) allocated while ``function`` ran."""
    tracemalloc.start()
    try:
        function()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_many_contacts_at_low_friction_stay_within_bounded_memory():
    """Issue 8's case: 127 grasps x 64 contacts at mu 0.01 took 2.1 GiB in the pair test."""
    rng = np.random.default_rng(0)
    positions, normals = ellipsoid_grasps(rng, 127, 64)
    positions[:60, :, 1:] = 0.0              # contacts on a line: not force closure
    passed = []
    peak = peak_bytes(lambda: passed.append(torque_filter(positions, normals, 0.01)))
    assert peak < 150e6, f"{peak / 1e6:.0f} MB"
    assert (~passed[0]).any()


def test_hundreds_of_contacts_are_filtered_soundly_and_with_certificates():
    rng = np.random.default_rng(1)
    positions, normals = ellipsoid_grasps(rng, 4, 300)
    # Two grasps with every contact on one face, sharing its normal: not force closure.
    positions[:2] = np.concatenate([rng.uniform(-1, 1, (2, 300, 2)), np.zeros((2, 300, 1))],
                                   axis=2)
    normals[:2] = [0.0, 0.0, 1.0]
    exact = exact_force_closure(positions, normals, 0.05)
    passed, wrench = torque_filter(positions, normals, 0.05, certificates=True)
    assert exact[2:].all() and passed[2:].all()
    assert not passed[:2].any() and np.isfinite(wrench[:2]).all()


@pytest.mark.parametrize("n_contacts", [12, 18, 19, 30])
def test_pair_and_hull_tests_agree_on_the_filter(n_contacts, monkeypatch):
    rng = np.random.default_rng(n_contacts)
    positions, normals = ellipsoid_grasps(rng, 300, n_contacts)
    # Half of them near one face with tilted normals: both verdicts occur.
    positions[:150, :, 2] = rng.uniform(-0.1, 0.1, (150, n_contacts))
    normals[:150] = [0.0, 0.0, 1.0] + rng.uniform(-0.4, 0.4, (150, n_contacts, 3))
    verdicts = []
    for hull_from in (0, 10**9):
        monkeypatch.setattr(positive_span, "HULL_MIN_VECTORS", hull_from)
        verdicts.append(torque_filter(positions, normals, 0.01))
    assert np.array_equal(*verdicts) and (~verdicts[0]).any()


def test_memory_per_pass_is_chunked_whatever_the_batch(monkeypatch):
    """Splitting the problems into passes changes nothing but memory."""
    rng = np.random.default_rng(2)
    positions, normals = ellipsoid_grasps(rng, 400, 7)
    whole = torque_filter(positions, normals, 0.2, origins="all", certificates=True)
    monkeypatch.setattr(torque_space_filter, "_MAX_LEVER_ARMS_PER_PASS", 50)
    parts = torque_filter(positions, normals, 0.2, origins="all", certificates=True)
    assert np.array_equal(whole[0], parts[0])
    assert np.array_equal(whole[1], parts[1], equal_nan=True)


def test_auto_runs_the_filter_only_where_it_pays():
    seed_limit = FILTER_PAYS_UP_TO_CONTACTS["seed"]
    assert filter_worthwhile(3) and filter_worthwhile(seed_limit)
    assert not filter_worthwhile(seed_limit + 1) and not filter_worthwhile(10_000)
    assert resolve_use_filter(True, 10_000) and not resolve_use_filter(False, 3)
    with pytest.raises(ValueError, match="use_filter must be True, False or 'auto'"):
        resolve_use_filter("yes", 4)
    with pytest.raises(ValueError, match="origins must be one of"):
        filter_worthwhile(4, "centroid")

    rng = np.random.default_rng(3)
    for n_contacts, filtered in ((4, True), (seed_limit + 2, False)):
        positions, normals = ellipsoid_grasps(rng, 100, n_contacts)
        normals[:, :, 2] = -np.abs(normals[:, :, 2]) - 0.5
        auto = check_force_closure(positions, normals, 0.01, use_filter="auto")
        forced = check_force_closure(positions, normals, 0.01, use_filter=filtered)
        assert np.array_equal(auto.status, forced.status)
        assert auto.filtered_out.any() == filtered


def test_thousands_of_contacts_need_no_per_size_tables():
    """5,000 contacts: an (n, n-1) index table alone would be 200 MB."""
    rng = np.random.default_rng(4)
    positions, normals = ellipsoid_grasps(rng, 1, 5000)
    face = np.concatenate([rng.uniform(-1, 1, (1, 5000, 2)), np.zeros((1, 5000, 1))], axis=2)
    face_normals = [0.0, 0.0, 1.0] + rng.uniform(-0.3, 0.3, face.shape)
    results = []
    peak = peak_bytes(lambda: results.append(torque_filter(
        np.concatenate([positions, face]), np.concatenate([normals, face_normals]), 0.01,
        certificates=True)))
    assert peak < 100e6, f"{peak / 1e6:.0f} MB"
    passed, wrench = results[0]
    assert passed[0] and not passed[1] and np.isfinite(wrench[1]).all()


def test_all_origins_are_capped_for_many_contacts_and_stay_sound():
    from grasp_fc_ros.core.filter.torque_space_filter import MAX_ALL_ORIGINS, _origin_indices
    rng = np.random.default_rng(5)
    positions, normals = ellipsoid_grasps(rng, 6, 200)
    positions[:3, :, 1:] *= 1e-3             # nearly a line: most are not force closure
    points = np.ascontiguousarray(positions.transpose(2, 1, 0))
    chosen = _origin_indices(points, "all")
    assert chosen.shape == (MAX_ALL_ORIGINS, 6)
    assert np.array_equal(chosen[:2], _origin_indices(points, "seed"))
    assert len(np.unique(chosen[2:, 0])) == MAX_ALL_ORIGINS - 2
    assert _origin_indices(points[:, :MAX_ALL_ORIGINS], "all").shape[0] == MAX_ALL_ORIGINS
    exact = exact_force_closure(positions, normals, 0.02)
    passed = torque_filter(positions, normals, 0.02, origins="all")
    assert not np.any(exact & ~passed)
    assert not np.any(passed & ~torque_filter(positions, normals, 0.02, origins="seed"))
