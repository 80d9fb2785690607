"""Deciding a long job chunk by chunk, with progress reports and a prompt stop (no ROS).

The ``label_grasps`` action of the node decides its goal with :func:`decide_in_chunks`:
the grasps go to the :class:`~grasp_fc_ros.engine.pool.EvaluationPool` a few chunks at a
time (so that other goals and batches share the workers), the decided chunks are kept
in order, a progress report goes out at least every ``report_period_s`` even while a
chunk is still being decided, and a stop request is seen within :data:`STOP_POLL_S`.
On a stop the verdicts decided so far come back:
a prefix of the job, in order; chunks still being decided are abandoned.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass, field

import numpy as np

from grasp_fc_ros.core import Status
from grasp_fc_ros.engine.chunking import adapted_chunk_contacts
from grasp_fc_ros.engine.pool import PRIORITY_BATCH, EvaluationPool
from grasp_fc_ros.packed import PackedGrasps, Settings, Verdicts, chunk_end

# How often a job waiting for a chunk looks at its stop condition (s): this wait is most
# of a cancel's latency, hence shorter than the pool's POLL_S, and a few hundred wake-ups
# a second cost next to nothing (tuned: docs/performance.md#action).
STOP_POLL_S = 0.005
# Progress reports at most this often (s): 4 Hz, well above the 1 Hz the action
# promises, and a negligible cost next to a chunk's work.
REPORT_PERIOD_S = 0.25
# Chunks of one job queued at once per worker: one being decided and one waiting, so a
# worker never idles between two chunks of the job, while a second job's (or a batch's)
# chunks can slip in between.
CHUNKS_PER_WORKER = 2

N_STATUSES = len(Status)


@dataclass(frozen=True)
class Progress:
    """How far a job is.

    Attributes
    ----------
    done, total : int
        Grasps decided so far, out of ``total``.
    grasps_per_second : float
        ``done`` over the seconds since the job started (0 at the start).
    counts : (len(Status),) int64 array
        Decided grasps per :class:`~grasp_fc_ros.core.Status` code.
    """

    done: int
    total: int
    grasps_per_second: float
    counts: np.ndarray


@dataclass
class Outcome:
    """What a job decided.

    Attributes
    ----------
    verdicts : Verdicts
        The decided grasps, in order: all of them when ``complete``, else a prefix.
    seconds : dict
        Time per stage summed over the decided chunks (``validation_s``, ...).
    complete : bool
        False when the job was stopped before every grasp was decided.
    """

    verdicts: Verdicts
    seconds: dict = field(default_factory=dict)
    complete: bool = True


class _Tally:
    """Decided chunks so far, their status counts, and when to report next."""

    def __init__(self, total: int, report: Callable[[Progress], None], period_s: float):
        self.parts: list[Verdicts] = []
        self.seconds: dict = {}
        self.done = 0
        self.counts = np.zeros(N_STATUSES, np.int64)
        self._total, self._report, self._period_s = total, report, period_s
        self._start = time.monotonic()
        self._last_report = -math.inf

    def add(self, verdicts: Verdicts, seconds: dict) -> None:
        self.parts.append(verdicts)
        self.done += len(verdicts)
        self.counts += np.bincount(verdicts.status, minlength=N_STATUSES)[:N_STATUSES]
        for key, value in seconds.items():
            self.seconds[key] = self.seconds.get(key, 0.0) + value

    def report_if_due(self) -> None:
        now = time.monotonic()
        if now - self._last_report < self._period_s:
            return
        self._last_report = now
        elapsed = now - self._start
        self._report(Progress(done=self.done, total=self._total,
                              grasps_per_second=self.done / elapsed if elapsed > 0 else 0.0,
                              counts=self.counts.copy()))

    def outcome(self, complete: bool, ids: np.ndarray) -> Outcome:
        verdicts = (Verdicts.concatenate(self.parts) if self.parts
                    else Verdicts.failed(ids[:0], Status.INVALID_INPUT, ""))
        return Outcome(verdicts=verdicts, seconds=self.seconds, complete=complete)


def _chunk_result(future: Future, chunk: PackedGrasps, settings: Settings
                  ) -> tuple[Verdicts, dict]:
    """A finished chunk's verdicts. The pool answers even a chunk its workers died on
    (with SOLVER_FAILURE verdicts); a Future's exception (the core raising in a pool
    without workers) fails this chunk only, its certificates NaN."""
    try:
        return future.result()
    except Exception as exc:  # noqa: BLE001 - the rest of the job goes on
        return Verdicts.failed_grasps(chunk, settings, Status.SOLVER_FAILURE,
                                      f"internal error: {exc}"), {}


def decide_in_chunks(pool: EvaluationPool, packed: PackedGrasps, settings: Settings,
                     stop: Callable[[], bool], report: Callable[[Progress], None],
                     priority: int = PRIORITY_BATCH,
                     report_period_s: float = REPORT_PERIOD_S) -> Outcome:
    """Decide ``packed`` in chunks on ``pool``; report progress; stop when asked.

    Parameters
    ----------
    pool : EvaluationPool
        Decides the chunks (in the calling thread when it has no workers).
    packed : PackedGrasps
        The job: N grasps, any mix of contact counts.
    settings : Settings
        One snapshot for the whole job.
    stop : callable () -> bool
        Polled every :data:`STOP_POLL_S` while waiting for a worker, and between
        chunks; True ends the job early.
    report : callable (Progress) -> None
        Called at the start and then at least every ``report_period_s`` (at most that
        often) while the job runs, in the calling thread.
    priority : int
        Of the chunks in the pool's queue.

    Returns
    -------
    Outcome
        The verdicts of the chunks decided before the stop (all of them if none came),
        in the job's order; chunks finished by then but not yet collected are included.
    """
    ends = np.cumsum(packed.counts)
    # Without workers each chunk is decided on submission: one at a time, stop seen between.
    window = CHUNKS_PER_WORKER * pool.workers if pool.workers else 1
    upper = pool.chunk_contacts
    chunk_contacts = upper
    tally = _Tally(len(packed), report, report_period_s)
    in_flight: deque[tuple[PackedGrasps, Future]] = deque()
    first = 0
    stopped = False
    try:
        while True:
            if stop():
                stopped = True
                break
            while len(in_flight) < window and first < len(packed):
                last = chunk_end(ends, first, chunk_contacts)
                chunk = packed.slice(first, last)
                in_flight.append((chunk, pool.submit(chunk, settings, priority)))
                first = last
            tally.report_if_due()
            if not in_flight:
                break
            chunk, future = in_flight[0]
            try:
                future.result(STOP_POLL_S)
            except FutureTimeout:
                continue
            except Exception:  # noqa: BLE001 - handled by _chunk_result
                pass
            in_flight.popleft()
            verdicts, seconds = _chunk_result(future, chunk, settings)
            tally.add(verdicts, seconds)
            compute_s = sum(seconds.values())
            chunk_contacts = adapted_chunk_contacts(int(chunk.counts.sum()), compute_s, upper)
        # Chunks that finished while the stop came in are decided: keep them (in order).
        while in_flight and in_flight[0][1].done():
            chunk, future = in_flight.popleft()
            tally.add(*_chunk_result(future, chunk, settings))
    finally:
        for _, future in in_flight:
            future.cancel()
    return tally.outcome(complete=not stopped or tally.done == len(packed), ids=packed.ids)
