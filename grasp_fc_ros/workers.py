"""A small pool of worker processes deciding chunks of packed grasps (no ROS).

The core is CPU-bound Python and numpy, and the GIL lets one process use about one
core. :class:`EvaluationPool` splits a large :class:`~grasp_fc_ros.evaluation.PackedGrasps`
into chunks, decides them in worker processes with :func:`~grasp_fc_ros.evaluation.evaluate`
and puts the verdicts back together in order. Small requests are decided in the
calling thread: a round trip through a worker costs more than they do.

Workers are started by a *forkserver* (a clean process that imports only this module's
dependencies), never forked from the ROS process, whose DDS threads must not be copied.
They ignore SIGINT (Ctrl-C reaches the whole process group; the owner decides) and exit
when their parent goes away, so a SIGKILL of the node leaves no workers behind.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import threading
import time
from typing import Callable

from grasp_fc_ros.evaluation import PackedGrasps, Settings, Verdicts, evaluate

# Requests up to this many contacts are decided inline: a worker round trip (pickling
# both ways, ~1 ms) would cost more than deciding them (a 6-finger grasp ~0.1 ms).
INLINE_CONTACTS = 600
# Contacts per chunk: ~1,000 6-finger grasps, about 0.1 s of core time; short enough
# that a shutdown or a cancelled batch waits little for the chunk in progress.
CHUNK_CONTACTS = 6_000
# How often a waiting caller looks at its cancel condition (s).
POLL_S = 0.02
# How often a worker checks that its parent is still alive (s).
PARENT_CHECK_S = 0.5


class Cancelled(Exception):
    """The caller's cancel condition became true while its chunks were being decided."""


def _init_worker():
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    parent = os.getppid()

    def watch_parent():
        while os.getppid() == parent:
            time.sleep(PARENT_CHECK_S)
        os._exit(0)

    threading.Thread(target=watch_parent, daemon=True).start()


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
        self._pool = None
        if workers:
            context = multiprocessing.get_context("forkserver")
            context.set_forkserver_preload(["grasp_fc_ros.evaluation"])
            self._pool = context.Pool(workers, initializer=_init_worker)

    def decide(self, packed: PackedGrasps, settings: Settings,
               cancelled: Callable[[], bool] = lambda: False) -> tuple[Verdicts, dict]:
        """Verdicts for every grasp of ``packed``, in order, and the seconds per stage.

        Raises
        ------
        Cancelled
            If ``cancelled()`` became true before all chunks were decided.
        """
        if self._pool is None or int(packed.counts.sum()) <= INLINE_CONTACTS:
            return evaluate(packed, settings)
        pending = [self._pool.apply_async(evaluate, (chunk, settings))
                   for chunk in packed.chunks(self._chunk_contacts)]
        parts, seconds = [], {}
        for result in pending:
            while not result.ready():
                if cancelled():
                    raise Cancelled()
                result.wait(POLL_S)
            verdicts, chunk_seconds = result.get()
            parts.append(verdicts)
            for key, value in chunk_seconds.items():
                seconds[key] = seconds.get(key, 0.0) + value
        return Verdicts.concatenate(parts), seconds

    def close(self):
        """Stop the workers at once (a chunk in progress is abandoned)."""
        if self._pool is not None:
            self._pool.terminate()
            self._pool.join()
            self._pool = None
