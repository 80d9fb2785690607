"""The pool's worker processes, kept working: a dead or hung worker costs no grasp (no ROS).

:class:`WorkerCrew` runs one slot per worker process: a thread that takes chunks from
the crew's priority queue, hands each to its process (:mod:`.worker`) and sets the
chunk's Future from the answer. When a worker dies while deciding a chunk, or stops
answering for longer than :func:`answer_bound_s` (the crew's watchdog then kills it),
its slot starts a replacement and the chunk goes back to the queue, ahead of the chunks
queued after it, for whichever worker is free first. A chunk on which workers die
twice is not tried again: its grasps get SOLVER_FAILURE verdicts that say why.

A slot that cannot start a worker process (:data:`START_ATTEMPTS` tries) retires and
leaves the queue to the others; the last slot to retire decides the chunks in this
process. Everything that goes wrong is reported through the crew's ``log``.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import IO

from grasp_fc_ros.core import Status
from grasp_fc_ros.engine.child_process import ONE_THREAD_ENV, read_message, write_message
from grasp_fc_ros.engine.evaluation import evaluate
from grasp_fc_ros.engine.shared_chunk import PICKLED, SHARED, SharedChunk, shared_bytes
from grasp_fc_ros.packed import PackedGrasps, Settings, Verdicts

_logger = logging.getLogger(__name__)

#: The command that starts a worker process; the crew appends its memory file's
#: descriptor (see :func:`.worker.serve`).
WORKER_COMMAND = (sys.executable, "-m", "grasp_fc_ros.engine.worker")
#: Given before the descriptor, a worker also warms the epsilon kernels before it says
#: it is ready (the pool's ``warm_epsilon``); otherwise its first epsilon chunk does.
WARM_EPSILON_FLAG = "--warm-epsilon"

# How long a worker may stay silent on a chunk before it counts as hung: at least
# WORKER_TIMEOUT_S, plus a time per contact of the chunk (answer_bound_s). The floor
# leaves a loaded machine and a kernel compiled on first use room; each per-contact time
# is about twenty times the slowest measured per contact of its kind (tuned:
# docs/performance.md#worker-pool). Soft contacts and mu* are far slower than hard
# contacts without mu*, hence two rates; a long job's chunks of soft contacts may hold
# the pool's CHUNK_CONTACTS, so the bound grows with the chunk.
WORKER_TIMEOUT_S = 30.0
HARD_CONTACT_S = 2e-4
SLOW_CONTACT_S = 2e-2

# How long a worker may take to say it is ready: in a fresh install it compiles every
# kernel (the numba cache is empty), several workers at once on a loaded machine
# (docs/performance.md#worker-pool); later starts load the cache.
START_TIMEOUT_S = 300.0
# Tries to start a worker before its slot retires: a second try covers a one-off
# failure (a process killed while it imports); a broken install fails both at once.
START_ATTEMPTS = 2
# A chunk on which this many workers die is answered with SOLVER_FAILURE verdicts
# instead of being tried again: the chunk itself is killing them.
DEATHS_PER_CHUNK = 2
# The watchdog looks at the workers this often (s), or 4 times per bound if shorter.
WATCHDOG_PERIOD_S = 1.0
# How long a worker whose stream ended may take to exit before it counts as alive (s).
EXIT_GRACE_S = 1.0
# How long close() waits for a slot's thread (s): a thread deciding a chunk in this
# process (all workers retired) finishes its chunk first.
JOIN_TIMEOUT_S = 2.0


def answer_bound_s(chunk: PackedGrasps, settings: Settings, floor_s: float) -> float:
    """Seconds a worker may take to answer ``chunk`` before it counts as hung:
    ``floor_s`` plus :data:`SLOW_CONTACT_S` per contact when the chunk has soft contacts
    or asks for mu*, epsilon or robustness, else :data:`HARD_CONTACT_S`; and for
    robustness as much again per contact of every sample (each an exact test)."""
    per_contact = SLOW_CONTACT_S if is_slow(chunk, settings) else HARD_CONTACT_S
    samples = 0 if settings.robustness is None else settings.robustness.samples
    per_sample = SLOW_CONTACT_S if chunk.torsional is not None else HARD_CONTACT_S
    return floor_s + len(chunk.mu) * (per_contact + samples * per_sample)


def is_slow(chunk: PackedGrasps, settings: Settings) -> bool:
    """Whether ``chunk`` has soft contacts or asks for mu*, epsilon or robustness (far
    slower a contact than hard contacts without them)."""
    return (chunk.torsional is not None or settings.compute_min_friction
            or settings.compute_epsilon or settings.robustness is not None)


def uses_epsilon_kernels(settings: Settings) -> bool:
    """Whether deciding with ``settings`` runs the epsilon kernels (compiled on first use,
    see :class:`_Slot`): epsilon, and the robustness radii (their position radius is an
    epsilon search)."""
    return bool(settings.compute_epsilon) or settings.robustness is not None


def describe_chunk(chunk: PackedGrasps) -> str:
    """Which grasps ``chunk`` holds, for messages: 'grasps 40,960-43,007'."""
    if chunk.name_by_id:
        return f"{len(chunk):,} single queries"
    return f"grasps {chunk.first_index:,}-{chunk.first_index + len(chunk) - 1:,}"


@dataclass
class Task:
    """A chunk waiting for a worker, and the Future of its (verdicts, seconds)."""

    future: Future
    chunk: PackedGrasps
    settings: Settings
    priority: int
    order: int
    deaths: list[str] = field(default_factory=list)  # why each worker on it died
    # Sent alone from now on: a worker died on a message of this chunk and others, and
    # which of them killed it is not known (see WorkerCrew.message_died).
    alone: bool = False


def settle(task: Task, answer: tuple[Verdicts, dict]) -> None:
    """Set ``task``'s result, unless its Future was cancelled meanwhile."""
    if task.future.set_running_or_notify_cancel():
        task.future.set_result(answer)


def settle_failed(task: Task, message: str) -> None:
    """Answer every grasp of ``task`` with SOLVER_FAILURE and ``message``."""
    settle(task, (Verdicts.failed_grasps(task.chunk, task.settings, Status.SOLVER_FAILURE,
                                         message), {}))


class WorkerCrew:
    """Worker processes deciding the chunks of one queue, replaced when they die.

    Parameters
    ----------
    workers : int
        Number of worker processes (>= 1): the first, then the others side by side; the
        constructor returns when each is ready or its slot has retired.
    command : sequence of str
        Starts a worker (:data:`WORKER_COMMAND`); the descriptor of its memory file is
        appended.
    worker_timeout_s : float
        Floor of :func:`answer_bound_s` (s).
    start_timeout_s : float
        Longest a worker may take to become ready (s).
    log : callable (str) -> None
        Told of every worker that dies, hangs or cannot start, and what became of its
        chunk.
    message_contacts : int
        Contacts a worker is sent in one message at most: a slot that takes a chunk
        also takes the chunks queued behind it (same priority and settings, hard
        contacts without mu* or epsilon) up to this many contacts, while as many more
        wait as there are idle slots (0: one chunk a message).
    """

    def __init__(self, workers: int, command: Sequence[str], worker_timeout_s: float,
                 start_timeout_s: float, log: Callable[[str], None],
                 message_contacts: int = 0):
        self.command = tuple(command)
        self.message_contacts = message_contacts
        self.worker_timeout_s = worker_timeout_s
        self.start_timeout_s = start_timeout_s
        self._log = log
        self.closing = threading.Event()
        self._tasks: queue.PriorityQueue = queue.PriorityQueue()
        self._order = itertools.count()
        self._lock = threading.Lock()
        self._active = workers  # slots not retired
        self._idle = 0  # slots waiting for a chunk
        self._restarts = 0
        self._slots: list[_Slot] = []
        self._watchdog = threading.Thread(target=self._watch, daemon=True,
                                          name="grasp_fc_watchdog")
        self._watchdog.start()
        # The first worker starts alone: in a fresh install it compiles the core's
        # kernels into numba's cache, which the others then load instead of compiling
        # them too, side by side, on the same cores.
        self._slots.append(_Slot(self, 0))
        self._slots[0].ready.wait()
        self._slots += [_Slot(self, index) for index in range(1, workers)]
        for slot in self._slots:
            slot.ready.wait()

    def say(self, message: str) -> None:
        """Tell ``log``; a failing ``log`` must not stop the slot's thread that calls it."""
        try:
            self._log(message)
        except Exception:  # noqa: BLE001 - the message still reaches this module's logger
            _logger.exception("the pool's log failed on: %s", message)

    def submit(self, chunk: PackedGrasps, settings: Settings, priority: int) -> Future:
        """Queue ``chunk``; a Future of its (verdicts, seconds), cancelled if the crew
        closes first."""
        future: Future = Future()
        order = next(self._order)
        self._tasks.put((priority, order, Task(future, chunk, settings, priority, order)))
        return future

    def queued(self) -> int:
        """Chunks waiting for a worker now (approximate: others may queue or take
        meanwhile)."""
        return self._tasks.qsize()

    def next_task(self) -> Task | None:
        """The most urgent queued chunk, once there is one; None when closing."""
        with self._lock:
            self._idle += 1
        try:
            task = self._tasks.get()[2]
        finally:
            with self._lock:
                self._idle -= 1
        if task is not None and self.closing.is_set():
            task.future.cancel()
            return None
        return task

    def tasks_behind(self, first: Task) -> list[Task]:
        """Queued chunks to send in one message with ``first``, in order: those right
        behind it with its priority and settings, hard and fast (:func:`is_slow`),
        sent alone by no rule, up to :attr:`message_contacts` contacts in all, leaving
        a chunk for each idle slot. One message costs the slot and its worker about
        what one chunk does (tuned: docs/performance.md#worker-messages)."""
        if first.alone or is_slow(first.chunk, first.settings):
            return []
        taken: list[Task] = []
        contacts = len(first.chunk.mu)
        while True:
            with self._lock:
                spare = self._tasks.qsize() > self._idle
            if not spare:
                return taken
            try:
                entry = self._tasks.get_nowait()
            except queue.Empty:
                return taken
            task = entry[2]
            if (task is None or task.alone or task.priority != first.priority
                    or task.settings != first.settings or is_slow(task.chunk, task.settings)
                    or contacts + len(task.chunk.mu) > self.message_contacts):
                self._tasks.put(entry)  # back in its place
                return taken
            contacts += len(task.chunk.mu)
            taken.append(task)

    def requeue(self, task: Task) -> None:
        """Put ``task`` back in its place in the queue (ahead of later chunks)."""
        self._tasks.put((task.priority, task.order, task))

    def message_died(self, tasks: list[Task], reason: str) -> None:
        """A worker died (or was killed as hung) deciding a message of ``tasks``: queue
        them again, each to be sent alone. A message of one chunk counts against it
        (:meth:`worker_died`); of several, no death is counted against any (which one
        killed the worker is not known): alone, a chunk that kills workers does so
        twice more and fails, the others are decided."""
        if len(tasks) == 1:
            self.worker_died(tasks[0], reason)
            return
        if self.closing.is_set():
            for task in tasks:
                task.future.cancel()
            return
        self.say(f"{reason}; its {len(tasks)} chunks ("
                 + ", ".join(describe_chunk(task.chunk) for task in tasks)
                 + ") are decided again, each alone")
        for task in tasks:
            task.alone = True
            self.requeue(task)

    def worker_died(self, task: Task, reason: str) -> None:
        """A worker died (or was killed as hung) deciding ``task``: queue it again, or
        answer it with SOLVER_FAILURE if it was its :data:`DEATHS_PER_CHUNK` th."""
        task.deaths.append(reason)
        if self.closing.is_set():
            task.future.cancel()
            return
        where = describe_chunk(task.chunk)
        if len(task.deaths) < DEATHS_PER_CHUNK:
            self.say(f"{reason}; its chunk ({where}) is decided again")
            self.requeue(task)
            return
        message = (f"worker process died twice deciding this chunk ({where}): "
                   + "; then ".join(task.deaths))
        self.say(message)
        settle_failed(task, message)

    def retire(self, index: int, reason: str) -> bool:
        """Slot ``index`` could not start a worker: log it. True if it was the last
        slot with workers (it then decides the chunks in this process)."""
        with self._lock:
            self._active -= 1
            left = self._active
        if self.closing.is_set():
            return False
        self.say(f"worker {index}: no worker process could be started ({reason}); "
                 + (f"its chunks go to the {left} other worker(s)" if left
                    else "chunks are decided in this process from now on"))
        return not left

    def count_restart(self) -> None:
        with self._lock:
            self._restarts += 1

    @property
    def restarts(self) -> int:
        """Worker processes that died or were killed as hung so far."""
        with self._lock:
            return self._restarts

    def pids(self) -> list[int]:
        """Process ids of the running worker processes."""
        return [pid for pid in (slot.pid() for slot in self._slots) if pid is not None]

    def _watch(self) -> None:
        """Kill the workers that are late with an answer (their slots then see EOF)."""
        period = min(WATCHDOG_PERIOD_S, self.worker_timeout_s / 4, self.start_timeout_s / 4)
        while not self.closing.wait(period):
            now = time.monotonic()
            for slot in self._slots:
                slot.kill_if_late(now)

    def close(self) -> None:
        """Kill the workers, end the slots' threads, cancel the chunks not decided."""
        self.closing.set()
        for slot in self._slots:
            slot.kill()
        for _ in self._slots:
            self._tasks.put((-1, next(self._order), None))  # wakes a waiting slot
        for slot in self._slots:
            slot.join(JOIN_TIMEOUT_S)
        self._watchdog.join(JOIN_TIMEOUT_S)
        while True:
            try:
                task = self._tasks.get_nowait()[2]
            except queue.Empty:
                return
            if task is not None:
                task.future.cancel()


class _WorkerLost(Exception):
    """A worker process died, was killed as hung, or could not be started."""


class _Slot:
    """One worker process at a time, and the thread that feeds it chunks."""

    def __init__(self, crew: WorkerCrew, index: int):
        self.crew = crew
        self.index = index
        self.shared = SharedChunk.create()
        self.ready = threading.Event()  # set once the first start succeeded or failed
        self._lock = threading.Lock()  # the process and its deadline: the watchdog's too
        self._process: subprocess.Popen[bytes] | None = None
        self._deadline: float | None = None
        self._bound_s = 0.0
        self._killed_late = False
        # Whether the current process has answered an epsilon (or robustness) chunk: a
        # worker warms only the verdict kernels at start, so its first such chunk
        # compiles (or loads from numba's cache) the epsilon kernels and gets the
        # start-up allowance (uses_epsilon_kernels).
        self._epsilon_warm = False
        self._thread = threading.Thread(target=self._run, daemon=True,
                                        name=f"grasp_fc_worker_{index}")
        self._thread.start()

    # --- the slot's thread ----------------------------------------------------------

    def _run(self) -> None:
        try:
            failure = self._start()
            last = failure is not None and self.crew.retire(self.index, failure)
        finally:
            self.ready.set()
        if failure is None:
            try:
                failure = self._feed()
            except Exception as exc:  # noqa: BLE001 - a bug: this slot stops, others go on
                _logger.exception("worker slot %d failed", self.index)
                self._drop_process()
                failure = f"its thread failed: {exc!r}"
            last = failure is not None and self.crew.retire(self.index, failure)
        if last:
            self._decide_here()

    def _feed(self) -> str | None:
        """Feed the worker chunks, replacing it whenever it dies; None once the crew
        closes, else why no replacement could be started."""
        while (task := self.crew.next_task()) is not None:
            tasks = [t for t in [task, *self.crew.tasks_behind(task)] if not t.future.done()]
            if not tasks or self._decide(tasks):
                continue
            self.crew.count_restart()
            failure = self._start()
            if failure is not None:
                return failure
        return None

    def _start(self) -> str | None:
        """Start a worker and wait until it is ready; None, or why it could not."""
        reasons = []
        for _ in range(START_ATTEMPTS):
            if self.crew.closing.is_set():
                return "the pool is closing"
            try:
                self._spawn()
                return None
            except _WorkerLost as exc:
                reasons.append(str(exc))
        return "; ".join(reasons)

    def _spawn(self) -> None:
        command = [*self.crew.command, str(self.shared.fd)]
        with self._lock:
            if self.crew.closing.is_set():
                raise _WorkerLost("the pool is closing")
            try:
                process = subprocess.Popen(command, stdin=subprocess.PIPE,
                                           stdout=subprocess.PIPE, pass_fds=(self.shared.fd,),
                                           env={**os.environ, **ONE_THREAD_ENV})
            except OSError as exc:
                raise _WorkerLost(f"cannot run {command[0]}: {exc}") from exc
            self._process = process
            self._epsilon_warm = WARM_EPSILON_FLAG in self.crew.command
            self._arm(self.crew.start_timeout_s)
        try:
            hello = read_message(_pipes(process)[1])
        except Exception as exc:  # noqa: BLE001 - anything on the stream: not started
            raise _WorkerLost(self._lost(process, exc, "while starting")) from exc
        finally:
            late = self._disarm()
        if late or hello != "ready":
            raise _WorkerLost(self._lost(process, f"said {hello!r}", "while starting"))

    def _decide(self, tasks: list[Task]) -> bool:
        """Have the worker decide ``tasks`` (one message) and settle them; False if the
        worker died (the tasks are then back in the queue, or answered as failed)."""
        process = self._process
        assert process is not None
        if process.poll() is not None:  # died while idle: not these chunks' doing
            self.crew.say(f"{self._lost(process, None, 'while idle')}; starting another")
            for task in tasks:
                self.crew.requeue(task)
            return False
        try:
            message = self._message(tasks)
        except Exception as exc:  # noqa: BLE001 - these chunks only; the worker is fine
            for task in tasks:
                settle_failed(task, f"internal error: {exc}")
            return True
        compiles = (any(uses_epsilon_kernels(task.settings) for task in tasks)
                    and not self._epsilon_warm)
        with self._lock:
            self._arm(self.crew.worker_timeout_s
                      + sum(answer_bound_s(task.chunk, task.settings, 0.0) for task in tasks)
                      + (self.crew.start_timeout_s if compiles else 0.0))
        to_worker, from_worker = _pipes(process)
        try:
            write_message(to_worker, message)
            answers = read_message(from_worker)
        except Exception as exc:  # noqa: BLE001 - the worker is gone, whatever the error
            self._disarm()
            self.crew.message_died(tasks, self._lost(process, exc, "deciding a chunk"))
            return False
        self._disarm()
        self._epsilon_warm |= any(uses_epsilon_kernels(task.settings) for task in tasks)
        for task, (ok, answer) in zip(tasks, answers, strict=True):
            if ok:
                settle(task, answer)
            else:  # evaluate itself raised: deciding again would fail the same way
                settle_failed(task, f"internal error: {answer}")
        return True

    def _message(self, tasks: list[Task]) -> tuple:
        """The message that sends ``tasks``' chunks: their arrays one after the other in
        the shared memory, or, if they do not all fit, the chunks pickled whole."""
        layouts, at = [], 0
        for task in tasks:
            layout = self.shared.put(task.chunk, at)
            if layout is None:
                return PICKLED, [task.chunk for task in tasks], tasks[0].settings
            layouts.append(layout)
            at += shared_bytes(task.chunk)
        return SHARED, layouts, tasks[0].settings

    def _decide_here(self) -> None:
        """Decide queued chunks in this process until the crew closes (no workers left)."""
        while (task := self.crew.next_task()) is not None:
            if task.future.done():
                continue
            try:
                answer = evaluate(task.chunk, task.settings)
            except Exception as exc:  # noqa: BLE001 - this chunk only
                settle_failed(task, f"internal error: {exc}")
                continue
            settle(task, answer)

    def _lost(self, process: subprocess.Popen[bytes], error: object, doing: str) -> str:
        """Reap ``process`` (killed if need be) and say what became of it."""
        late = self._killed_late
        try:  # a dying process closes its stream a moment before it can be reaped
            process.wait(EXIT_GRACE_S)
            alive = False
        except subprocess.TimeoutExpired:
            alive = True
        self._discard(process)
        code = process.returncode
        if late:
            return (f"worker process {process.pid} did not answer within "
                    f"{self._bound_s:.3g} s {doing} and was killed")
        if alive:
            return f"worker process {process.pid} broke its stream {doing} ({error!r})"
        if code < 0:
            return f"worker process {process.pid} was killed by {_signal_name(-code)} {doing}"
        return f"worker process {process.pid} exited with code {code} {doing}"

    def _discard(self, process: subprocess.Popen[bytes]) -> None:
        with self._lock:
            if self._process is process:
                self._process = None
        process.kill()  # nothing if it has already been reaped
        process.wait()
        for stream in (process.stdin, process.stdout):
            with contextlib.suppress(OSError):
                if stream is not None:
                    stream.close()

    # --- the deadline, shared with the watchdog (under self._lock) ------------------

    def _arm(self, bound_s: float) -> None:
        self._bound_s = bound_s
        self._deadline = time.monotonic() + bound_s
        self._killed_late = False

    def _disarm(self) -> bool:
        """Clear the deadline; whether the watchdog killed the worker for missing it."""
        with self._lock:
            self._deadline = None
            return self._killed_late

    def kill_if_late(self, now: float) -> None:
        """Kill the worker if it has missed its deadline (the watchdog's thread)."""
        with self._lock:
            if (self._deadline is not None and now > self._deadline
                    and self._process is not None):
                self._killed_late = True
                self._deadline = None
                self._process.kill()

    # --- the owner's thread ---------------------------------------------------------

    def pid(self) -> int | None:
        with self._lock:
            process = self._process
        return process.pid if process is not None and process.poll() is None else None

    def kill(self) -> None:
        with self._lock:
            if self._process is not None:
                self._process.kill()

    def join(self, timeout_s: float) -> None:
        """Wait for the thread; then reap the worker and free the shared memory."""
        self._thread.join(timeout_s)
        if self._thread.is_alive():
            return  # still deciding a chunk in this process: it is a daemon thread
        self._drop_process()
        self.shared.close()

    def _drop_process(self) -> None:
        """Kill and reap the worker process, if there is one."""
        with self._lock:
            process = self._process
        if process is not None:
            self._discard(process)


def _pipes(process: subprocess.Popen[bytes]) -> tuple[IO[bytes], IO[bytes]]:
    """The worker's stdin and stdout (both pipes: see _Slot._spawn)."""
    assert process.stdin is not None and process.stdout is not None
    return process.stdin, process.stdout


def _signal_name(number: int) -> str:
    try:
        return signal.Signals(number).name
    except ValueError:
        return f"signal {number}"
