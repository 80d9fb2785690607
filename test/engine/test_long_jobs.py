"""grasp_fc_ros.engine.long_jobs: chunked decisions with progress and stop, without ROS.

The verdicts are checked against grasp_fc_ros.engine.evaluation.evaluate on the same grasps
(whole jobs and stopped prefixes); the pacing (reports while a chunk hangs, a stop seen
while one hangs, a failed chunk failing alone) against a pool whose chunks the test
finishes by hand. Its order of events is asserted, not its timing.
"""

from __future__ import annotations

import threading
import time
from concurrent.futures import Future

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from grasp_fc_ros.core import Status
from grasp_fc_ros.engine.chunking import (
    MIN_CHUNK_CONTACTS,
    TARGET_CHUNK_S,
    adapted_chunk_contacts,
)
from grasp_fc_ros.engine.evaluation import evaluate
from grasp_fc_ros.engine.long_jobs import decide_in_chunks
from grasp_fc_ros.engine.pool import EvaluationPool
from grasp_fc_ros.objects import make_object, sample_grasps
from grasp_fc_ros.packed import PackedGrasps, Settings, chunk_end

# Bound on waits for a job's thread (s): generous, since a loaded machine runs it late;
# a wait that succeeds returns at once.
WAIT_S = 60.0


def packed_grasps(n_grasps: int, seed: int = 0, mixed: bool = False) -> PackedGrasps:
    """Random grasps on a box; with ``mixed`` 3 to 7 contacts each, else 6."""
    rng = np.random.default_rng(seed)
    counts = rng.integers(3, 8, n_grasps) if mixed else np.full(n_grasps, 6)
    positions, normals = [], []
    for n in counts:
        p, q = sample_grasps(make_object("box"), 1, int(n), rng)
        positions.append(p[0])
        normals.append(q[0])
    positions, normals = np.concatenate(positions), np.concatenate(normals)
    return PackedGrasps(ids=np.arange(1000, 1000 + n_grasps, dtype=np.uint64),
                        counts=counts.astype(np.int64), positions=positions,
                        normals=normals, mu=np.zeros(len(positions)))


def assert_same_verdicts(got, expected):
    np.testing.assert_array_equal(got.ids, expected.ids)
    np.testing.assert_array_equal(got.status, expected.status)
    np.testing.assert_array_equal(got.force_closure, expected.force_closure)
    np.testing.assert_allclose(got.margin, expected.margin, rtol=1e-6, atol=1e-9)
    assert got.messages == expected.messages


@pytest.fixture(scope="module")
def job():
    return packed_grasps(300, seed=1, mixed=True)


@pytest.fixture(scope="module")
def expected(job):
    return evaluate(job, Settings())[0]


class SmallPool(EvaluationPool):
    """The in-thread pool with a small chunk size, so that a job has many chunks."""

    def __init__(self, chunk_contacts: int = 200):
        super().__init__(0, chunk_contacts)


def test_a_whole_job_equals_evaluate_and_reports_progress(job, expected):
    reports = []
    outcome = decide_in_chunks(SmallPool(), job, Settings(), lambda: False, reports.append,
                               report_period_s=0.0)
    assert outcome.complete
    assert_same_verdicts(outcome.verdicts, expected)
    assert set(outcome.seconds) >= {"validation_s", "exact_s"}
    assert reports[0].done == 0 and all(r.total == len(job) for r in reports)
    done = [r.done for r in reports]
    assert done == sorted(done) and len(set(done)) > 3  # several chunks, in order
    for r in reports:
        assert r.counts.sum() == r.done and r.grasps_per_second >= 0


def test_a_stopped_job_returns_the_decided_prefix(job, expected):
    reports = []
    outcome = decide_in_chunks(SmallPool(), job, Settings(),
                               stop=lambda: len(reports) >= 3, report=reports.append,
                               report_period_s=0.0)
    assert not outcome.complete
    n = len(outcome.verdicts)
    assert 0 < n < len(job) and n >= reports[-1].done
    prefix = evaluate(job.slice(0, n), Settings())[0]
    assert_same_verdicts(outcome.verdicts, prefix)
    np.testing.assert_array_equal(outcome.verdicts.status, expected.status[:n])


def test_a_stop_before_the_start_decides_nothing(job):
    outcome = decide_in_chunks(SmallPool(), job, Settings(), lambda: True, lambda _: None)
    assert len(outcome.verdicts) == 0 and not outcome.complete
    assert outcome.verdicts.ids.dtype == np.uint64


def test_an_empty_job_is_complete():
    empty = packed_grasps(1).slice(0, 0)
    outcome = decide_in_chunks(SmallPool(), empty, Settings(), lambda: False, lambda _: None)
    assert outcome.complete and len(outcome.verdicts) == 0


class HandPool:
    """A pool with one 'worker' whose chunks the test finishes (or fails) by hand."""

    workers = 1
    chunk_contacts = 60

    def __init__(self):
        self.submitted: list[tuple[PackedGrasps, Future]] = []
        self.lock = threading.Lock()

    def submit(self, chunk, settings, priority):
        future = Future()
        with self.lock:
            self.submitted.append((chunk, future))
            self.settings = settings
        return future

    def finish(self, index: int, fail: bool = False):
        chunk, future = self.submitted[index]
        future.set_running_or_notify_cancel()
        if fail:
            future.set_exception(RuntimeError("worker process failed: test"))
        else:
            future.set_result(evaluate(chunk, self.settings))


def wait_until(condition, what: str) -> None:
    """Wait for ``condition()``, for up to WAIT_S (a loaded machine runs threads late)."""
    deadline = time.monotonic() + WAIT_S
    while not condition():
        assert time.monotonic() < deadline, f"not within {WAIT_S} s: {what}"
        time.sleep(0.01)


def test_reports_keep_coming_and_a_stop_is_seen_while_a_chunk_hangs():
    job = packed_grasps(40, seed=2)
    pool = HandPool()
    reports, stop = [], threading.Event()
    result = {}
    thread = threading.Thread(target=lambda: result.update(outcome=decide_in_chunks(
        pool, job, Settings(), stop.is_set, reports.append, report_period_s=0.05)))
    thread.start()
    # The first chunk never finishes by itself: reports come all the same.
    wait_until(lambda: len(reports) >= 6, "six reports while the first chunk hangs")
    assert len(pool.submitted) == 2  # one chunk per worker waiting behind the first
    assert all(r.done == 0 for r in reports)
    pool.finish(0)
    pool.finish(1)
    decided = len(pool.submitted[0][0]) + len(pool.submitted[1][0])
    wait_until(lambda: reports[-1].done == decided, "both chunks collected")
    stop.set()  # chunk 2 hangs: only a stop seen while waiting for it ends the job
    thread.join(timeout=WAIT_S)
    assert not thread.is_alive(), "the stop was not seen while a chunk hung"
    outcome = result["outcome"]
    assert not outcome.complete
    # Chunks 0 and 1 were decided; chunk 2 was still waiting and was cancelled.
    assert len(outcome.verdicts) == decided
    assert pool.submitted[2][1].cancelled()
    assert reports[-1].done == decided


@pytest.mark.parametrize("chosen", [Settings(), Settings(certificates=True,
                                                         compute_min_friction=True)],
                         ids=["plain", "certificates"])
def test_a_failed_chunk_fails_alone(chosen):
    job = packed_grasps(30, seed=3)
    pool = HandPool()
    result = {}
    thread = threading.Thread(target=lambda: result.update(outcome=decide_in_chunks(
        pool, job, chosen, lambda: False, lambda _: None)))
    thread.start()
    deadline = time.monotonic() + WAIT_S
    finished = 0
    while thread.is_alive() and time.monotonic() < deadline:
        with pool.lock:
            submitted = len(pool.submitted)
        for index in range(finished, submitted):
            pool.finish(index, fail=index == 1)
        finished = submitted
        time.sleep(0.01)
    thread.join(timeout=WAIT_S)
    outcome = result["outcome"]
    assert outcome.complete and len(outcome.verdicts) == len(job)
    failed = pool.submitted[1][0]
    lo = int(failed.first_index)
    hi = lo + len(failed)
    assert np.all(outcome.verdicts.status[lo:hi] == Status.SOLVER_FAILURE)
    assert all("worker process failed" in m for m in outcome.verdicts.messages[lo:hi])
    expected = evaluate(job, chosen)[0]
    others = np.r_[0:lo, hi:len(job)]
    np.testing.assert_array_equal(outcome.verdicts.status[others], expected.status[others])
    if not chosen.certificates:
        return
    # The other chunks keep their certificates; the failed one's are NaN.
    got = outcome.verdicts
    for per_grasp in (got.separating_wrench, got.min_friction):
        assert per_grasp is not None and len(per_grasp) == len(job)
        assert np.isnan(per_grasp[lo:hi]).all()
    np.testing.assert_array_equal(got.separating_wrench[others],
                                  expected.separating_wrench[others])
    np.testing.assert_array_equal(got.min_friction[others], expected.min_friction[others])
    rows = np.arange(job.starts[lo], job.starts[hi - 1] + job.counts[hi - 1])
    assert got.contact_forces.shape == expected.contact_forces.shape
    assert np.isnan(got.contact_forces[rows]).all()
    kept = np.setdiff1d(np.arange(len(job.positions)), rows)
    np.testing.assert_array_equal(got.contact_forces[kept], expected.contact_forces[kept])


@settings(max_examples=60, deadline=None)
@given(counts=st.lists(st.integers(1, 40), min_size=1, max_size=30),
       first_frac=st.floats(0, 1, exclude_max=True), budget=st.integers(1, 200))
def test_chunk_end_takes_at_most_the_budget_and_at_least_one_grasp(counts, first_frac, budget):
    ends = np.cumsum(counts)
    first = int(first_frac * len(counts))
    last = chunk_end(ends, first, budget)
    assert first < last <= len(counts)
    taken = sum(counts[first:last])
    assert taken <= budget or last == first + 1
    if last < len(counts):
        assert taken + counts[last] > budget  # as large as the budget allows


def test_chunks_shrink_when_slow_and_never_exceed_the_pool_chunk():
    upper = 4096
    assert adapted_chunk_contacts(4096, TARGET_CHUNK_S / 10, upper) == upper
    assert adapted_chunk_contacts(4096, 2 * TARGET_CHUNK_S, upper) == 2048
    assert adapted_chunk_contacts(4096, 1e6, upper) == MIN_CHUNK_CONTACTS
    assert adapted_chunk_contacts(4096, 0.0, upper) == upper  # nothing measured
    assert adapted_chunk_contacts(100, 1.0, 50) == 50  # the pool's bound wins
