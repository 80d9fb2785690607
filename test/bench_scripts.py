"""Run a benchmark script of ``benchmarks/`` the way a user would, for its test."""

import os
import signal
import subprocess
import sys
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def run_benchmark(name: str, *args: str, timeout: float = 300) -> str:
    """The standard output of ``benchmarks/<name>.py args``, run in a subprocess of this
    environment (``os.environ`` as it is now: the ROS tests' own ROS_DOMAIN_ID too).

    The calling test fails, with the script's output, if it exits non-zero or runs longer
    than ``timeout`` seconds. The script runs in a session of its own, killed whole on
    time-out: a node or worker it started holds its output pipes too, and left alive it
    would keep the test waiting for them (and run on after it).
    """
    script = subprocess.Popen([sys.executable, str(BENCHMARKS / f"{name}.py"), *args],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              start_new_session=True)
    try:
        out, err = script.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(script.pid, signal.SIGKILL)
        out, err = script.communicate()
        raise AssertionError(f"{name} {' '.join(args)} ran longer than {timeout} s:\n"
                             f"{out}{err}") from None
    assert script.returncode == 0, out + err
    return out
