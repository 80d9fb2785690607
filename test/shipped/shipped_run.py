"""Running the installed console scripts as a user does (helpers of test/shipped/).

A user starts ``grasp-fc-node``, ``grasp-fc-demo`` and ``grasp-fc-label`` from the venv's
``bin`` in a plain shell: :func:`user_environment` is this test process's environment
without the knobs the test harness sets (ros_fixtures sets a discovery range) or a
developer may have set, plus the test run's own ROS_DOMAIN_ID. :class:`ScriptRun` keeps
the whole output (stdout and stderr, in order, in a file: a pipe could fill and stall
the process) so that a test can assert that no line reports an error.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sysconfig
from collections.abc import Sequence
from pathlib import Path

import ros_fixtures  # noqa: F401 - claims this run's ROS_DOMAIN_ID first
from ros_fixtures import NODE_EXIT_TIMEOUT_S, console_script

REPO = Path(__file__).resolve().parents[2]
#: The params file the package ships (README: --params-file config/force_closure.yaml).
PARAMS_FILE = REPO / "config" / "force_closure.yaml"

# Not in a user's shell who follows the README: what the test harness sets
# (ros_fixtures: ROS_AUTOMATIC_DISCOVERY_RANGE) and what tunes the middleware or this
# package; a test that wants one (a user's own profiles file) passes it explicitly.
NOT_A_USERS = ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_STATIC_PEERS", "ROS_LOCALHOST_ONLY",
               "RMW_IMPLEMENTATION", "FASTRTPS_DEFAULT_PROFILES_FILE",
               "FASTDDS_DEFAULT_PROFILES_FILE", "FASTDDS_BUILTIN_TRANSPORTS",
               "CYCLONEDDS_URI", "RCUTILS_CONSOLE_OUTPUT_FORMAT", "RCUTILS_LOGGING_SEVERITY")
NOT_A_USERS_PREFIXES = ("GRASP_FC_", "PYTEST_")

#: A line of output that reports an error: an rclpy/rcutils ERROR or FATAL log line, a
#: Fast DDS error ("[XMLPARSER Error]", "[RTPS_TRANSPORT_SHM Error]"), a Python
#: traceback, a C++ abort.
ERROR_LINE = re.compile(r"\[(ERROR|FATAL)\]|\w Error\]|Traceback \(most recent call last\)"
                        r"|terminate called|core dumped|Segmentation fault")


def user_environment(**extra: str) -> dict[str, str]:
    """The environment of a user's shell: this process's, less :data:`NOT_A_USERS`,
    with this run's ROS_DOMAIN_ID and ``extra``."""
    env = {name: value for name, value in os.environ.items()
           if name not in NOT_A_USERS and not name.startswith(NOT_A_USERS_PREFIXES)}
    env["ROS_DOMAIN_ID"] = os.environ["ROS_DOMAIN_ID"]
    env.update(extra)
    return env


def other_middlewares() -> list[str]:
    """RMW implementations installed in this venv besides Fast DDS (the default)."""
    site = Path(sysconfig.get_paths()["purelib"])
    return sorted(path.name for path in site.glob("rmw_*_cpp")
                  if path.is_dir() and path.name != "rmw_fastrtps_cpp"
                  and not path.name.endswith("_shared_cpp"))


def error_lines(output: str) -> list[str]:
    """The lines of ``output`` that report an error (:data:`ERROR_LINE`)."""
    return [line for line in output.splitlines() if ERROR_LINE.search(line)]


class ScriptRun:
    """A console script started as a user does, its output kept in ``log_path``.

    Parameters
    ----------
    name : str
        The console script (``grasp-fc-node``, ...), from the venv's bin.
    args : sequence of str
    log_path : Path
        Where its stdout and stderr go, in order.
    env : dict, optional
        Default :func:`user_environment`.
    cwd : Path, optional
    """

    def __init__(self, name: str, args: Sequence[str], log_path: Path,
                 env: dict[str, str] | None = None, cwd: Path | None = None):
        self.log_path = log_path
        self._log = open(log_path, "wb")  # noqa: SIM115 - closed in stop()/wait()
        self.process = subprocess.Popen(
            [console_script(name), *args], stdin=subprocess.DEVNULL, stdout=self._log,
            stderr=subprocess.STDOUT, env=user_environment() if env is None else env,
            cwd=cwd)

    def output(self) -> str:
        return self.log_path.read_text(errors="replace")

    def wait(self, timeout_s: float) -> int:
        """Wait for the script to end by itself; its exit code (killed after
        ``timeout_s``: an AssertionError showing its output)."""
        try:
            return self.process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
            raise AssertionError(f"{self.process.args[0]} still running after {timeout_s} "
                                 f"s; output:\n{self.output()}") from None
        finally:
            self._log.close()

    def stop(self, sig: signal.Signals) -> int:
        """Send ``sig`` (as Ctrl-C or a service manager does); the exit code (killed
        after NODE_EXIT_TIMEOUT_S: an AssertionError)."""
        if self.process.poll() is None:
            self.process.send_signal(sig)
        return self.wait(NODE_EXIT_TIMEOUT_S)
