"""The one-grasp fast path of check_force_closure: same input to the exact stage, same
results as the general path and as a batch, same errors; its compiled torque filter
decides as the numpy filter."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from grasp_cases import MU_PAPER, adversarial_grasps, ellipsoid_grasps
from grasp_fc_ros.core import check_force_closure, minimum_friction, pipeline
from grasp_fc_ros.core.exact.certificates import normalise_positions
from grasp_fc_ros.core.filter.one_grasp_filter import MAX_FILTER_CONTACTS, passes_filter
from grasp_fc_ros.core.filter.torque_space_filter import passes_torque_filter
from grasp_fc_ros.core.model.grasp_input import prepare_grasps
from grasp_fc_ros.core.one_grasp import GENERAL_PATH, _prepare_one
from grasp_fc_ros.core.tolerances import MARGIN_ACCURACY, MARGIN_TOL
from grasp_fc_ros.objects import make_object, sample_grasps
from reference_pyramids import pyramid_margin


def general_path(positions, normals, mu, **options):
    return pipeline.run_pipeline(prepare_grasps(positions, normals, mu),
                                 options.pop("use_filter", "auto"), **options)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_contacts=st.integers(2, 12),
       exponent=st.integers(-300, 300))
def test_prepared_input_is_bit_identical_to_numpy(seed, n_contacts, exponent):
    """The compiled validation and normalisation feed the fast stage exactly what
    prepare_grasps and normalise_positions give it, at any scale."""
    rng = np.random.default_rng(seed)
    positions = rng.normal(size=(n_contacts, 3)) * 10.0 ** exponent + rng.normal(size=3)
    normals = rng.normal(size=(n_contacts, 3)) * 10.0 ** rng.integers(-300, 300)
    unit, directions, friction = (np.empty((n_contacts, 3)), np.empty((n_contacts, 3)),
                                  np.empty(n_contacts))
    assert _prepare_one(positions, normals, 0.3, unit, directions, friction)
    grasps = prepare_grasps(positions, normals, 0.3)
    np.testing.assert_array_equal(directions, grasps.normals[0])
    np.testing.assert_array_equal(unit, normalise_positions(grasps.positions)[0][0])
    np.testing.assert_array_equal(friction, 0.3)


def test_results_equal_the_general_path(monkeypatch):
    decided = []
    check_one = pipeline.check_one
    monkeypatch.setattr(pipeline, "check_one", lambda *args: decided.append(check_one(*args))
                        or decided[-1])
    rng = np.random.default_rng(5)
    cases = [(p, n) for size in (2, 3, 5, 6, 8, 20)
             for p, n in zip(*ellipsoid_grasps(rng, 40, size), strict=True)]
    cases += adversarial_grasps(rng) + adversarial_grasps(rng, n_contacts=4)
    for positions, normals in cases:
        positions, normals = np.asarray(positions, float), np.asarray(normals, float)
        for mu in (MU_PAPER, 0.5):
            for margin in ("optimum", "bound"):
                for use_filter in ("auto", False):
                    fast = check_force_closure(positions, normals, mu, use_filter=use_filter,
                                               margin=margin)
                    slow = general_path(positions, normals, mu, use_filter=use_filter,
                                        margin=margin)
                    for field in ("force_closure", "filtered_out", "margin", "status",
                                  "margin_upper"):
                        a, b = getattr(fast, field), getattr(slow, field)
                        assert type(a) is type(b) and np.array_equal(a, b, equal_nan=True), field
                    assert fast.contact_forces is None and fast.separating_wrench is None
    # The fast path ran (filter off: every size; "auto": from 5 contacts) and decided
    # most of what it was given.
    assert len(decided) > 2 * len(cases)
    assert sum(d is not None for d in decided) > 0.9 * len(decided)


def test_bad_input_gets_the_general_paths_errors():
    positions, normals = ellipsoid_grasps(np.random.default_rng(0), 1, 6)
    positions, normals = positions[0], normals[0]
    bad = normals.copy()
    bad[2] = 0.0
    with pytest.raises(ValueError, match=r"grasp 0, contact 2: normal has zero length"):
        check_force_closure(positions, bad, 0.5)
    far = positions.copy()
    far[4, 1] = np.nan
    with pytest.raises(ValueError, match=r"grasp 0, contact 4: position is not finite"):
        check_force_closure(far, normals, 0.5)
    for mu, what in ((0.0, "must be > 0"), (np.inf, "not finite"), (2e3, "exceeds")):
        with pytest.raises(ValueError, match=what):
            check_force_closure(positions, normals, mu)
    with pytest.raises(ValueError, match="use_filter"):
        check_force_closure(positions, normals, 0.5, use_filter="sometimes")
    with pytest.raises(ValueError, match="margin"):
        check_force_closure(positions, normals, 0.5, margin="best")


def test_other_inputs_take_the_general_path_with_the_same_answer():
    """Lists, float32 and per-contact mu are not the fast path's; answers agree."""
    positions, normals = ellipsoid_grasps(np.random.default_rng(2), 1, 6)
    positions, normals = positions[0], normals[0]
    reference = check_force_closure(positions, normals, 0.5)
    for args in ((positions.tolist(), normals.tolist(), 0.5),
                 (positions.astype(np.float32).astype(float), normals, 0.5),
                 (positions, normals, np.full(6, 0.5)),
                 (np.asfortranarray(positions), normals, np.float64(0.5))):
        other = check_force_closure(*args)
        assert other.status == reference.status
        assert other.force_closure == reference.force_closure


# --- One grasp per call: the batch's verdicts, the filter compiled (issue 21 item 5) ---

FIELDS = ("force_closure", "filtered_out", "status")


def box_grasps(rng, n_grasps, n_contacts):
    return sample_grasps(make_object("box"), n_grasps, n_contacts, rng)


def assert_lone_calls_match_the_batch(positions, normals, mu, **options):
    """Each grasp alone gives the batch's verdict, status and filter flag, and a margin
    within the solvers' accuracy of the batch's. Returns how many were filtered out."""
    batch = check_force_closure(positions, normals, mu, **options)
    for g in range(len(positions)):
        lone = check_force_closure(positions[g], normals[g], mu, **options)
        for field in FIELDS:
            assert getattr(lone, field) == getattr(batch, field)[g], (field, g)
        assert np.isclose(lone.margin, batch.margin[g], rtol=0, atol=MARGIN_ACCURACY,
                          equal_nan=True), g
    return int(np.count_nonzero(batch.filtered_out))


@pytest.fixture
def compiled_calls(monkeypatch):
    """How often the one-grasp path's compiled call decided (not the general path)."""
    counts = {"decided": 0, "general": 0}
    decide = pipeline.decide_one

    def counted(*args):
        decided = decide(*args)
        counts["general" if decided[0] == GENERAL_PATH else "decided"] += 1
        return decided

    monkeypatch.setattr(pipeline, "decide_one", counted)
    return counts


@pytest.mark.parametrize("n_contacts", [2, 3, 4, 5, 6, 8])
@pytest.mark.parametrize("mu", [MU_PAPER, 0.5, 1.5])
def test_one_grasp_per_call_gives_the_batch_results(n_contacts, mu, compiled_calls):
    rng = np.random.default_rng(100 * n_contacts + int(10 * mu))
    for positions, normals in (box_grasps(rng, 150, n_contacts),
                               ellipsoid_grasps(rng, 150, n_contacts)):
        filtered = assert_lone_calls_match_the_batch(positions, normals, mu)
        # The default filters up to 4 contacts (FILTER_PAYS_UP_TO_CONTACTS): those
        # lone calls run it compiled, and it rejects what the batch's rejects.
        if n_contacts > 4:
            assert filtered == 0
        elif mu <= 0.5:
            assert filtered > 0
    # Up to 4 contacts the filtered calls are decided by the compiled call (beyond, the
    # unfiltered path, counted in test_results_equal_the_general_path).
    if n_contacts <= 4:
        assert compiled_calls["decided"] >= 0.9 * 300


@pytest.mark.parametrize("origins", ["seed", "all"])
@pytest.mark.parametrize("n_contacts", [3, 4, 6, 8])
def test_the_filter_asked_for_runs_compiled_with_the_batch_results(origins, n_contacts,
                                                                   compiled_calls):
    rng = np.random.default_rng(7 + n_contacts)
    positions, normals = box_grasps(rng, 120, n_contacts)
    for mu in (0.05, MU_PAPER):
        assert assert_lone_calls_match_the_batch(positions, normals, mu, use_filter=True,
                                                 origins=origins) > 0
    assert compiled_calls["decided"] >= 0.9 * 240


def shared_normal_grasps(rng, n_contacts):
    """Contacts that all share one normal (never force closure), also nearly."""
    positions = rng.normal(size=(n_contacts, 3))
    normal = rng.normal(size=3)
    normals = np.tile(normal / np.linalg.norm(normal), (n_contacts, 1))
    nearly = normals + 1e-9 * rng.normal(size=normals.shape)
    return [(positions, normals), (positions, nearly)]


def doubled_grasps(rng, n_contacts):
    """Each contact of a smaller grasp twice, exactly and 1e-9 apart."""
    positions, normals = ellipsoid_grasps(rng, 1, (n_contacts + 1) // 2)
    p, n = np.repeat(positions[0], 2, axis=0)[:n_contacts], np.repeat(normals[0], 2,
                                                                     axis=0)[:n_contacts]
    return [(p, n), (p + 1e-9 * rng.normal(size=p.shape), n)]


def scaled_grasps(rng, n_contacts):
    """One grasp at extreme scales and far from the origin."""
    positions, normals = ellipsoid_grasps(rng, 1, n_contacts)
    return [(positions[0] * scale + offset, normals[0] * normal_scale)
            for scale, offset, normal_scale in ((1e-300, 0.0, 1.0), (1e300, 0.0, 1e-300),
                                                (1e-6, 1e6, 1e300), (1.0, -3e5, 1.0))]


def near_threshold_mu(positions, normals):
    """Friction coefficients around the boundary of the verdict (margin MARGIN_TOL)."""
    boundary = float(minimum_friction(positions, normals, margin=MARGIN_TOL))
    if not np.isfinite(boundary) or boundary <= 0 or boundary > 100:
        return []
    return [boundary * (1.0 + step) for step in (-1e-6, -1e-9, 1e-9, 1e-6)]


@pytest.mark.parametrize("n_contacts", [3, 4, 6, 8])
def test_one_grasp_per_call_matches_the_batch_on_adversarial_grasps(n_contacts):
    rng = np.random.default_rng(31 + n_contacts)
    cases = (adversarial_grasps(rng, n_contacts) + shared_normal_grasps(rng, n_contacts)
             + doubled_grasps(rng, n_contacts) + scaled_grasps(rng, n_contacts))
    collinear = np.outer(np.linspace(-1, 1, n_contacts), [1.0, 2.0, 3.0])
    cases.append((collinear, rng.normal(size=(n_contacts, 3))))
    for positions, normals in cases:
        positions, normals = np.asarray(positions, float), np.asarray(normals, float)
        for mu in (1e-3, MU_PAPER, 0.5, 1e3):
            assert_lone_calls_match_the_batch(positions[None], normals[None], mu)
    # Near the threshold: friction within 1e-9 and 1e-6 of the verdict's boundary.
    near = 0
    for positions, normals in zip(*box_grasps(rng, 40, n_contacts), strict=True):
        for mu in near_threshold_mu(positions, normals):
            assert_lone_calls_match_the_batch(positions[None], normals[None], mu)
            near += 1
    assert near >= 8


@pytest.mark.parametrize("n_contacts", [3, 4])
def test_lone_filtered_verdicts_agree_with_the_pyramid_reference(n_contacts):
    """The compiled filter is sound and the lone verdicts right, by an independent LP:
    a grasp is force closure where its inscribed pyramids clearly are, and not where
    not even its circumscribed ones are; no rejected grasp's inscribed pyramids are."""
    rng = np.random.default_rng(53 + n_contacts)
    positions, normals = ellipsoid_grasps(rng, 120, n_contacts)
    mu = 3 * MU_PAPER
    rejected = decided = 0
    for g in range(len(positions)):
        lone = check_force_closure(positions[g], normals[g], mu)
        inner = pyramid_margin(positions[g], normals[g], mu, inscribed=True)
        outer = pyramid_margin(positions[g], normals[g], mu, inscribed=False)
        if lone.filtered_out:
            assert inner <= 1e-5, g
            rejected += 1
        if inner > 1e-5:
            assert lone.force_closure, g
            decided += 1
        if outer == 0.0:
            assert not lone.force_closure, g
            decided += 1
    assert rejected > 20 and decided > 60


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_contacts=st.integers(2, MAX_FILTER_CONTACTS),
       exponent=st.integers(-250, 250), mu=st.sampled_from([1e-3, 0.05, MU_PAPER, 0.8, 5.0]),
       all_origins=st.booleans())
def test_compiled_filter_decides_as_the_numpy_filter(seed, n_contacts, exponent, mu,
                                                     all_origins):
    """Same origins, torque sets and span tests: the same decision at any scale."""
    rng = np.random.default_rng(seed)
    positions = (rng.normal(size=(20, n_contacts, 3)) + rng.normal(size=3)) * 10.0 ** exponent
    normals = rng.normal(size=(20, n_contacts, 3))
    normals[:, 0] = np.where(rng.random((20, 1)) < 0.3, normals[:, 1], normals[:, 0])
    grasps = prepare_grasps(positions, normals, mu)
    expected = passes_torque_filter(grasps, "all" if all_origins else "seed")
    sin_half_angle = np.full(n_contacts, mu / np.sqrt(1.0 + mu * mu))
    for g in range(20):
        assert passes_filter(grasps.positions[g], grasps.normals[g], sin_half_angle,
                             all_origins) == expected[g], g
