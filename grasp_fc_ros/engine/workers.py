"""A small pool of worker processes deciding chunks of packed grasps (no ROS).

The core is CPU-bound Python and numpy, and the GIL lets one process use about one
core. :class:`EvaluationPool` splits a large :class:`~grasp_fc_ros.engine.evaluation.PackedGrasps`
into chunks, decides them in worker processes with :func:`~grasp_fc_ros.engine.evaluation.evaluate`
and puts the verdicts back together in order; :meth:`~EvaluationPool.start` queues a
request's chunks and returns at once (a :class:`Decision`), so that a caller can queue
the next request before this one is collected. Requests of at most
:data:`INLINE_GRASPS` grasps are decided in the calling thread: a few milliseconds of
GIL, and no waiting for a worker busy with a batch chunk. Everything larger goes to the
workers, so the core never holds the node's GIL for long.

Each worker is a fresh interpreter, ``python -m grasp_fc_ros.engine.workers FD``, answering on
its stdout the chunks announced on its stdin: a chunk's arrays are in memory shared
with it (:class:`SharedChunk`, the memory file FD), only their sizes and the settings go
through the pipe. Not multiprocessing: its spawn and
forkserver methods re-run the parent's ``__main__`` script in every worker (which breaks
any unguarded script embedding the node), and fork would copy the ROS process's DDS
threads. A worker ignores SIGINT (Ctrl-C reaches the whole process group; its owner
decides) and ends when its stdin closes, so a SIGKILL of the node leaves no workers.
"""

from __future__ import annotations

import itertools
import mmap
import os
import pickle
import queue
import signal
import struct
import subprocess
import sys
import tempfile
import threading
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from typing import Callable

from grasp_fc_ros.core import warm_up
import numpy as np

from grasp_fc_ros.engine.evaluation import PackedGrasps, Settings, Verdicts, evaluate

# Contacts per chunk: ~2,700 6-finger grasps, ~20 ms of work on the latest 2-core EPYC
# (~35 ms on the slower one), under the ~50 ms that a request of more than INLINE_GRASPS
# grasps or a shutdown may wait for a chunk in progress. The core's own cost per grasp
# levels off from ~680 grasps a call (0.023 ms per grasp in calls of 42, 0.018 from 680
# on); larger chunks save the node's cost per chunk (feeding a worker, waking threads).
# benchmarks/bench_ros.py, batches of 10,000, alternating runs: 4,096 contacts 1.24x and
# 1.26x the core alone (node process 1.26-1.30 us of CPU per grasp), 8,192 1.30x and
# 1.37x, 16,384 1.38x, 1.41x, 1.38x and 1.40x (0.70-0.94 us), 32,768 1.36x and 1.41x.
CHUNK_CONTACTS = 16384
# Chunks of a batch with soft contacts hold CHUNK_CONTACTS / 64 = 256 contacts: their
# exact test (Clarabel path) measured 0.13-0.65 ms per grasp of 3-6 fingers against the
# fast stage's 0.004-0.04 (benchmarks/bench_soft.py), so a chunk stays near 10-30 ms.
SOFT_CHUNK_DIVISOR = 64
# A request of fewer chunks than workers is split into one chunk per worker, as equal as
# grasps allow, down to chunks of this many contacts (~170 6-finger grasps, where the
# core's cost per grasp is within ~15% of its best, per the figures above): a 1,000-grasp
# batch went as chunks of 682 and 318 grasps, leaving one worker idle a third of the time.
MIN_CHUNK_CONTACTS = 1024
# Requests up to this many grasps are decided inline (one core call, ~0.1-0.2 ms): a
# service call or a trickle of single queries does not wait behind batch chunks.
INLINE_GRASPS = 4
# How often a waiting caller looks at its cancel condition (s).
POLL_S = 0.02
# Chunk priorities: lower first. Service requests overtake queued batch chunks.
PRIORITY_INTERACTIVE = 0
PRIORITY_BATCH = 1
# The workers are the parallelism: a BLAS thread pool per worker would oversubscribe
# the cores (OpenBLAS threads spin while waiting).
_ONE_THREAD = {name: "1" for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS",
                                      "MKL_NUM_THREADS")}
_HEADER = struct.Struct("<Q")  # length prefix of each pickled message
# Bytes of the memory each worker shares with its owner for the chunks' arrays: a chunk
# of CHUNK_CONTACTS hard contacts takes 16 * grasps + 56 * contacts bytes, at most
# 1,048,576 (two-contact grasps); 2 MiB leave room, and pages never written cost nothing.
# Pickled through the pipes, 10,000-grasp batches (3 MB) in chunks of 4,096 contacts
# cost the pool's owner ~0.85 and the workers ~9.1 us of CPU per grasp, shared ~0.66
# and ~8.3 (benchmarks/bench_pool.py, alternating runs). A chunk that does not fit (huge grasps,
# thousands of empty ones) still goes through the pipe.
SHARED_BYTES = 2 << 20


class Cancelled(Exception):
    """The caller's cancel condition became true while its chunks were being decided."""


def _write(stream, obj):
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(_HEADER.pack(len(data)))
    stream.write(data)
    stream.flush()


def _read(stream):
    header = stream.read(_HEADER.size)
    if len(header) < _HEADER.size:
        raise EOFError("worker stream closed")
    (size,) = _HEADER.unpack(header)
    return pickle.loads(stream.read(size))


class SharedChunk:
    """A chunk's arrays in memory shared between the node and one worker process.

    The owner :meth:`put` s a chunk's arrays into it and sends the worker only their
    sizes; the worker :meth:`get` s a :class:`PackedGrasps` of views into the same
    memory. One chunk at a time: the owner writes the next one only once the worker
    answered the last.
    """

    def __init__(self, fd: int):
        self.fd = fd
        self.memory = mmap.mmap(fd, 0)  # the whole file

    @classmethod
    def create(cls, size: int | None = None) -> SharedChunk:
        """A new block of ``size`` bytes (default :data:`SHARED_BYTES`), backed by an
        anonymous memory file (Linux; elsewhere a temporary file)."""
        if hasattr(os, "memfd_create"):
            fd = os.memfd_create("grasp_fc_chunk")
        else:
            with tempfile.TemporaryFile() as backing:
                fd = os.dup(backing.fileno())
        os.ftruncate(fd, SHARED_BYTES if size is None else size)
        return cls(fd)

    def close(self) -> None:
        self.memory.close()
        os.close(self.fd)

    def put(self, chunk: PackedGrasps) -> tuple | None:
        """Copy ``chunk``'s arrays in; what :meth:`get` needs to read them back, or None
        if they do not fit (the chunk then goes through the pipe)."""
        layout = (len(chunk), len(chunk.mu), chunk.torsional is not None, chunk.name_by_id,
                  chunk.first_index)
        fields = _shared_fields(*layout[:3])
        if sum(np.dtype(dtype).itemsize * count for _, dtype, count in fields) > len(
                self.memory):
            return None
        at = 0
        for name, dtype, count in fields:
            target = np.frombuffer(self.memory, dtype, count, at)
            target[:] = np.reshape(getattr(chunk, name), -1)
            at += target.nbytes
        return layout

    def get(self, layout: tuple) -> PackedGrasps:
        """The chunk that :meth:`put` returned ``layout`` for, as views of the memory."""
        n_grasps, n_contacts, soft, name_by_id, first_index = layout
        arrays, at = {}, 0
        for name, dtype, count in _shared_fields(n_grasps, n_contacts, soft):
            arrays[name] = np.frombuffer(self.memory, dtype, count, at)
            at += arrays[name].nbytes
        return PackedGrasps(ids=arrays["ids"], counts=arrays["counts"],
                            positions=arrays["positions"].reshape(-1, 3),
                            normals=arrays["normals"].reshape(-1, 3), mu=arrays["mu"],
                            name_by_id=name_by_id, first_index=first_index,
                            torsional=arrays.get("torsional"))


def _shared_fields(n_grasps: int, n_contacts: int, soft: bool) -> list[tuple]:
    """(PackedGrasps field, dtype, values) of a chunk's arrays, in their order in the
    shared memory: 16 bytes per grasp, 56 per contact (64 with torsional friction)."""
    fields = [("ids", np.uint64, n_grasps), ("counts", np.int64, n_grasps),
              ("positions", np.float64, 3 * n_contacts),
              ("normals", np.float64, 3 * n_contacts), ("mu", np.float64, n_contacts)]
    return fields + [("torsional", np.float64, n_contacts)] if soft else fields


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
            [sys.executable, "-m", "grasp_fc_ros.engine.workers", str(self.shared.fd)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, pass_fds=(self.shared.fd,),
            env={**os.environ, **_ONE_THREAD})
        _read(process.stdout)
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
                _write(self.process.stdin, (_SHARED, layout, settings) if layout is not None
                       else (_PICKLED, chunk, settings))
                ok, answer = _read(self.process.stdout)
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


# How a chunk reaches a worker: its arrays in the shared memory, or pickled whole.
_SHARED = "shared"
_PICKLED = "pickled"


def chunk_size(total_contacts: int, workers: int, chunk_contacts: int = CHUNK_CONTACTS) -> int:
    """Contacts per chunk for a request of ``total_contacts`` on ``workers`` processes.

    At most ``chunk_contacts``; the chunks as equal as possible, and at least one per
    worker while each keeps :data:`MIN_CHUNK_CONTACTS`.
    """
    n_chunks = max(-(-total_contacts // chunk_contacts),
                   min(workers, total_contacts // MIN_CHUNK_CONTACTS), 1)
    return max(1, -(-total_contacts // n_chunks))


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


def _serve(shared_fd: int):
    """Worker main loop: a chunk in on stdin (its arrays in the memory of file descriptor
    ``shared_fd``, or pickled whole), (verdicts, seconds) out on stdout."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    stdin, stdout = sys.stdin.buffer, sys.stdout.buffer
    # Anything else printing to stdout would corrupt the stream: send it to stderr.
    sys.stdout = sys.stderr
    shared = SharedChunk(shared_fd)
    warm_up()  # the compiled exact stage, before the pool counts this worker as ready
    _write(stdout, "ready")
    while True:
        try:
            how, chunk, settings = _read(stdin)
        except EOFError:
            return  # the owner closed the pipe or died
        try:
            answer = True, evaluate(shared.get(chunk) if how == _SHARED else chunk, settings)
        except Exception as exc:  # noqa: BLE001 - reported to the owner, worker goes on
            answer = False, f"{type(exc).__name__}: {exc}"
        _write(stdout, answer)


if __name__ == "__main__":
    _serve(int(sys.argv[1]))
