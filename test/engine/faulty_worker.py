"""A pool worker for fault tests: the pool's own worker (grasp_fc_ros.engine.worker.serve
deciding with evaluate), except on the chunks that hold a chosen grasp id.

Started through EvaluationPool's ``worker_command`` seam, which appends the memory
file's descriptor:

    python faulty_worker.py [--die-on ID] [--stop-on ID] [--pause-on ID]
                            [--garble-on ID] [--once MARKER] [--no-start PATH]
                            [--chatter] FD

--die-on ID    exit (code 3) on a chunk holding grasp id ID
--stop-on ID   stop itself (SIGSTOP) on such a chunk: a hung worker
--pause-on ID  sleep on such a chunk (the test kills it meanwhile)
--garble-on ID write bytes that are no message on its channel before answering such a
               chunk (a broken stream)
--once MARKER  do the above only if file MARKER does not exist, and create it first
               holding this process's id (so that the test knows which worker to
               kill, and the worker deciding the chunk again behaves)
--no-start PATH  exit (code 4) at start, before saying ready, while PATH exists
--chatter      write CHATTER on file descriptor 1 at start and before every chunk, as a
               library does (Fast DDS prints its XML parser errors there)
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import time
from pathlib import Path

from grasp_fc_ros.engine.child_process import CHANNEL_VARIABLE
from grasp_fc_ros.engine.evaluation import evaluate
from grasp_fc_ros.engine.worker import serve
from grasp_fc_ros.packed import PackedGrasps, Settings, Verdicts

DIE_CODE = 3
NO_START_CODE = 4
PAUSE_S = 120.0  # far longer than any test waits: the test kills the worker first
CHATTER = b"2026-01-01 [XMLPARSER Error] realpath failed for /tmp/gone/reader_times.xml\n"
GARBLE = b"this is no message header, and not a pickle either"


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--die-on", type=int)
    parser.add_argument("--stop-on", type=int)
    parser.add_argument("--pause-on", type=int)
    parser.add_argument("--once", type=Path)
    parser.add_argument("--garble-on", type=int)
    parser.add_argument("--no-start", type=Path)
    parser.add_argument("--chatter", action="store_true")
    parser.add_argument("fd", type=int)
    args = parser.parse_args()
    if args.no_start is not None and args.no_start.exists():
        sys.exit(NO_START_CODE)
    if args.chatter:
        os.write(1, CHATTER)
    answers_fd = int(os.environ[CHANNEL_VARIABLE].split(",")[1])  # serve() opens it

    def fault_due(chunk: PackedGrasps, grasp_id: int | None) -> bool:
        if grasp_id is None or grasp_id not in chunk.ids:
            return False
        if args.once is None:
            return True
        try:
            with open(args.once, "x") as marker:
                marker.write(str(os.getpid()))
        except FileExistsError:
            return False
        return True

    def decide(chunk: PackedGrasps, settings: Settings) -> tuple[Verdicts, dict]:
        if args.chatter:
            os.write(1, CHATTER)
        if fault_due(chunk, args.garble_on):
            os.write(answers_fd, GARBLE)
        if fault_due(chunk, args.die_on):
            os._exit(DIE_CODE)
        if fault_due(chunk, args.stop_on):
            os.kill(os.getpid(), signal.SIGSTOP)
        if fault_due(chunk, args.pause_on):
            time.sleep(PAUSE_S)
        return evaluate(chunk, settings)

    serve(args.fd, decide)


if __name__ == "__main__":
    main()
