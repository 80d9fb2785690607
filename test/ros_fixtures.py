"""ROS-specific test helpers for the node tests (the fixtures are in conftest.py).

Importing this module claims a ROS_DOMAIN_ID of its own for this test run
(:func:`ros_domains.claim_domain_id`) *before* rclpy is initialised, so that parallel
runs on one machine cannot hear each other. Child processes inherit it through the environment.

:class:`Client` speaks the raw protocol (it can send what grasp_fc_ros.client never
would: malformed batches, queries without a client id); tests of normal use take
:class:`grasp_fc_ros.client.GraspClient`.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

from ros_domains import claim_domain_id

os.environ["ROS_DOMAIN_ID"] = str(claim_domain_id())
# Keep discovery on this machine (no multicast on the network).
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from grasp_fc_msgs.msg import (  # noqa: E402  # noqa: E402
    ContactArray,
    ContactArrayBatch,
    ForceClosureVerdict,
    ForceClosureVerdictArray,
)
from grasp_fc_msgs.srv import CheckForceClosure  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402

from grasp_fc_ros.interface.conversions import (  # noqa: E402
    grasp_to_contact_array,
    grasps_to_batch_msg,
)
from grasp_fc_ros.interface.names import QUERY_QOS as RELIABLE  # noqa: E402 - the documented QoS
from grasp_fc_ros.interface.names import reply_topic  # noqa: E402

# Bounds on waits for what must come (s): generous, since on a shared 2-core machine a
# node process's start (numba's cache loaded, workers started) or an answer can take many
# seconds; a wait that succeeds returns at once, so they cost only a failing test.
DISCOVERY_TIMEOUT_S = 60.0
REPLY_TIMEOUT_S = 60.0
NODE_EXIT_TIMEOUT_S = 10.0
# Id of wait_connected's probe queries and batches (no test uses it), and how often an
# unanswered probe is sent again (s).
PROBE_ID = 2 ** 64 - 1
PROBE_PERIOD_S = 1.0
# Two opposite fingers on a unit sphere: (positions, normals), (2, 3) each.
PROBE_GRASP = (np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]]),
               np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]))


class SpinThread:
    """Spin one node on its own executor in a daemon thread."""

    def __init__(self, node: Node):
        self.node = node
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(node)
        self.stopped = False
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self):
        try:
            self.executor.spin()
        except Exception:  # noqa: BLE001 - shutdown while spinning ends the thread quietly
            pass

    def stop(self):
        """Stop spinning and destroy the node (a second call does nothing)."""
        if self.stopped:
            return
        self.stopped = True
        self.executor.shutdown()
        self.thread.join(timeout=5.0)
        self.node.destroy_node()


class Client:
    """A test client: publishes queries, collects verdicts, calls the service.

    All waiting uses timeouts; messages are collected by the client's own spin thread.
    """

    def __init__(self, name: str = "grasp_fc_test_client", namespace: str | None = None):
        self.node = Node(name, namespace=namespace)
        self._lock = threading.Condition()
        self.verdicts: list[ForceClosureVerdict] = []
        self.batches: list[ForceClosureVerdictArray] = []
        self.diagnostics = []
        self._sent = 0
        self._probes_answered: set[str] = set()
        self.contacts_pub = self.node.create_publisher(ContactArray, "contacts", RELIABLE)
        self.batch_pub = self.node.create_publisher(ContactArrayBatch, "contacts_batch", RELIABLE)
        self.node.create_subscription(ForceClosureVerdict, "verdicts", self._on_verdict, RELIABLE)
        self.node.create_subscription(ForceClosureVerdictArray, "verdicts_batch",
                                      self._on_batch, RELIABLE)
        from diagnostic_msgs.msg import DiagnosticArray
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10)
        self.service = self.node.create_client(CheckForceClosure, "check_force_closure")
        self.spinner = SpinThread(self.node)

    def listen(self, client_id: int) -> None:
        """Also collect the answers to queries carrying ``client_id``: they come on that
        client's reply topics (call before sending, so that the node's reply publishers
        find the subscriptions)."""
        self.node.create_subscription(ForceClosureVerdict, reply_topic("verdicts", client_id),
                                      self._on_verdict, RELIABLE)
        self.node.create_subscription(ForceClosureVerdictArray,
                                      reply_topic("verdicts_batch", client_id),
                                      self._on_batch, RELIABLE)

    def _on_verdict(self, msg):
        with self._lock:
            if msg.id == PROBE_ID:
                self._probes_answered.add("verdicts")
            else:
                self.verdicts.append(msg)
            self._lock.notify_all()

    def _on_batch(self, msg):
        with self._lock:
            if msg.request_id == PROBE_ID:
                self._probes_answered.add("verdicts_batch")
            else:
                self.batches.append(msg)
            self._lock.notify_all()

    def _on_diagnostics(self, msg):
        with self._lock:
            self.diagnostics.append(msg)
            self._lock.notify_all()

    def wait_connected(self, timeout=DISCOVERY_TIMEOUT_S, node: Node | None = None):
        """Wait until the node's service, subscriptions and publishers are matched.

        ``node``: the node, when it runs in this process: then its answer publishers'
        own matches are waited for. A node in another process is not seen from here (the
        two ends of a match see it at different times, and a reliable, volatile publisher
        drops what it sends before): probe queries on both topics are sent until each
        was answered, which only a matched answer publisher can do. Their answers are
        not collected; the node counts them in its diagnostics.
        """
        deadline = time.monotonic() + timeout
        assert self.service.wait_for_service(timeout_sec=timeout), "service not found"
        while time.monotonic() < deadline:
            if (self.contacts_pub.get_subscription_count() > 0
                    and self.batch_pub.get_subscription_count() > 0
                    and self.node.count_publishers("verdicts") > 0
                    and self.node.count_publishers("verdicts_batch") > 0
                    and (node is None or answers_matched(node))):
                if node is None:
                    self._probe(deadline)
                return
            time.sleep(0.05)
        raise AssertionError("node topics not matched within timeout")

    def _probe(self, deadline: float) -> None:
        """Send a probe query and a probe batch (id PROBE_ID) every PROBE_PERIOD_S until
        both were answered, by ``deadline`` (time.monotonic())."""
        with self._lock:
            self._probes_answered.clear()
        positions, normals = PROBE_GRASP
        single = grasp_to_contact_array(PROBE_ID, positions, normals)
        batch = grasps_to_batch_msg(np.array([PROBE_ID], dtype=np.uint64), positions[None],
                                    normals[None], request_id=PROBE_ID)
        topics = {"verdicts": (self.contacts_pub, single),
                  "verdicts_batch": (self.batch_pub, batch)}
        while True:
            with self._lock:
                waiting = set(topics) - self._probes_answered
            if not waiting:
                return
            assert time.monotonic() < deadline, f"no answer to probes on {sorted(waiting)}"
            for topic in waiting:
                publisher, msg = topics[topic]
                publisher.publish(msg)
            with self._lock:
                self._lock.wait_for(lambda: set(topics) <= self._probes_answered,
                                    PROBE_PERIOD_S)

    def wait_for(self, attribute: str, count: int, timeout=REPLY_TIMEOUT_S):
        """Wait until ``len(self.<attribute>) >= count``; return a copy of the list."""
        with self._lock:
            ok = self._lock.wait_for(lambda: len(getattr(self, attribute)) >= count, timeout)
            items = list(getattr(self, attribute))
        assert ok, f"received {len(items)} of {count} {attribute} within {timeout} s"
        return items

    def publish_batch(self, msg: ContactArrayBatch) -> int:
        """Publish a batch under a request_id of its own (set in ``msg``); that id, for
        :meth:`batch_reply`."""
        self._sent += 1
        msg.request_id = self._sent
        self.batch_pub.publish(msg)
        return msg.request_id

    def batch_reply(self, request_id: int, timeout=REPLY_TIMEOUT_S):
        """The one ForceClosureVerdictArray answering the batch sent as ``request_id``.

        Recognised by its request_id (the node copies it), so that a stray earlier reply
        (this client may be shared by a module's tests) cannot be mistaken for it.
        """
        with self._lock:
            ok = self._lock.wait_for(
                lambda: any(b.request_id == request_id for b in self.batches), timeout)
            replies = [b for b in self.batches if b.request_id == request_id]
        assert ok, f"no reply to batch {request_id} within {timeout} s"
        assert len(replies) == 1, f"{len(replies)} replies to one batch"
        return replies[0]

    def request_batch(self, msg: ContactArrayBatch, timeout=REPLY_TIMEOUT_S):
        """Publish a batch and return the ForceClosureVerdictArray answering it."""
        return self.batch_reply(self.publish_batch(msg), timeout)

    def diagnostics_after(self, t: float, node_name: str = "/force_closure",
                          timeout=REPLY_TIMEOUT_S) -> dict[str, str]:
        """Key values of the first diagnostics of ``node_name`` stamped after ``t``.

        ``t`` is system time (time.time()), the node's clock. A status stamped after
        ``t`` was built after everything the node had counted by then, so comparing
        two such readings gives exact changes.
        """
        def find():
            for msg in self.diagnostics:
                stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
                for status in msg.status:
                    if stamp > t and status.name.startswith(node_name + ":"):
                        return {kv.key: kv.value for kv in status.values}
            return None

        with self._lock:
            ok = self._lock.wait_for(lambda: find() is not None, timeout)
            values = find()
        assert ok, f"no diagnostics of {node_name} stamped after {t} within {timeout} s"
        return values

    def diagnostics_when(self, reached: Callable[[dict[str, str]], bool],
                         node_name: str = "/force_closure",
                         timeout=REPLY_TIMEOUT_S) -> dict[str, str]:
        """Key values of the first diagnostics of ``node_name`` stamped after this call
        for which ``reached(values)`` holds; the last one read if none does within
        ``timeout`` (the caller's assertion then shows it).

        The node counts a single query answered just after publishing its verdict, and a
        marker or a goal's end as it happens: a test that has seen them waits until the
        counts reach what it expects, then asserts them exactly.
        """
        deadline = time.monotonic() + timeout
        while True:
            values = self.diagnostics_after(time.time(), node_name, timeout)
            if reached(values) or time.monotonic() > deadline:
                return values

    def clear(self):
        with self._lock:
            self.verdicts.clear()
            self.batches.clear()
            self.diagnostics.clear()

    def call(self, grasps, timeout=REPLY_TIMEOUT_S):
        """Call the service with ContactArray messages; return the verdict list."""
        request = CheckForceClosure.Request(grasps=list(grasps))
        done = threading.Event()
        future = self.service.call_async(request)
        future.add_done_callback(lambda _: done.set())
        assert done.wait(timeout), "service call timed out"
        return future.result().verdicts

    def close(self):
        self.spinner.stop()


def answers_matched(node: Node) -> bool:
    """Whether ``node``'s publishers of the shared answer topics (``verdicts``,
    ``verdicts_batch``) have each matched a subscription."""
    topics = {node.resolve_topic_name(name) for name in ("verdicts", "verdicts_batch")}
    answers = [p for p in node.publishers if p.topic_name in topics]
    return len(answers) == len(topics) and all(p.get_subscription_count() for p in answers)


def console_script(name: str) -> str:
    """The path of console script ``name`` (grasp-fc-node, ...), installed next to this
    interpreter (the venv's bin), else on PATH."""
    script = Path(sys.executable).with_name(name)
    if not script.exists():
        found = shutil.which(name)
        if found is None:
            pytest.fail(f"console script {name} not installed (pip install -e . into this "
                        "venv)")
        script = Path(found)
    return str(script)


def node_command() -> list[str]:
    """The node's console script, installed next to this interpreter."""
    return [console_script("grasp-fc-node")]


class DiagnosticsWatch:
    """Every /diagnostics status of one node (``/NS/NAME``), with its level and message,
    as it arrives (a node of its own, spun on a thread)."""

    def __init__(self, node_name: str):
        from diagnostic_msgs.msg import DiagnosticArray

        self._prefix = node_name + ":"
        self._lock = threading.Condition()
        self.statuses: list = []
        node = Node("grasp_fc_diagnostics_watch")
        node.create_subscription(DiagnosticArray, "/diagnostics", self._on_array, 10)
        self._spinner = SpinThread(node)

    def _on_array(self, msg) -> None:
        with self._lock:
            self.statuses += [s for s in msg.status if s.name.startswith(self._prefix)]
            self._lock.notify_all()

    def wait_for(self, condition, what: str, timeout: float = REPLY_TIMEOUT_S):
        """The first status from now on for which ``condition(level, values)`` holds
        (``values``: its key values as a dict)."""
        with self._lock:
            start = len(self.statuses)
            found: list = []

            def seen() -> bool:
                found[:] = [s for s in self.statuses[start:]
                            if condition(s.level, key_values(s))]
                return bool(found)

            assert self._lock.wait_for(seen, timeout), f"no diagnostics with {what}"
            return found[0]

    def close(self) -> None:
        self._spinner.stop()


def key_values(status) -> dict[str, str]:
    """A DiagnosticStatus's key values as a dict."""
    return {kv.key: kv.value for kv in status.values}


class NodeProcess:
    """The node as a separate process; stop() asserts a clean exit."""

    def __init__(self, command: list[str], extra_env: dict | None = None):
        env = dict(os.environ)
        env.update(extra_env or {})
        self.proc = subprocess.Popen(command, env=env, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True)

    def stop(self, sig=signal.SIGTERM) -> tuple[int, str, str]:
        """Send ``sig``; return (exit code, stdout, stderr)."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            out, err = self.proc.communicate(timeout=NODE_EXIT_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            out, err = self.proc.communicate()
            raise AssertionError(f"node did not exit after {sig!r}; stderr:\n{err}") from None
        return self.proc.returncode, out, err
