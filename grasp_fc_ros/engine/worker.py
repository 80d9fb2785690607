"""A worker process of the pool: ``python -m grasp_fc_ros.engine.worker FD`` (no ROS).

It answers the chunks announced on its channel (:mod:`.child_process`: pipes of its
own, so that nothing a library prints can corrupt them): a chunk's arrays are in the
memory file FD (:class:`.shared_chunk.SharedChunk`), or pickled whole. It ignores SIGINT
(Ctrl-C reaches the whole process group; its owner decides) and ends when its channel
closes, so a SIGKILL of the owner leaves no workers.
"""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Callable
from typing import Any

from grasp_fc_ros.core import warm_up
from grasp_fc_ros.engine.child_process import (
    FramingError,
    open_channel,
    read_message,
    write_message,
)
from grasp_fc_ros.engine.evaluation import evaluate, warm_up_epsilon
from grasp_fc_ros.engine.shared_chunk import SHARED, SharedChunk
from grasp_fc_ros.engine.worker_crew import WARM_EPSILON_FLAG
from grasp_fc_ros.packed import PackedGrasps, Settings, Verdicts

#: What a worker does with a chunk: :func:`~.evaluation.evaluate`'s signature.
Decide = Callable[[PackedGrasps, Settings], tuple[Verdicts, dict]]

def serve(shared_fd: int, decide: Decide = evaluate, warm_epsilon: bool = False) -> None:
    """Worker main loop: a message of one or more chunks in on the channel (their arrays
    in the memory of file descriptor ``shared_fd``, or pickled whole), and for each
    chunk, in order, ``(True, decide(chunk, settings))`` out, or ``(False, reason)`` if
    ``decide`` raised: one list per message. Ends when the channel closes, or with exit
    code 1 and the reason on stderr if a message is broken.

    ``decide`` is a seam for fault tests (test/engine/faulty_worker.py wraps
    :func:`~.evaluation.evaluate` in a worker that dies or hangs on chosen chunks);
    the pool's workers use :func:`~.evaluation.evaluate` itself. With ``warm_epsilon``
    the epsilon kernels are warmed too before the worker says it is ready.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    requests, answers = open_channel()
    shared = SharedChunk(shared_fd)
    warm_up()  # the compiled exact stage, before the pool counts this worker as ready
    if warm_epsilon:
        warm_up_epsilon()
    write_message(answers, "ready")
    while True:
        try:
            how, chunks, settings = read_message(requests)
        except EOFError:
            return  # the owner closed the channel or died
        except FramingError as exc:
            sys.exit(f"worker process {os.getpid()}: {exc}")  # the owner replaces it
        write_message(answers, [_decide_one(decide, shared, how, chunk, settings)
                               for chunk in chunks])


def _decide_one(decide: Decide, shared: SharedChunk, how: str, chunk: Any,
                settings: Settings) -> tuple[bool, object]:
    """``(True, decide(...))`` for one chunk of a message (its layout in ``shared``, or
    itself), or ``(False, reason)``."""
    try:
        return True, decide(shared.get(chunk) if how == SHARED else chunk, settings)
    except Exception as exc:  # noqa: BLE001 - reported to the owner, worker goes on
        return False, f"{type(exc).__name__}: {exc}"

if __name__ == "__main__":
    serve(int(sys.argv[-1]), warm_epsilon=WARM_EPSILON_FLAG in sys.argv[1:-1])
