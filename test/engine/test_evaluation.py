"""grasp_fc_ros.engine.evaluation without ROS: packed grasps in, verdicts out, structured
validation errors, requests cut into chunks. The worker pool: test_workers.py."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from grasp_fc_ros.core import Status, check_force_closure
from grasp_fc_ros.core.model.grasp_input import show_value
from grasp_fc_ros.engine.evaluation import InvalidGrasp, evaluate, find_invalid
from grasp_fc_ros.objects import make_object, sample_grasps
from grasp_fc_ros.packed import PackedGrasps, Settings, Verdicts

# The exact test's margin depends on which grasps share a solver call, to solver accuracy.
MARGIN_ABS_TOL = 1e-6
MARGIN_REL_TOL = 1e-4


def pack(grasp_list, mu=None, **kwargs) -> PackedGrasps:
    """PackedGrasps of [(positions (n, 3), normals (n, 3)), ...]; mu per contact or 0."""
    counts = np.array([len(p) for p, _ in grasp_list], dtype=np.int64)
    positions = np.concatenate([p for p, _ in grasp_list]).reshape(-1, 3)
    normals = np.concatenate([n for _, n in grasp_list]).reshape(-1, 3)
    mu = np.zeros(len(positions)) if mu is None else np.asarray(mu, dtype=float)
    ids = kwargs.pop("ids", np.arange(len(counts), dtype=np.uint64) + 100)
    return PackedGrasps(ids=np.asarray(ids, np.uint64), counts=counts, positions=positions,
                        normals=normals, mu=mu, **kwargs)


@pytest.fixture(scope="module")
def mixed():
    """40 grasps of 3 to 8 contacts on the torus, and their sizes."""
    rng = np.random.default_rng(11)
    sizes = rng.choice([3, 4, 6, 8], size=40)
    torus = make_object("torus")
    return [tuple(a[0] for a in sample_grasps(torus, 1, int(n), rng)) for n in sizes]


def assert_same_as_core(verdicts: Verdicts, grasp_list, mu):
    for i, (p, n) in enumerate(grasp_list):
        expected = check_force_closure(p, n, mu)
        assert verdicts.status[i] == expected.status, f"grasp {i}"
        assert verdicts.force_closure[i] == expected.force_closure
        assert verdicts.margin[i] == pytest.approx(float(expected.margin), rel=MARGIN_REL_TOL,
                                                  abs=MARGIN_ABS_TOL, nan_ok=True)


def test_mixed_contact_counts_match_the_core_in_order(mixed):
    verdicts, seconds = evaluate(pack(mixed), Settings(friction_coefficient=0.7))
    np.testing.assert_array_equal(verdicts.ids, np.arange(40) + 100)
    assert_same_as_core(verdicts, mixed, 0.7)
    assert set(seconds) >= {"validation_s", "filter_s", "exact_s"}
    assert {Status.FORCE_CLOSURE, Status.FILTERED_OUT} <= set(verdicts.status.tolist())


@pytest.mark.parametrize("use_filter", [True, False])
def test_a_lone_grasp_gets_the_verdict_it_gets_in_a_batch(mixed, use_filter, monkeypatch):
    import grasp_fc_ros.core.pipeline as pipeline

    lone_calls = []
    real_check_one = pipeline.check_one
    monkeypatch.setattr(pipeline, "check_one",
                        lambda *args: lone_calls.append(1) or real_check_one(*args))
    settings_ = Settings(friction_coefficient=0.7, use_filter=use_filter)
    together, _ = evaluate(pack(mixed), settings_)
    for i, grasp in enumerate(mixed):
        alone, _ = evaluate(pack([grasp], ids=[100 + i]), settings_)
        assert alone.status[0] == together.status[i], f"grasp {i}"
        assert alone.force_closure[0] == together.force_closure[i]
        assert alone.margin[0] == pytest.approx(together.margin[i], rel=MARGIN_REL_TOL,
                                                abs=MARGIN_ABS_TOL, nan_ok=True)
    # Lone grasps the filter does not run on take the core's one-grasp compiled path
    # (without the filter: all of them; with it, "auto" filters n <= 4 only).
    assert len(lone_calls) == (len(mixed) if not use_filter
                               else sum(len(p) > 4 for p, _ in mixed))


def test_a_lone_grasp_with_mixed_friction_or_certificates_takes_the_batch_path(mixed,
                                                                                monkeypatch):
    import grasp_fc_ros.core.pipeline as pipeline

    monkeypatch.setattr(pipeline, "check_one", lambda *args: pytest.fail("one-grasp path"))
    grasp = next(g for g in mixed if len(g[0]) == 6)
    mu = np.linspace(0.5, 0.9, 6)
    alone, _ = evaluate(pack([grasp], mu=mu), Settings(use_filter=False))
    expected = check_force_closure(*grasp, mu, use_filter=False)
    assert alone.status[0] == expected.status
    certified, _ = evaluate(pack([grasp]), Settings(certificates=True, use_filter=False))
    assert certified.separating_wrench.shape == (1, 6)


def test_invalid_grasps_are_structured_and_spare_the_others(mixed):
    grasps = [(p.copy(), n.copy()) for p, n in mixed[:6]]
    grasps[1][0][2, 0] = np.nan
    grasps[3][1][1] = 0.0
    grasps[4] = (grasps[4][0][:1], grasps[4][1][:1])
    mu = np.zeros(sum(len(p) for p, _ in grasps))
    mu[sum(len(p) for p, _ in grasps[:5]) + 2] = np.inf  # grasp 5, contact 2
    packed = pack(grasps, mu)
    settings_ = Settings()
    friction = np.where(mu == 0, settings_.friction_coefficient, mu)
    problems = find_invalid(packed, friction, settings_)
    assert problems == [
        InvalidGrasp(1, 2, f"position is not finite, got {show_value(grasps[1][0][2])}"),
        InvalidGrasp(3, 1, "normal has zero length, got (0, 0, 0)"),
        InvalidGrasp(4, None, "1 contacts; a grasp needs 2 to max_contacts=64"),
        InvalidGrasp(5, 2, "friction coefficient is not finite, got inf"),
    ]
    verdicts, _ = evaluate(packed, settings_)
    assert verdicts.messages[1] == ("grasp 1 (id 101), contact 2: position is not finite, "
                                    f"got {show_value(grasps[1][0][2])}")
    assert verdicts.messages[4] == ("grasp 4 (id 104): 1 contacts; a grasp needs 2 to "
                                    "max_contacts=64")
    assert (verdicts.status[[1, 3, 4, 5]] == Status.INVALID_INPUT).all()
    good = [0, 2]
    assert all(verdicts.messages[i] == "" for i in good)
    assert_same_as_core(Verdicts(*(a[good] for a in (verdicts.ids, verdicts.force_closure,
                                                     verdicts.status, verdicts.margin)),
                                 messages=[]), [grasps[i] for i in good], 0.5)


@pytest.mark.parametrize("spoil, message", [
    (lambda p, n, mu: p.__setitem__((2, 0), np.nan),
     lambda p, n, mu: f"contact 2: position is not finite, got {show_value(p[2])}"),
    (lambda p, n, mu: n.__setitem__(1, 0.0),
     lambda p, n, mu: "contact 1: normal has zero length, got (0, 0, 0)"),
    (lambda p, n, mu: mu.fill(np.inf),
     lambda p, n, mu: "contact 0: friction coefficient is not finite, got inf"),
    (lambda p, n, mu: mu.__setitem__(4, -0.25),
     lambda p, n, mu: ("contact 4: friction coefficient must be > 0, got -0.25 (0 uses the "
                       "node's friction_coefficient, 0.5)")),
])
def test_a_lone_invalid_grasp_is_named_like_one_in_a_batch(mixed, spoil, message):
    p, n = (a.copy() for a in next(g for g in mixed if len(g[0]) == 6))
    mu = np.zeros(6)
    spoil(p, n, mu)
    verdicts, _ = evaluate(pack([(p, n)], mu, name_by_id=True, ids=[7]), Settings())
    assert verdicts.status[0] == Status.INVALID_INPUT
    assert verdicts.messages == [f"query id 7, {message(p, n, mu)}"]


def test_a_lone_grasp_whose_core_call_fails_gets_solver_failure(mixed, monkeypatch):
    from grasp_fc_ros.engine import evaluation

    def explodes(*args, **kwargs):
        raise RuntimeError("solver exploded")

    monkeypatch.setattr(evaluation, "check_force_closure", explodes)
    verdicts, _ = evaluate(pack(mixed[:1]), Settings())
    assert verdicts.status[0] == Status.SOLVER_FAILURE
    assert verdicts.messages == ["internal error: solver exploded"]


def test_single_queries_are_named_by_id_and_chunks_by_batch_index(mixed):
    grasps = [(p.copy(), n.copy()) for p, n in mixed[:3]]
    grasps[2][1][0] = 0.0
    by_id = evaluate(pack(grasps, name_by_id=True, ids=[7, 8, 9]), Settings())[0]
    assert by_id.messages[2] == "query id 9, contact 0: normal has zero length, got (0, 0, 0)"
    chunk = evaluate(pack(grasps, first_index=50), Settings())[0]
    assert chunk.messages[2] == ("grasp 52 (id 102), contact 0: normal has zero length, "
                                 "got (0, 0, 0)")


def test_max_contacts_and_max_batch_are_applied(mixed):
    sizes = [len(p) for p, _ in mixed[:10]]
    tight = Settings(max_contacts=4)
    verdicts, _ = evaluate(pack(mixed[:10]), tight)
    for i, n in enumerate(sizes):
        assert (verdicts.status[i] == Status.INVALID_INPUT) == (n > 4)
    whole, _ = evaluate(pack(mixed[:10]), Settings(max_batch=9))
    assert (whole.status == Status.INVALID_INPUT).all()
    assert whole.messages[0] == "10 grasps exceed max_batch=9"


def test_a_failing_core_group_fails_only_that_group(mixed, monkeypatch):
    from grasp_fc_ros.engine import evaluation

    real = evaluation.check_force_closure

    def fails_on_four(positions, *args, **kwargs):
        if positions.shape[1] == 4:
            raise RuntimeError("solver exploded")
        return real(positions, *args, **kwargs)

    monkeypatch.setattr(evaluation, "check_force_closure", fails_on_four)
    verdicts, _ = evaluate(pack(mixed), Settings())
    for i, (p, _) in enumerate(mixed):
        failed = verdicts.status[i] == Status.SOLVER_FAILURE
        assert failed == (len(p) == 4)
        assert ("solver exploded" in verdicts.messages[i]) == failed


@pytest.fixture(scope="module")
def six_finger():
    """30 six-finger grasps on the box."""
    grasps = sample_grasps(make_object("box"), 30, 6, np.random.default_rng(5))
    return list(zip(*grasps, strict=True))


@pytest.mark.parametrize("extras", [{}, {"certificates": True}, {"compute_min_friction": True}])
def test_one_size_batches_skip_the_general_path_and_decide_as_it_does(six_finger, extras,
                                                                     monkeypatch):
    from grasp_fc_ros.engine import evaluation

    settings_ = Settings(friction_coefficient=0.6, **extras)
    # A grasp of another size sends the same 30 grasps down the general path.
    odd_p, odd_n = sample_grasps(make_object("box"), 1, 4, np.random.default_rng(6))
    general, _ = evaluate(pack(six_finger + [(odd_p[0], odd_n[0])]), settings_)
    monkeypatch.setattr(evaluation, "find_invalid",
                        lambda *args: pytest.fail("general path taken"))
    one_size, seconds = evaluate(pack(six_finger), settings_)
    assert seconds["validation_s"] == 0.0  # validated inside the core call
    np.testing.assert_array_equal(one_size.status, general.status[:30])
    np.testing.assert_array_equal(one_size.force_closure, general.force_closure[:30])
    np.testing.assert_allclose(one_size.margin, general.margin[:30], rtol=MARGIN_REL_TOL,
                               atol=MARGIN_ABS_TOL)
    assert_same_as_core(one_size, six_finger, 0.6)
    for name in ("contact_forces", "separating_wrench", "min_friction"):
        ours, theirs = getattr(one_size, name), getattr(general, name)
        assert (ours is None) == (theirs is None), name
        if ours is not None:
            np.testing.assert_allclose(ours, theirs[:len(ours)], rtol=1e-6, atol=1e-9,
                                       err_msg=name)


def test_an_invalid_grasp_in_a_one_size_batch_is_named_and_spares_the_others(six_finger):
    grasps = [(p.copy(), n.copy()) for p, n in six_finger[:8]]
    grasps[5][1][3] = 0.0
    verdicts, _ = evaluate(pack(grasps), Settings())
    assert verdicts.status[5] == Status.INVALID_INPUT
    assert verdicts.messages[5] == ("grasp 5 (id 105), contact 3: normal has zero length, "
                                    "got (0, 0, 0)")
    good = [i for i in range(8) if i != 5]
    assert all(verdicts.messages[i] == "" for i in good)
    assert_same_as_core(Verdicts(*(a[good] for a in (verdicts.ids, verdicts.force_closure,
                                                     verdicts.status, verdicts.margin)),
                                 messages=[]), [grasps[i] for i in good], 0.5)


def test_a_failing_core_call_fails_a_one_size_batch_with_the_reason(six_finger, monkeypatch):
    from grasp_fc_ros.engine import evaluation

    def explodes(*args, **kwargs):
        raise RuntimeError("solver exploded")

    monkeypatch.setattr(evaluation, "check_force_closure", explodes)
    verdicts, _ = evaluate(pack(six_finger[:5]), Settings())
    assert (verdicts.status == Status.SOLVER_FAILURE).all()
    assert verdicts.messages == ["internal error: solver exploded"] * 5


@settings(max_examples=30, deadline=None)
@given(sizes=st.lists(st.integers(1, 9), min_size=0, max_size=30),
       bound=st.integers(1, 40))
def test_chunks_partition_the_grasps_in_order(sizes, bound):
    counts = np.array(sizes, dtype=np.int64)
    total = int(counts.sum())
    packed = PackedGrasps(ids=np.arange(len(sizes), dtype=np.uint64), counts=counts,
                          positions=np.arange(3 * total, dtype=float).reshape(total, 3),
                          normals=np.zeros((total, 3)), mu=np.arange(total, dtype=float))
    chunks = packed.chunks(bound)
    assert [c.first_index for c in chunks] == list(np.cumsum([0] + [len(c) for c in chunks])[:-1])
    np.testing.assert_array_equal(np.concatenate([c.ids for c in chunks] or [[]]), packed.ids)
    np.testing.assert_array_equal(np.concatenate([c.mu for c in chunks] or [[]]), packed.mu)
    for c in chunks:
        # A chunk holds at most `bound` contacts, unless it is a single larger grasp.
        assert c.counts.sum() <= bound or len(c) == 1
        assert len(c.positions) == c.counts.sum()
