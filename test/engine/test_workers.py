"""The worker pool without ROS: chunks on worker processes, in order, through shared
memory or the pipe; and what happens when a worker dies, hangs or cannot start.

Faults are made through the pool's seams: ``worker_pids()`` for the signals a user could
send, and ``worker_command`` starting test/engine/faulty_worker.py, the pool's own worker
except on the chunks that hold a chosen grasp id. Every verdict is compared with the
core's (check_force_closure on the same grasps).
"""

from __future__ import annotations

import dataclasses
import os
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from grasp_fc_ros.core import Status, check_force_closure
from grasp_fc_ros.engine import shared_chunk, worker_crew
from grasp_fc_ros.engine.chunking import chunk_size
from grasp_fc_ros.engine.evaluation import evaluate
from grasp_fc_ros.engine.long_jobs import decide_in_chunks
from grasp_fc_ros.engine.pool import (
    PRIORITY_BATCH,
    PRIORITY_INTERACTIVE,
    Cancelled,
    EvaluationPool,
)
from grasp_fc_ros.engine.shared_chunk import SharedChunk
from grasp_fc_ros.engine.worker_crew import answer_bound_s
from grasp_fc_ros.objects import make_object, sample_grasps
from grasp_fc_ros.packed import PackedGrasps, Settings, Verdicts

pytestmark = pytest.mark.timeout(180)

# The exact test's margin depends on which grasps share a solver call, to solver accuracy.
MARGIN_ABS_TOL = 1e-6
MARGIN_REL_TOL = 1e-4
N_GRASPS = 1200
N_FINGERS = 6
MU = 0.5
# 100 six-finger grasps a chunk: 12 chunks.
CHUNK_CONTACTS = 600
# The chunk that holds this grasp id is the faulty worker's target: grasps 500-599.
TARGET_ID = 555
TARGET = slice(500, 600)
# A short silence bound for the hang tests (s); the default is for real chunks.
SHORT_BOUND_S = 0.5
# Bounds on waits in these tests (s): generous for a loaded machine, where a worker's
# start takes a few seconds; they only keep a broken pool from stalling the run.
WAIT_S = 60.0
CLOSE_S = 10.0

FAULTY_WORKER = Path(__file__).with_name("faulty_worker.py")


def faulty(*args: object) -> list[str]:
    """The worker_command of test/engine/faulty_worker.py with ``args``."""
    return [sys.executable, str(FAULTY_WORKER), *map(str, args)]


def packed(positions: np.ndarray, normals: np.ndarray, first_id: int = 0) -> PackedGrasps:
    """Grasps (N, n, 3) as one request, ids first_id.., friction MU everywhere."""
    n_grasps, n_contacts = positions.shape[:2]
    return PackedGrasps(ids=np.arange(first_id, first_id + n_grasps, dtype=np.uint64),
                        counts=np.full(n_grasps, n_contacts), positions=positions.reshape(-1, 3),
                        normals=normals.reshape(-1, 3), mu=np.full(n_grasps * n_contacts, MU))


@pytest.fixture(scope="module")
def grasps():
    """N_GRASPS six-finger box grasps, their request, and the core's verdicts."""
    positions, normals = sample_grasps(make_object("box"), N_GRASPS, N_FINGERS,
                                       np.random.default_rng(13))
    return packed(positions, normals), check_force_closure(positions, normals, MU)


def assert_as_core(verdicts: Verdicts, expected, where=slice(None)) -> None:
    """The verdicts ``where`` are the core's, in order."""
    np.testing.assert_array_equal(verdicts.status[where], expected.status[where])
    np.testing.assert_array_equal(verdicts.force_closure[where], expected.force_closure[where])
    np.testing.assert_allclose(verdicts.margin[where], expected.margin[where],
                               rtol=MARGIN_REL_TOL, atol=MARGIN_ABS_TOL, equal_nan=True)
    assert all(message == "" for message in np.asarray(verdicts.messages)[where])


def assert_as_inline(verdicts: Verdicts, inline: Verdicts) -> None:
    """The verdicts are those of :func:`evaluate` in this process (ids, status, margins
    and messages), in order."""
    np.testing.assert_array_equal(verdicts.ids, inline.ids)
    np.testing.assert_array_equal(verdicts.status, inline.status)
    np.testing.assert_allclose(verdicts.margin, inline.margin, rtol=MARGIN_REL_TOL,
                               atol=MARGIN_ABS_TOL, equal_nan=True)
    assert verdicts.messages == inline.messages


def wait_until(condition, what: str, timeout: float = WAIT_S) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"not within {timeout} s: {what}"
        time.sleep(0.01)


def marked_pid(marker: Path) -> int:
    """The id of the faulty worker that wrote ``marker`` (it is on the target chunk)."""
    wait_until(lambda: marker.exists() and marker.read_text(), "a worker on the target chunk")
    return int(marker.read_text())


def kill_on_target(marker: Path, killed: list[int]) -> Callable[[], bool]:
    """A cancel (or stop) condition that is never true, but SIGKILLs the faulty worker
    on the target chunk the first time it is asked once there is one (appending its
    process id to ``killed``)."""
    def poll() -> bool:
        if not killed and marker.exists() and marker.read_text():
            killed.append(int(marker.read_text()))
            os.kill(killed[0], signal.SIGKILL)
        return False
    return poll


def is_child(pid: int) -> bool:
    """Whether ``pid`` is a child of this process, running or a zombie (not reaped)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return int(stat.rsplit(")", 1)[1].split()[1]) == os.getpid()


@pytest.fixture
def make_pool():
    """Factory: EvaluationPool(...) closed after the test, with its log kept."""
    made = []

    def make(workers: int = 2, **kwargs) -> tuple[EvaluationPool, list[str]]:
        log: list[str] = []
        pool = EvaluationPool(workers, chunk_contacts=kwargs.pop("chunk_contacts",
                                                                CHUNK_CONTACTS),
                              log=log.append, **kwargs)
        made.append(pool)
        return pool, log

    yield make
    for pool in made:
        pool.close()


# --- in order, side by side --------------------------------------------------------------

def test_worker_pool_gives_the_inline_verdicts_in_order(grasps, make_pool):
    request, expected = grasps
    pool, log = make_pool(chunk_contacts=200)  # 36 chunks of 33 grasps or fewer
    pooled, seconds = pool.decide(request, Settings())
    inline, _ = evaluate(request, Settings())
    assert_as_inline(pooled, inline)
    assert_as_core(pooled, expected)
    assert seconds["exact_s"] > 0
    assert log == [] and pool.worker_restarts == 0


def test_started_requests_are_decided_side_by_side_and_collected_in_any_order(grasps,
                                                                            make_pool):
    request, _ = grasps
    first, second = request.slice(0, 80), request.slice(80, 120)
    tiny = first.slice(0, 2)  # decided inline, at start
    pool, _ = make_pool(workers=1, chunk_contacts=120)  # 20 grasps a chunk, one worker
    decisions = [pool.start(part, Settings()) for part in (first, second, tiny)]
    assert decisions[2].done()  # inline: decided before start returned
    results = [decision.result()[0] for decision in reversed(decisions)][::-1]
    assert all(decision.done() for decision in decisions)
    for part, got in zip((first, second, tiny), results, strict=True):
        inline, _ = evaluate(part, Settings())
        np.testing.assert_array_equal(got.ids, inline.ids)
        np.testing.assert_array_equal(got.status, inline.status)


@pytest.mark.parametrize("total, workers, expected", [
    (6000, 2, 3000),     # 1,000 6-finger grasps: two equal chunks, not 4096 + 1904
    (10_000, 2, 3334),   # three chunks within the bound, as equal as possible
    (100_000, 2, 4000),  # 25 chunks
    (1500, 2, 1500),     # splitting would leave chunks under MIN_CHUNK_CONTACTS
    (2048, 2, 1024),
    (6000, 0, 3000),     # no workers: the bound alone
    (0, 2, 1),
])
def test_chunks_are_balanced_over_the_workers(total, workers, expected):
    assert chunk_size(total, workers, 4096) == expected


def test_a_request_is_spread_over_the_workers_only_when_no_chunks_wait(grasps, make_pool):
    request, _ = grasps
    small = request.slice(0, 400)  # 2,400 contacts: two chunks on an idle pool
    pool, _ = make_pool(workers=2, chunk_contacts=4096)
    assert pool.start(small, Settings()).chunks == 2
    # Behind queued chunks (a client's large batch comes in parts) it stays whole.
    ahead = [pool.start(request, Settings()) for _ in range(4)]  # 8 chunks of 600 grasps
    behind = pool.start(small, Settings())
    assert behind.chunks == 1
    verdicts, _ = behind.result()
    np.testing.assert_array_equal(verdicts.status, evaluate(small, Settings())[0].status)
    for decision in ahead:
        decision.result()


def sent_messages(monkeypatch) -> list[int]:
    """Record how many chunks each message to a worker holds."""
    sizes: list[int] = []
    write = worker_crew.write_message

    def record(stream, message):
        if isinstance(message, tuple):
            sizes.append(len(message[1]))
        write(stream, message)

    monkeypatch.setattr(worker_crew, "write_message", record)
    return sizes


def test_small_requests_queued_together_go_in_one_message_each_with_its_own_verdicts(
        grasps, make_pool, monkeypatch):
    """Requests smaller than a chunk (a client's batch parts) queued behind each other
    reach a worker several to a message, up to a chunk's contacts; each keeps its own
    verdicts and messages (an invalid grasp named by its place in its own request)."""
    request, _ = grasps
    sizes = sent_messages(monkeypatch)
    # 600 contacts each, each a message of its own (first_index 0), as a batch's parts.
    parts = [dataclasses.replace(request.slice(k, k + 100), first_index=0)
             for k in range(0, N_GRASPS, 100)]
    parts[5] = dataclasses.replace(parts[5], normals=parts[5].normals.copy())
    parts[5].normals[3] = 0.0  # grasp 0 of part 5: a zero normal at its contact 3
    pool, log = make_pool(workers=1, chunk_contacts=1800)  # up to 3 parts a message
    decisions = [pool.start(part, Settings()) for part in parts]
    for part, decision in zip(parts, decisions, strict=True):
        got, _ = decision.result()
        assert_as_inline(got, evaluate(part, Settings())[0])
    assert decisions[5].result()[0].messages[0].startswith("grasp 0 (id 500), contact 3: ")
    assert sum(sizes) == len(parts) and max(sizes) == 3 and len(sizes) < len(parts)
    assert log == []


def test_interactive_and_slow_chunks_are_not_sent_with_batch_chunks(grasps, make_pool,
                                                                    monkeypatch):
    request, _ = grasps
    sizes = sent_messages(monkeypatch)
    pool, _ = make_pool(workers=1, chunk_contacts=1800)
    blocker = pool.start(request, Settings())  # 4 full chunks: the worker is busy
    epsilon = Settings(compute_epsilon=True)
    decisions = [pool.start(request.slice(300, 320), epsilon) for _ in range(2)]
    decisions += [pool.start(request.slice(320, 340), Settings(), priority)
                  for priority in (PRIORITY_BATCH, PRIORITY_INTERACTIVE)]
    for decision in [blocker, *decisions]:
        decision.result()
    # The blocker's chunks, each epsilon chunk alone, the two others alone.
    assert sizes == [1] * 8


# --- a worker that dies ------------------------------------------------------------------

@pytest.mark.parametrize("how", ["start", "decide"])
def test_a_worker_killed_mid_chunk_costs_no_grasp(grasps, make_pool, tmp_path, how):
    """SIGKILL of the worker deciding a chunk: the chunk is decided again, every verdict
    is the core's, and the killed worker is reaped and replaced."""
    request, expected = grasps
    marker = tmp_path / "on_target"
    pool, log = make_pool(worker_command=faulty("--pause-on", TARGET_ID, "--once", marker))
    killed: list[int] = []
    if how == "start":
        decision = pool.start(request, Settings())
        killed.append(marked_pid(marker))
        os.kill(killed[0], signal.SIGKILL)
        verdicts, _ = decision.result()
    else:  # killed from the caller's cancel poll, while decide() waits
        verdicts, _ = pool.decide(request, Settings(), cancelled=kill_on_target(marker, killed))
    assert_as_core(verdicts, expected)
    np.testing.assert_array_equal(verdicts.ids, request.ids)
    assert log == [f"worker process {killed[0]} was killed by SIGKILL deciding a chunk; "
                   "its chunk (grasps 500-599) is decided again"]
    assert pool.worker_restarts == 1 and not is_child(killed[0])
    wait_until(lambda: len(pool.worker_pids()) == 2, "a replacement worker")
    assert killed[0] not in pool.worker_pids()


def test_a_job_chunk_whose_worker_is_killed_is_decided_again(grasps, make_pool, tmp_path):
    """The same through submit(), as the label_grasps action's long jobs use it."""
    request, expected = grasps
    marker = tmp_path / "on_target"
    pool, log = make_pool(worker_command=faulty("--pause-on", TARGET_ID, "--once", marker))
    killed: list[int] = []
    outcome = decide_in_chunks(pool, request, Settings(), stop=kill_on_target(marker, killed),
                               report=lambda _: None)
    assert killed, "the target chunk was never decided"
    assert outcome.complete
    assert_as_core(outcome.verdicts, expected)
    assert len(log) == 1 and f"worker process {killed[0]} was killed by SIGKILL" in log[0]
    assert pool.worker_restarts == 1 and not is_child(killed[0])


def test_a_chunk_that_kills_its_workers_fails_alone_with_the_reason(grasps, make_pool):
    request, expected = grasps
    pool, log = make_pool(worker_command=faulty("--die-on", TARGET_ID))
    verdicts, _ = pool.decide(request, Settings())
    assert (verdicts.status[TARGET] == Status.SOLVER_FAILURE).all()
    message = verdicts.messages[TARGET.start]
    assert verdicts.messages[TARGET] == [message] * 100
    assert message.startswith("worker process died twice deciding this chunk "
                              "(grasps 500-599): worker process ")
    assert message.count("exited with code 3 deciding a chunk") == 2
    others = np.r_[0:TARGET.start, TARGET.stop:N_GRASPS]
    assert_as_core(verdicts, expected, others)
    assert log[-1] == message and pool.worker_restarts == 2
    # Both workers were replaced: the next request is decided as usual.
    again, _ = pool.decide(request.slice(0, 300), Settings())
    assert_as_core(again, expected, slice(0, 300))


def test_a_worker_killed_on_a_message_of_several_chunks_costs_only_the_killers_grasps(
        grasps, make_pool):
    """A worker dies on a message of several requests' chunks: each is decided again
    alone; the one that kills workers fails after two deaths of its own, the others get
    the core's verdicts."""
    request, expected = grasps
    pool, log = make_pool(workers=1, chunk_contacts=1800,
                          worker_command=faulty("--die-on", TARGET_ID))
    parts = [request.slice(k, k + 100) for k in range(0, N_GRASPS, 100)]
    decisions = [pool.start(part, Settings()) for part in parts]
    verdicts = Verdicts.concatenate([decision.result()[0] for decision in decisions])
    assert (verdicts.status[TARGET] == Status.SOLVER_FAILURE).all()
    assert verdicts.messages[TARGET.start].startswith(
        "worker process died twice deciding this chunk (grasps 500-599): ")
    others = np.r_[0:TARGET.start, TARGET.stop:N_GRASPS]
    assert_as_core(verdicts, expected, others)
    together = [line for line in log if "are decided again, each alone" in line]
    assert len(together) == 1 and "grasps 500-599" in together[0]
    assert pool.worker_restarts == 3


def test_a_job_chunk_that_kills_its_workers_fails_alone(grasps, make_pool):
    request, expected = grasps
    pool, _ = make_pool(worker_command=faulty("--die-on", TARGET_ID))
    outcome = decide_in_chunks(pool, request, Settings(), stop=lambda: False,
                               report=lambda _: None)
    assert outcome.complete and len(outcome.verdicts) == N_GRASPS
    failed = outcome.verdicts.status == Status.SOLVER_FAILURE
    assert failed[TARGET_ID] and failed.sum() < N_GRASPS // 2  # its chunk only
    assert all(outcome.verdicts.messages[i].startswith("worker process died twice")
               for i in np.flatnonzero(failed))
    assert_as_core(outcome.verdicts, expected, ~failed)


def test_a_log_that_raises_does_not_stop_the_pool(grasps):
    request, expected = grasps

    def broken_log(message: str) -> None:
        raise RuntimeError("log is broken")

    pool = EvaluationPool(2, chunk_contacts=CHUNK_CONTACTS, log=broken_log,
                          worker_command=faulty("--die-on", TARGET_ID))
    try:
        verdicts, _ = pool.decide(request, Settings())
        assert (verdicts.status[TARGET] == Status.SOLVER_FAILURE).all()
        assert_as_core(verdicts, expected, np.r_[0:TARGET.start, TARGET.stop:N_GRASPS])
        wait_until(lambda: len(pool.worker_pids()) == 2, "both workers replaced")
    finally:
        pool.close()


# --- a worker that hangs -----------------------------------------------------------------

def test_a_stopped_worker_is_killed_after_the_bound_and_its_chunk_decided_again(
        grasps, make_pool, tmp_path):
    request, expected = grasps
    marker = tmp_path / "on_target"
    pool, log = make_pool(worker_timeout_s=SHORT_BOUND_S,
                          worker_command=faulty("--stop-on", TARGET_ID, "--once", marker))
    began = time.monotonic()
    verdicts, _ = pool.decide(request, Settings())
    took = time.monotonic() - began
    assert_as_core(verdicts, expected)
    stopped = int(marker.read_text())
    bound = answer_bound_s(request.slice(*TARGET.indices(N_GRASPS)[:2]), Settings(),
                           SHORT_BOUND_S)
    assert log == [f"worker process {stopped} did not answer within {bound:.3g} s deciding a "
                   "chunk and was killed; its chunk (grasps 500-599) is decided again"]
    assert not is_child(stopped)  # killed and reaped: no zombie
    assert took < SHORT_BOUND_S + WAIT_S / 2


def test_a_chunk_that_hangs_its_workers_fails_alone_after_two_bounds(grasps, make_pool):
    request, expected = grasps
    pool, _ = make_pool(worker_timeout_s=SHORT_BOUND_S,
                        worker_command=faulty("--stop-on", TARGET_ID))
    verdicts, _ = pool.decide(request, Settings())
    assert (verdicts.status[TARGET] == Status.SOLVER_FAILURE).all()
    message = verdicts.messages[TARGET.start]
    assert message.startswith("worker process died twice deciding this chunk (grasps "
                              "500-599)")
    assert message.count("deciding a chunk and was killed") == 2
    assert_as_core(verdicts, expected, np.r_[0:TARGET.start, TARGET.stop:N_GRASPS])


# --- closing with faults -----------------------------------------------------------------

def test_the_pool_closes_cleanly_with_a_stopped_and_a_killed_worker(grasps, make_pool,
                                                                     tmp_path):
    request, _ = grasps
    marker = tmp_path / "on_target"
    pool, _ = make_pool(worker_command=faulty("--stop-on", TARGET_ID, "--once", marker))
    decision = pool.start(request, Settings())
    stopped = marked_pid(marker)  # stopped itself on the target chunk
    (other,) = set(pool.worker_pids()) - {stopped}
    os.kill(other, signal.SIGKILL)
    began = time.monotonic()
    pool.close()
    assert time.monotonic() - began < CLOSE_S
    with pytest.raises(Cancelled, match="closed"):
        decision.result()
    assert pool.worker_pids() == []
    assert not is_child(stopped) and not is_child(other)


# --- workers that cannot start ----------------------------------------------------------

@pytest.fixture
def quick_backoff(monkeypatch):
    """Starts retried after 0.05 s, doubling up to 0.2 s (the defaults are for a node)."""
    monkeypatch.setattr(worker_crew, "START_BACKOFF_S", 0.05)
    monkeypatch.setattr(worker_crew, "START_BACKOFF_MAX_S", 0.2)


def test_the_start_delay_doubles_from_the_first_to_the_largest():
    delays = [worker_crew.start_delay_s(failed) for failed in range(1, 10)]
    assert delays[0] == worker_crew.START_BACKOFF_S
    assert all(b == min(2 * a, worker_crew.START_BACKOFF_MAX_S)
               for a, b in zip(delays, delays[1:], strict=False))
    assert delays[-1] == worker_crew.START_BACKOFF_MAX_S


@pytest.mark.parametrize("command, reason", [
    ([sys.executable, "-c", "raise SystemExit(7)"], "exited with code 7 while starting"),
    (["/nonexistent/python3"], "cannot run /nonexistent/python3"),
])
def test_workers_that_cannot_start_are_tried_again_and_chunks_decided_here_meanwhile(
        grasps, make_pool, quick_backoff, command, reason):
    request, expected = grasps
    pool, log = make_pool(worker_command=command)
    counts = pool.worker_counts()
    assert (counts["workers_configured"], counts["workers_alive"]) == (2, 0)
    verdicts, _ = pool.decide(request, Settings())
    assert_as_core(verdicts, expected)
    # Never given up: each slot keeps trying, logged at its 1st, 2nd, 4th... failure.
    wait_until(lambda: pool.worker_restarts >= 10, "ten failed starts")
    for index in (0, 1):
        mine = [line for line in log if line.startswith(f"worker {index}: ")]
        assert reason in mine[0] and mine[0].endswith(
            "; 1 failed start(s) in a row); trying again in 0.05 s, meanwhile chunks are "
            "decided in this process")
        assert "; 2 failed start(s) in a row); trying again in 0.1 s" in mine[1]
    assert all("no worker process could be started" in line and reason in line
               for line in log)
    assert len(log) < pool.worker_restarts  # not every failure is logged
    assert pool.worker_counts()["workers_alive"] == 0


def test_a_worker_that_cannot_be_replaced_for_a_while_is_back_once_starts_work(
        grasps, make_pool, tmp_path, quick_backoff):
    request, expected = grasps
    no_start = tmp_path / "no_start"
    pool, log = make_pool(worker_command=faulty("--no-start", no_start))
    first, second = pool.worker_pids()
    no_start.touch()  # from now on, worker processes exit as they start
    os.kill(first, signal.SIGKILL)
    wait_until(lambda: any("no worker process could be started" in line for line in log),
               "a failed start")
    assert log[-1].endswith("exited with code 4 while starting; 1 failed start(s) in a "
                            "row); trying again in 0.05 s, meanwhile its chunks go to the "
                            "1 running worker(s)")
    assert pool.worker_counts()["workers_alive"] == 1
    verdicts, _ = pool.decide(request, Settings())
    assert_as_core(verdicts, expected)
    # The other slot keeps starting processes that exit at once: one may be seen.
    assert second in pool.worker_pids() and pool.worker_counts()["workers_alive"] == 1
    os.kill(second, signal.SIGKILL)  # none left: this process decides
    wait_until(lambda: pool.worker_counts()["workers_alive"] == 0, "no worker running")
    verdicts, _ = pool.decide(request, Settings())
    assert_as_core(verdicts, expected)
    no_start.unlink()  # starts work again: both slots are back
    wait_until(lambda: pool.worker_counts()["workers_alive"] == 2, "both workers back")
    assert any(line.endswith("failed start(s)") and "started after" in line for line in log)
    verdicts, _ = pool.decide(request, Settings())
    assert_as_core(verdicts, expected)
    assert first not in pool.worker_pids() and second not in pool.worker_pids()


def test_workers_killed_while_starting_are_all_counted_and_replaced(grasps, make_pool,
                                                                    quick_backoff):
    """An operator kills a worker, then every replacement as soon as it appears (while
    it imports, before it is ready): each kill is a restart, the pool keeps starting
    workers, decides every chunk meanwhile, and runs all its workers once the kills end."""
    request, expected = grasps
    pool, log = make_pool()
    kills = 0
    answer = pool.start(request, Settings())
    seen = set(pool.worker_pids())
    os.kill(next(iter(seen)), signal.SIGKILL)
    kills += 1
    deadline = time.monotonic() + WAIT_S
    while kills < 6:
        assert time.monotonic() < deadline, f"only {kills} kills within {WAIT_S} s"
        for pid in set(pool.worker_pids()) - seen:
            seen.add(pid)
            os.kill(pid, signal.SIGKILL)  # a replacement, while it starts
            kills += 1
        time.sleep(0.005)
    assert_as_core(answer.result()[0], expected)
    wait_until(lambda: pool.worker_counts()["workers_alive"] == 2, "both workers back")
    assert pool.worker_restarts == kills
    assert sum("killed by SIGKILL while starting" in line for line in log) >= 1
    verdicts, _ = pool.decide(request, Settings())
    assert_as_core(verdicts, expected)


# --- what a worker prints, and a broken channel -------------------------------------------

def test_what_a_worker_prints_on_its_stdout_never_reaches_the_pool(grasps, make_pool,
                                                                  capfd):
    """Its library output (Fast DDS prints errors on file descriptor 1) goes to this
    process's output; the messages travel on a channel of their own."""
    request, expected = grasps
    pool, log = make_pool(worker_command=faulty("--chatter"))
    verdicts, _ = pool.decide(request, Settings())
    assert_as_core(verdicts, expected)
    assert log == [] and pool.worker_restarts == 0
    assert "[XMLPARSER Error]" in capfd.readouterr().out


def test_a_broken_channel_is_reported_with_its_bytes_and_the_worker_replaced(
        grasps, make_pool, tmp_path):
    request, expected = grasps
    marker = tmp_path / "on_target"
    pool, log = make_pool(worker_command=faulty("--garble-on", TARGET_ID, "--once", marker))
    verdicts, _ = pool.decide(request, Settings())
    assert_as_core(verdicts, expected)
    garbled = int(marker.read_text())
    assert len(log) == 1 and log[0].startswith(
        f"worker process {garbled} broke its stream deciding a chunk (FramingError(")
    assert "no message header where one should start: b'this is no message header" in log[0]
    assert log[0].endswith("its chunk (grasps 500-599) is decided again")
    assert pool.worker_restarts == 1 and not is_child(garbled)
    wait_until(lambda: pool.worker_counts()["workers_alive"] == 2, "a replacement worker")


# --- chunks in shared memory -------------------------------------------------------------

@settings(max_examples=60, deadline=None)
@given(counts=st.lists(st.integers(0, 7), max_size=12), soft=st.booleans(),
       name_by_id=st.booleans(), first_index=st.integers(0, 10**6), seed=st.integers(0, 99))
def test_a_shared_chunk_reads_back_what_was_put(counts, soft, name_by_id, first_index, seed):
    rng = np.random.default_rng(seed)
    k = sum(counts)
    chunk = PackedGrasps(
        ids=rng.integers(0, 2**63, len(counts)).astype(np.uint64) + 2**63,
        counts=np.array(counts, np.int64), positions=rng.normal(size=(k, 3)),
        normals=rng.normal(size=(k, 3)), mu=rng.uniform(-1, 1, k), name_by_id=name_by_id,
        first_index=first_index, torsional=rng.uniform(0, 0.01, k) if soft else None)
    shared = SharedChunk.create()
    try:
        shared.put(PackedGrasps(  # a larger chunk first: nothing of it may show through
            ids=np.arange(40, dtype=np.uint64), counts=np.full(40, 3),
            positions=np.ones((120, 3)), normals=np.ones((120, 3)), mu=np.ones(120),
            torsional=np.ones(120)))
        # Another mapping of the same memory file, as the worker process has.
        reader = SharedChunk(shared.fd)
        got = reader.get(shared.put(chunk))
        for name in ("ids", "counts", "positions", "normals", "mu"):
            np.testing.assert_array_equal(getattr(got, name), getattr(chunk, name))
            assert getattr(got, name).dtype == getattr(chunk, name).dtype
        assert (got.name_by_id, got.first_index) == (name_by_id, first_index)
        if soft:
            np.testing.assert_array_equal(got.torsional, chunk.torsional)
        else:
            assert got.torsional is None
        del got  # views of the memory: it cannot be unmapped while they exist
        reader.memory.close()
    finally:
        shared.close()


def test_a_chunk_too_large_for_the_shared_memory_is_refused():
    positions = np.zeros((1000, 3))
    chunk = PackedGrasps(ids=np.arange(250, dtype=np.uint64), counts=np.full(250, 4),
                         positions=positions, normals=positions, mu=np.zeros(1000))
    shared = SharedChunk.create(16 * 250 + 56 * 1000 - 8)  # 8 bytes short
    try:
        assert shared.put(chunk) is None
    finally:
        shared.close()
    shared = SharedChunk.create(16 * 250 + 56 * 1000)  # exactly enough
    try:
        assert shared.get(shared.put(chunk)).ids.tolist() == chunk.ids.tolist()
    finally:
        shared.close()


def test_chunks_that_do_not_fit_go_through_the_pipe_with_the_same_verdicts(grasps,
                                                                          make_pool,
                                                                          monkeypatch):
    """With shared memory too small for any chunk, every chunk is pickled through the
    pipe, and the verdicts are those decided inline."""
    request, _ = grasps
    request = request.slice(0, 60)
    monkeypatch.setattr(shared_chunk, "SHARED_BYTES", 64)
    sent = []
    put = SharedChunk.put
    monkeypatch.setattr(SharedChunk, "put",
                        lambda self, chunk, at=0: sent.append(put(self, chunk, at)) or sent[-1])
    pool, _ = make_pool(chunk_contacts=60)  # 10 grasps a chunk
    got, _ = pool.decide(request, Settings())
    assert sent and all(layout is None for layout in sent)  # one put a message
    want, _ = evaluate(request, Settings())
    np.testing.assert_array_equal(got.ids, want.ids)
    np.testing.assert_array_equal(got.status, want.status)
    np.testing.assert_array_equal(got.margin, want.margin)
