"""Run a benchmark script of ``benchmarks/`` the way a user would, for its test."""

import subprocess
import sys
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def run_benchmark(name: str, *args: str, timeout: float = 300) -> str:
    """The standard output of ``benchmarks/<name>.py args``, run in a subprocess of this
    environment (``os.environ`` as it is now: the ROS tests' own ROS_DOMAIN_ID too).

    The calling test fails, with the script's output, if it exits non-zero.
    """
    done = subprocess.run([sys.executable, str(BENCHMARKS / f"{name}.py"), *args],
                          capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stdout
