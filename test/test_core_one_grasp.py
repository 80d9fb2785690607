"""The one-grasp fast path of check_force_closure: same input to the exact stage, same
results as the general path, same errors."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from grasp_cases import MU_PAPER, adversarial_grasps, ellipsoid_grasps
from grasp_fc_ros.core import check_force_closure, pipeline
from grasp_fc_ros.core.certificates import normalise_positions
from grasp_fc_ros.core.grasp_input import prepare_grasps
from grasp_fc_ros.core.one_grasp import _prepare_one


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
