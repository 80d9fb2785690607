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

import itertools
import os
import queue
import subprocess
import sys
import threading
from collections.abc import Callable
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout

from grasp_fc_ros.engine.child_process import ONE_THREAD_ENV, read_message, write_message
from grasp_fc_ros.engine.chunking import CHUNK_CONTACTS, SOFT_CHUNK_DIVISOR, chunk_size
from grasp_fc_ros.engine.evaluation import evaluate
from grasp_fc_ros.engine.packed import PackedGrasps, Settings, Verdicts
from grasp_fc_ros.engine.shared_chunk import PICKLED, SHARED, SharedChunk

# Requests up to this many grasps are decided inline (one core call, ~0.1-0.2 ms): a
# service call or a trickle of single queries does not wait behind batch chunks.
INLINE_GRASPS = 4
# How often a waiting caller looks at its cancel condition (s).
POLL_S = 0.02
# Chunk priorities: lower first. Service requests overtake queued batch chunks.
PRIORITY_INTERACTIVE = 0
PRIORITY_BATCH = 1


class Cancelled(Exception):
    """The caller's cancel condition became true while its chunks were being decided."""


class _Worker:
    """One worker process and the thread that feeds it chunks from the shared queue."""

    def __init__(self, tasks: queue.PriorityQueue, closing: threading.Event, index: int):
        self._tasks = tasks
        self._closing = closing
        self.shared = SharedChunk.create()
        self.process = self._start()
        self.thread = threading.Thread(target=self._feed, daemon=True,
                                       name=f"grasp_fc_worker_{index}")
        self.thread.start()

    def _start(self) -> subprocess.Popen:
        """A new worker process, once it says it has imported the core (a pool is ready
        when its constructor returns, and the first chunks do not wait for imports)."""
        process = subprocess.Popen(
            [sys.executable, "-m", "grasp_fc_ros.engine.worker", str(self.shared.fd)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, pass_fds=(self.shared.fd,),
            env={**os.environ, **ONE_THREAD_ENV})
        read_message(process.stdout)
        return process

    def _feed(self):
        while True:
            _, _, task = self._tasks.get()
            if task is None:
                return  # the pool is closing
            future, chunk, settings = task
            if not future.set_running_or_notify_cancel():
                continue
            try:
                layout = self.shared.put(chunk)
                write_message(self.process.stdin, (SHARED, layout, settings) if layout is not None
                       else (PICKLED, chunk, settings))
                ok, answer = read_message(self.process.stdout)
            except Exception as exc:  # noqa: BLE001 - the worker died: fail this chunk only
                future.set_exception(RuntimeError(f"worker process failed: {exc!r}"))
                if self._closing.is_set():
                    return
                if self.process.poll() is None:
                    self.process.kill()
                self.process = self._start()
                continue
            if ok:
                future.set_result(answer)
            else:
                future.set_exception(RuntimeError(answer))




class Decision:
    """One request being decided: its chunks' futures, or its verdicts if decided inline.

    Made by :meth:`EvaluationPool.start`; :meth:`result` waits for the verdicts.
    """

    def __init__(self, futures: list[Future], ready: tuple[Verdicts, dict] | None = None):
        self._futures = futures
        self._ready = ready

    def result(self, cancelled: Callable[[], bool] = lambda: False) -> tuple[Verdicts, dict]:
        """The verdicts, in order, and the seconds per stage summed over the chunks.

        Raises
        ------
        Cancelled
            If ``cancelled()`` became true before all chunks were decided (the chunks
            not started yet are dropped).
        RuntimeError
            If a worker failed on a chunk.
        """
        if self._ready is not None:
            return self._ready
        try:
            parts, seconds = [], {}
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
    def _wait(future: Future, cancelled: Callable[[], bool]):
        while True:
            if cancelled():
                raise Cancelled()
            try:
                return future.result(POLL_S)
            except FutureTimeout:
                continue


class EvaluationPool:
    """Decide packed grasps, large ones in chunks on ``workers`` processes.

    Parameters
    ----------
    workers : int
        Number of worker processes; 0 decides everything in the calling thread.
    chunk_contacts : int
        Largest number of contacts sent to a worker at once.
    """

    def __init__(self, workers: int, chunk_contacts: int = CHUNK_CONTACTS):
        self.workers = workers
        self._chunk_contacts = chunk_contacts
        self._tasks: queue.PriorityQueue = queue.PriorityQueue()
        self._order = itertools.count()
        self._closing = threading.Event()
        self._workers = [_Worker(self._tasks, self._closing, i) for i in range(workers)]

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
        :data:`INLINE_GRASPS` grasps (or with no workers) are decided here, before
        returning.
        """
        if not self._workers or len(packed) <= INLINE_GRASPS:
            return Decision([], evaluate(packed, settings))
        futures = []
        # Soft grasps take the exact test's Clarabel path, ~15-60x a hard grasp's cost
        # (benchmarks/bench_soft.py): smaller chunks keep one chunk's delay as short.
        limit = (self._chunk_contacts if packed.torsional is None
                 else max(1, self._chunk_contacts // SOFT_CHUNK_DIVISOR))
        size = chunk_size(int(packed.counts.sum()), len(self._workers), limit)
        for chunk in packed.chunks(size):
            future: Future = Future()
            self._tasks.put((priority, next(self._order), (future, chunk, settings)))
            futures.append(future)
        return Decision(futures)

    @property
    def chunk_contacts(self) -> int:
        """Largest number of contacts :meth:`decide` sends to a worker at once."""
        return self._chunk_contacts

    def submit(self, chunk: PackedGrasps, settings: Settings,
               priority: int = PRIORITY_BATCH) -> Future:
        """Queue ``chunk`` for a worker, whole; a Future of its (verdicts, seconds).

        For callers that pace their own chunks (the ``label_grasps`` action). Without
        workers the chunk is decided at once in the calling thread (the Future is done
        on return). A worker failure sets the Future's exception (RuntimeError).
        """
        future: Future = Future()
        if not self._workers:
            future.set_running_or_notify_cancel()
            try:
                future.set_result(evaluate(chunk, settings))
            except Exception as exc:  # noqa: BLE001 - reported through the Future
                future.set_exception(exc)
            return future
        self._tasks.put((priority, next(self._order), (future, chunk, settings)))
        return future

    def close(self):
        """Stop the workers at once (a chunk in progress is abandoned)."""
        self._closing.set()
        for worker in self._workers:
            self._tasks.put((-1, next(self._order), None))
        for worker in self._workers:
            worker.process.kill()
            worker.process.wait()
        for worker in self._workers:
            worker.thread.join(timeout=1.0)
            if not worker.thread.is_alive():
                worker.shared.close()
        self._workers = []

