"""A small pool of worker processes deciding chunks of packed grasps (no ROS).

The core is CPU-bound Python and numpy, and the GIL lets one process use about one
core. :class:`EvaluationPool` splits a large :class:`~.packed.PackedGrasps` into chunks
(:mod:`.chunking`), decides them in worker processes (:mod:`.worker`) and puts the
verdicts back together in order; :meth:`~EvaluationPool.start` queues a request's chunks
and returns at once (a :class:`Decision`), so that a caller can queue the next request
before this one is collected. Requests of at most :data:`INLINE_GRASPS` grasps are
decided in the calling thread: no waiting for a worker busy with a batch chunk.
Everything larger goes to the workers, so the core never holds the caller's GIL for long.
A chunk's arrays reach its worker through memory shared with it
(:class:`~.shared_chunk.SharedChunk`), only their sizes and the settings through the pipe.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from concurrent.futures import CancelledError, Future
from concurrent.futures import TimeoutError as FutureTimeout

from grasp_fc_ros.engine.chunking import (
    CHUNK_CONTACTS,
    INLINE_ASSESSMENT_SAMPLES,
    SOFT_CHUNK_DIVISOR,
    assessment_chunk_contacts,
    assessment_samples,
    chunk_size,
)
from grasp_fc_ros.engine.evaluation import evaluate
from grasp_fc_ros.engine.worker_crew import (
    START_TIMEOUT_S,
    WARM_EPSILON_FLAG,
    WORKER_COMMAND,
    WORKER_TIMEOUT_S,
    WorkerCrew,
)
from grasp_fc_ros.packed import PackedGrasps, Settings, Verdicts

# Requests up to this many grasps are decided inline (one core call; tuned:
# docs/performance.md#service-latency): a service call or a trickle of single queries
# does not wait behind batch chunks.
INLINE_GRASPS = 4
# How often a waiting caller looks at its cancel condition (s).
POLL_S = 0.02
# Chunk priorities: lower first. Service requests overtake queued batch chunks.
PRIORITY_INTERACTIVE = 0
PRIORITY_BATCH = 1

_log = logging.getLogger(__name__)


class Cancelled(Exception):
    """The caller's cancel condition became true while its chunks were being decided, or
    the pool was closed."""


class Decision:
    """One request being decided: its chunks' futures, or its verdicts if decided inline.

    Made by :meth:`EvaluationPool.start`; :meth:`result` waits for the verdicts.
    """

    def __init__(self, futures: list[Future], ready: tuple[Verdicts, dict] | None = None):
        self._futures = futures
        self._ready = ready

    @property
    def chunks(self) -> int:
        """How many chunks the request went to the workers in (0: decided inline)."""
        return len(self._futures)

    def done(self) -> bool:
        """Whether every chunk has been decided (or dropped): :meth:`result` would not
        wait."""
        return all(future.done() for future in self._futures)

    def result(self, cancelled: Callable[[], bool] = lambda: False) -> tuple[Verdicts, dict]:
        """The verdicts, in order, and the seconds per stage summed over the chunks.

        Every grasp has a verdict: a chunk on which worker processes died twice has
        SOLVER_FAILURE verdicts saying so (see :class:`EvaluationPool`), the others
        theirs.

        Raises
        ------
        Cancelled
            If ``cancelled()`` became true before all chunks were decided (the chunks
            not decided yet are dropped), or the pool was closed meanwhile.
        """
        if self._ready is not None:
            return self._ready
        try:
            parts: list[Verdicts] = []
            seconds: dict[str, float] = {}
            for future in self._futures:
                verdicts, chunk_seconds = self._wait(future, cancelled)
                parts.append(verdicts)
                for key, value in chunk_seconds.items():
                    seconds[key] = seconds.get(key, 0.0) + value
            return Verdicts.concatenate(parts), seconds
        finally:
            for future in self._futures:
                future.cancel()

    @staticmethod
    def _wait(future: Future, cancelled: Callable[[], bool]) -> tuple[Verdicts, dict]:
        while True:
            if cancelled():
                raise Cancelled()
            try:
                return future.result(POLL_S)
            except FutureTimeout:
                continue
            except CancelledError:
                raise Cancelled("the pool was closed") from None


class EvaluationPool:
    """Decide packed grasps, large ones in chunks on ``workers`` processes.

    A worker that dies while deciding a chunk, or does not answer it within its bound
    (``worker_timeout_s`` plus a time per contact:
    :func:`~.worker_crew.answer_bound_s`; it is then killed), is replaced, and the chunk
    is decided again by the next free worker. Only a chunk on which workers die twice
    is not: its grasps get SOLVER_FAILURE verdicts saying so, the rest of the request
    its own. A worker that cannot be started leaves its chunks to the others; with no
    worker left, chunks are decided in this process. See :mod:`.worker_crew`.

    Parameters
    ----------
    workers : int
        Number of worker processes; 0 decides everything in the calling thread.
    chunk_contacts : int
        Largest number of contacts sent to a worker at once.
    worker_timeout_s : float
        Least time a worker may take to answer a chunk before it counts as hung (s).
    start_timeout_s : float
        Longest a worker may take to start (imports, loading or compiling the core's
        kernels) before it counts as failed (s).
    worker_command : sequence of str, optional
        The command that starts a worker process, to which the pool appends a file
        descriptor (default :data:`~.worker_crew.WORKER_COMMAND`,
        ``python -m grasp_fc_ros.engine.worker``). A seam: fault tests start workers
        that die on chosen chunks; a deployment may wrap the command (``nice``).
    log : callable (str) -> None, optional
        Told of every worker that dies, hangs or cannot start and what became of its
        chunk (default: this module's :mod:`logging` logger, as warnings).
    warm_epsilon : bool
        Workers also warm the epsilon kernels before they are ready (a cold compilation
        counts against ``start_timeout_s``); otherwise each worker's first chunk with
        ``compute_epsilon`` does, with the start-up time allowed on top of its bound.
    """

    def __init__(self, workers: int, chunk_contacts: int = CHUNK_CONTACTS, *,
                 worker_timeout_s: float = WORKER_TIMEOUT_S,
                 start_timeout_s: float = START_TIMEOUT_S,
                 worker_command: Sequence[str] | None = None,
                 log: Callable[[str], None] | None = None, warm_epsilon: bool = False):
        self.workers = workers
        self.worker_timeout_s = worker_timeout_s
        self._chunk_contacts = chunk_contacts
        command = tuple(WORKER_COMMAND if worker_command is None else worker_command)
        if warm_epsilon:
            command += (WARM_EPSILON_FLAG,)
        # A worker is sent the chunks queued behind its next one in the same message, up
        # to a chunk's contacts in all: a client's large batch comes in parts smaller
        # than a chunk, each a request (docs/performance.md#worker-messages).
        self._crew = WorkerCrew(workers, command, worker_timeout_s, start_timeout_s,
                                _log.warning if log is None else log,
                                message_contacts=chunk_contacts) if workers else None

    def decide(self, packed: PackedGrasps, settings: Settings,
               cancelled: Callable[[], bool] = lambda: False,
               priority: int = PRIORITY_BATCH) -> tuple[Verdicts, dict]:
        """Verdicts for every grasp of ``packed``, in order, and the seconds per stage.

        Raises
        ------
        Cancelled
            If ``cancelled()`` was true at the start or became true before all chunks
            were decided (the chunks not started yet are dropped).
        """
        if cancelled():
            raise Cancelled()
        return self.start(packed, settings, priority).result(cancelled)

    def start(self, packed: PackedGrasps, settings: Settings,
              priority: int = PRIORITY_BATCH) -> Decision:
        """Queue the chunks of ``packed`` for the workers and return at once.

        A caller can start the next request while this one's chunks are decided, so
        that the workers never wait for it between requests. Requests of at most
        :data:`INLINE_GRASPS` grasps (assess_robustness requests: of at most
        :data:`~.chunking.INLINE_ASSESSMENT_SAMPLES` samples), or with no workers, are
        decided here, before returning.
        """
        query = settings.robustness
        if self._crew is None or (
                len(packed) <= INLINE_GRASPS if query is None
                else assessment_samples(len(packed), query.samples) <= INLINE_ASSESSMENT_SAMPLES):
            return Decision([], evaluate(packed, settings))
        if query is not None:
            return Decision([self._crew.submit(chunk, settings, priority) for chunk in
                             packed.chunks(assessment_chunk_contacts(
                                 len(packed), int(packed.counts.max()), query.samples,
                                 self.workers))])
        # Soft grasps take the exact test's Clarabel path, many times a hard grasp's cost
        # (tuned: docs/performance.md#worker-chunks): smaller chunks keep one chunk's delay
        # as short.
        limit = (self._chunk_contacts if packed.torsional is None
                 else max(1, self._chunk_contacts // SOFT_CHUNK_DIVISOR))
        # Split a small request across the workers only while fewer chunks than workers
        # wait: behind a queue (a client's large batch comes in parts, each a request)
        # the workers are kept busy anyway, and each chunk costs the node and its worker
        # a fixed share (tuned: docs/performance.md#worker-chunks).
        spread = max(0, self.workers - self._crew.queued())
        size = chunk_size(int(packed.counts.sum()), spread, limit)
        return Decision([self._crew.submit(chunk, settings, priority)
                         for chunk in packed.chunks(size)])

    @property
    def chunk_contacts(self) -> int:
        """Largest number of contacts :meth:`decide` sends to a worker at once."""
        return self._chunk_contacts

    def submit(self, chunk: PackedGrasps, settings: Settings,
               priority: int = PRIORITY_BATCH) -> Future:
        """Queue ``chunk`` for a worker, whole; a Future of its (verdicts, seconds).

        For callers that pace their own chunks (the ``label_grasps`` action). Without
        workers the chunk is decided at once in the calling thread (the Future is done
        on return; an exception of the core is its exception). A chunk on which workers
        die twice gets SOLVER_FAILURE verdicts saying so, as with :meth:`start`; the
        Future is cancelled if the pool closes first.
        """
        if self._crew is not None:
            return self._crew.submit(chunk, settings, priority)
        future: Future = Future()
        future.set_running_or_notify_cancel()
        try:
            future.set_result(evaluate(chunk, settings))
        except Exception as exc:  # noqa: BLE001 - reported through the Future
            future.set_exception(exc)
        return future

    def worker_pids(self) -> list[int]:
        """Process ids of the worker processes running now (for monitoring and fault
        tests); empty without workers."""
        return [] if self._crew is None else self._crew.pids()

    @property
    def worker_restarts(self) -> int:
        """Worker processes that died or were killed as hung since the pool started."""
        return 0 if self._crew is None else self._crew.restarts

    def close(self) -> None:
        """Stop the workers at once: chunks in progress are abandoned, and the requests
        still waiting for chunks get :class:`Cancelled`."""
        if self._crew is not None:
            self._crew.close()
            self._crew = None
