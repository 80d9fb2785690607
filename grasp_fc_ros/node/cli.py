"""``grasp-fc-node``: the command line, the spin loop and a clean shutdown."""

from __future__ import annotations

import gc
import os
import signal
import sys
import threading

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from grasp_fc_ros.interface.names import (
    CHECK_SERVICE,
    CLEAR_MARKERS_SERVICE,
    CONTACT_FORCES_SERVICE,
    CONTACTS_BATCH_TOPIC,
    CONTACTS_TOPIC,
    DIAGNOSTICS_TOPIC,
    LABEL_ACTION,
    MARKERS_TOPIC,
    NODE_NAME,
    VERDICTS_BATCH_TOPIC,
    VERDICTS_TOPIC,
)
from grasp_fc_ros.node.dds_profile import prompt_acks
from grasp_fc_ros.node.force_closure_node import ForceClosureNode
from grasp_fc_ros.node.parameters import PARAMETERS

# How often the spin loop of grasp-fc-node looks for a Ctrl-C or SIGTERM (s): the
# signal handler only sets a flag, so this bounds the time to start shutting down.
SIGNAL_POLL_S = 0.05


def _interface_lines() -> str:
    """The node's topics, services and action, one line each, for --help."""
    rows = [("topics", f"{CONTACTS_TOPIC} -> {VERDICTS_TOPIC}", "one grasp per message"),
            ("", f"{CONTACTS_BATCH_TOPIC} -> {VERDICTS_BATCH_TOPIC}", "many grasps per message"),
            ("", MARKERS_TOPIC, "RViz markers (publish_markers:=true)"),
            ("", DIAGNOSTICS_TOPIC, "counters and timings, once a second"),
            ("services", CHECK_SERVICE, "verdicts for the grasps of a request"),
            ("", CONTACT_FORCES_SERVICE, "contact forces that hold a load"),
            ("", CLEAR_MARKERS_SERVICE, "delete the published markers"),
            ("action", LABEL_ACTION, "a long batch, with feedback and cancel")]
    return "\n".join(f"  {kind:<10} {name:<34} {what}" for kind, name, what in rows)


USAGE = f"""usage: grasp-fc-node [-h] [--ros-args ROS_ARGUMENTS...]

The {NODE_NAME} node: force-closure verdicts for grasp queries (grasp_fc_msgs),
one per query (see the README and docs/node.rst).

{_interface_lines()}

ROS arguments (after --ros-args):
  -p NAME:=VALUE           set a parameter (doubles need a decimal point: 1.0)
  --params-file FILE       parameters from a YAML file keyed by node name
                           ({NODE_NAME}, /NAMESPACE/{NODE_NAME} or /**)
  -r __ns:=/NAMESPACE      run in a namespace
  -r __node:=NAME          run under another node name
  --log-level LEVEL        debug, info, warn, error

parameters:
""" + "\n".join(f"  {name:<22} {default!r:>10}  {descriptor.description}"
                for name, (default, descriptor) in PARAMETERS.items())


class UsageError(Exception):
    """Command-line arguments the node cannot start with (exit code 2)."""


def check_arguments(argv: list[str]) -> bool:
    """Check the command line before rclpy sees it; True when --help was asked.

    Raises
    ------
    UsageError
        For arguments before ``--ros-args`` (e.g. ``-p x:=y`` without it, which rclpy
        would ignore) and for a missing, unreadable or malformed params file.
    """
    user = argv[1:]
    split = user.index("--ros-args") if "--ros-args" in user else len(user)
    before, ros_args = user[:split], user[split + 1:]
    if "-h" in before or "--help" in before:
        return True
    if before:
        raise UsageError(f"unexpected argument(s) {' '.join(before)}: ROS arguments go after "
                         "--ros-args (e.g. --ros-args -p friction_coefficient:=0.3); see --help")
    for i, arg in enumerate(ros_args):
        if arg == "--params-file":
            if i + 1 >= len(ros_args):
                raise UsageError("--params-file needs a file name")
            _check_params_file(ros_args[i + 1])
    return False


def _check_params_file(path: str) -> None:
    import yaml

    try:
        with open(path, encoding="utf-8") as stream:
            content = yaml.safe_load(stream)
    except OSError as exc:
        raise UsageError(f"cannot read params file {path}: {exc.strerror}") from None
    except yaml.YAMLError as exc:
        raise UsageError(f"params file {path} is not valid YAML: "
                         f"{str(exc).splitlines()[0]}") from None
    if not isinstance(content, dict) or not all(
            isinstance(v, dict) and isinstance(v.get("ros__parameters"), dict)
            for v in content.values()):
        raise UsageError(f"params file {path}: expected '<node name>: {{ros__parameters: "
                         "{...}}' at the top level")


def _warn_params_file_keys(argv: list[str], node: Node) -> None:
    """Warn when a params file has no section for this node (rclpy ignores it then)."""
    import yaml

    names = {"/**", node.get_name(), node.get_fully_qualified_name(),
             node.get_fully_qualified_name().lstrip("/")}
    for i, arg in enumerate(argv[:-1]):
        if arg == "--params-file":
            with open(argv[i + 1], encoding="utf-8") as stream:
                keys = set(yaml.safe_load(stream))
            if not keys & names:
                node.get_logger().warning(
                    f"params file {argv[i + 1]} has sections {sorted(keys)} but none for "
                    f"this node ({node.get_fully_qualified_name()}): it is ignored")


def main(args: list[str] | None = None) -> int:
    """Run the node until Ctrl-C or SIGTERM; return the process exit code."""
    argv = list(sys.argv if args is None else args)
    try:
        if check_arguments(argv):
            print(USAGE)
            return 0
    except UsageError as exc:
        print(f"{NODE_NAME}: {exc}", file=sys.stderr)
        return 2
    # The node handles SIGINT and SIGTERM itself: rclpy's own handler shuts the context
    # down at once, while the service thread and the worker threads may still be inside
    # rcl calls, which crashed the process (SIGSEGV) now and then. Here a signal only
    # ends the spin loop; the node then stops its threads before the context goes.
    stop = threading.Event()

    def on_signal(*_: object) -> None:
        stop.set()
        # A second Ctrl-C while shutting down ends the process at once, quietly (the
        # workers notice their parent is gone and exit too).
        signal.signal(signal.SIGINT, lambda *_: os._exit(130))

    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, on_signal)
    # Fast DDS reads its profiles while the context and the node are made, and so does
    # a child process's (the marker process) whenever it starts: the profile stays until
    # the node and its children are gone (see .dds_profile).
    with prompt_acks():
        return _spin(argv, stop)


def _spin(argv: list[str], stop: threading.Event) -> int:
    """Make the node, spin it until ``stop`` is set, destroy it; the exit code."""
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    try:
        executor = SingleThreadedExecutor()
        node = ForceClosureNode()
        _warn_params_file_keys(argv, node)
        executor.add_node(node)
        # Out of the cyclic garbage collector's full scans: everything imported and set up
        # so far (numba, rclpy, the message types). A full scan of it, now and then during
        # a long label_grasps job, held every thread of the node, its service included,
        # beyond the service's latency target (tuned: docs/performance.md#big-label-jobs).
        gc.freeze()
        while not stop.is_set():
            executor.spin_once(timeout_sec=SIGNAL_POLL_S)
    except ExternalShutdownException:
        pass  # rclpy shut down by other code in this process
    except ParameterException as exc:
        print(f"{NODE_NAME}: bad parameter: {exc}", file=sys.stderr)
        return 1
    finally:
        if node is not None:
            node.destroy_node()
        shutdown_rclpy()
    return 0


def shutdown_rclpy() -> None:
    """Shut rclpy down unless a signal already did.

    ``try_shutdown`` checks the context and then shuts it down; rclpy's signal handler
    can shut it down in between, and the second shutdown raises RCLError.
    """
    try:
        rclpy.try_shutdown()
    except Exception:  # noqa: BLE001 - rclpy raises its private RCLError here
        if rclpy.ok():
            raise

