"""The node as a separate process started from its console script (grasp-fc-node).

Each test pays for a process start and DDS discovery (a few seconds): start-up
checks, signals, SIGKILL and restart with the client library resubmitting.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from grasp_fc_ros.client import GraspClient
from grasp_fc_ros.core import Status, check_force_closure
from grasp_fc_ros.interface.conversions import (
    grasp_to_contact_array,
    grasps_to_batch_msg,
    verdict_array_to_numpy,
)
from grasp_fc_ros.node.lane import SHUTDOWN_MESSAGE
from grasp_fc_ros.objects import make_object, sample_grasps
from ros_fixtures import Client, NodeProcess, node_command

pytestmark = pytest.mark.timeout(120)

MARGIN_ABS_TOL = 1e-6


@pytest.fixture(scope="module")
def client(ros):
    client = Client("grasp_fc_process_test_client")
    yield client
    client.close()


@pytest.fixture(scope="module")
def grasps():
    return sample_grasps(make_object("cylinder"), 100, 6, np.random.default_rng(5))


def assert_clean_exit(process, sig):
    code, _, err = process.stop(sig)
    assert code == 0, f"exit code {code}; stderr:\n{err}"
    assert "Traceback" not in err, err


@pytest.mark.parametrize("extra_env", [{}, {"FASTDDS_BUILTIN_TRANSPORTS": "UDPv4"}],
                         ids=["default_transports", "udp_only_node"])
def test_console_script_node_answers_topics_and_service(client, grasps, extra_env):
    client.clear()
    process = NodeProcess(node_command() + ["--ros-args", "-p", "friction_coefficient:=0.7"],
                          extra_env)
    try:
        client.wait_connected()
        positions, normals = grasps
        expected = check_force_closure(positions, normals, 0.7)

        got = verdict_array_to_numpy(
            client.request_batch(grasps_to_batch_msg(np.arange(100) + 5, positions, normals)))
        np.testing.assert_array_equal(got.ids, np.arange(100) + 5)
        np.testing.assert_array_equal(got.status, expected.status)
        np.testing.assert_allclose(got.margin, expected.margin, atol=MARGIN_ABS_TOL,
                                   rtol=1e-4, equal_nan=True)

        for i in range(20):
            client.contacts_pub.publish(grasp_to_contact_array(i, positions[i], normals[i]))
        verdicts = client.wait_for("verdicts", 20)
        assert [v.id for v in verdicts] == list(range(20))
        assert [v.status for v in verdicts] == expected.status[:20].tolist()

        infinite = normals[0].copy()
        infinite[3, 1] = np.inf
        bad = grasp_to_contact_array(77, positions[0], infinite)
        [answer] = client.call([bad])
        assert answer.id == 77 and answer.status == Status.INVALID_INPUT
        assert "contact 3" in answer.message
    finally:
        assert_clean_exit(process, signal.SIGTERM)


def test_module_entry_point_stops_cleanly_on_ctrl_c(client):
    process = NodeProcess([sys.executable, "-m", "grasp_fc_ros.node"])
    try:
        assert client.service.wait_for_service(timeout_sec=20.0)
    finally:
        assert_clean_exit(process, signal.SIGINT)


def test_invalid_start_parameter_exits_with_error():
    process = NodeProcess(node_command() + ["--ros-args", "-p", "friction_coefficient:=-1.0"])
    deadline = time.monotonic() + 30.0
    while process.proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.1)
    code, _, err = process.stop()
    assert code == 1
    assert "friction_coefficient" in err and "Traceback" not in err


def run_node(*args, timeout=60.0) -> subprocess.CompletedProcess:
    return subprocess.run(node_command() + list(args), capture_output=True, text=True,
                          timeout=timeout)


def test_help_prints_usage_and_exits_0():
    done = run_node("--help")
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("usage: grasp-fc-node")
    assert "friction_coefficient" in done.stdout and "--params-file" in done.stdout
    for name in ("contacts_batch", "check_force_closure", "compute_contact_forces",
                 "label_grasps", "markers", "clear_markers", "publish_markers"):
        assert name in done.stdout, name


@pytest.mark.parametrize("args, why", [
    (["-p", "friction_coefficient:=0.3"], "ROS arguments go after --ros-args"),
    (["--ros-args", "--params-file", "/nonexistent/params.yaml"], "cannot read params file"),
    (["--ros-args", "--params-file", "BAD"], "is not valid YAML"),
    (["--ros-args", "--params-file", "FLAT"], "expected '<node name>: {ros__parameters"),
])
def test_bad_command_line_is_one_clear_line_and_exit_2(tmp_path, args, why):
    (tmp_path / "bad.yaml").write_text("force_closure: [unclosed\n")
    (tmp_path / "flat.yaml").write_text("friction_coefficient: 0.3\n")
    args = [{"BAD": str(tmp_path / "bad.yaml"), "FLAT": str(tmp_path / "flat.yaml")}.get(a, a)
            for a in args]
    done = run_node(*args)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and why in lines[0], done.stderr


def wait_for_log(process: NodeProcess, text: str, timeout=30.0) -> str:
    """Read the node's stderr line by line until ``text`` appears; return what was read."""
    seen = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = process.proc.stderr.readline()
        if not line:
            break
        seen.append(line)
        if text in line:
            return "".join(seen)
    raise AssertionError(f"{text!r} not logged; stderr so far:\n{''.join(seen)}")


def test_start_logs_settings_and_warns_about_unknown_parameters(tmp_path):
    params = tmp_path / "params.yaml"
    params.write_text("other_node:\n  ros__parameters:\n    friction_coefficient: 0.9\n")
    process = NodeProcess(node_command() + [
        "--ros-args", "-p", "frction_coefficient:=0.3", "-p", "use_filter:=false",
        "--params-file", str(params)])
    try:
        log = wait_for_log(process, "has sections")
        assert "ignoring unknown parameter(s) frction_coefficient" in log
        assert "use_filter=False" in log and "friction_coefficient=0.5" in log
        assert "other_node" in log
    finally:
        assert_clean_exit(process, signal.SIGTERM)


# One worker: a large batch then keeps the node busy long enough that a signal lands
# while it is decided.
ONE_WORKER = ["--ros-args", "-p", "workers:=1"]


def test_sigterm_during_a_large_batch_exits_within_a_second(client, grasps):
    # One message of 600,000 contacts: beyond the default max_message_contacts. With
    # epsilon, its 100,000 grasps are about a minute of work on one worker (the verdicts
    # alone now take under a second, which the signal could miss).
    process = NodeProcess(node_command() + ONE_WORKER + ["-p", "max_message_contacts:=0",
                                                         "-p", "compute_epsilon:=true"])
    try:
        client.wait_connected()
        positions, normals = grasps
        big = 1000
        msg = grasps_to_batch_msg(np.arange(big * len(positions)), np.tile(positions, (big, 1, 1)),
                                  np.tile(normals, (big, 1, 1)))
        request_id = client.publish_batch(msg)
        wait_for_log(process, "ready")
        deadline = time.monotonic() + 60.0
        while int(client.diagnostics_after(time.time())["received"]) < len(msg.ids):
            assert time.monotonic() < deadline, "the node never received the batch"
    except BaseException:
        process.stop(signal.SIGKILL)
        raise
    start = time.monotonic()
    code, _, err = process.stop(signal.SIGTERM)
    elapsed = time.monotonic() - start
    assert code == 0 and "Traceback" not in err, err
    assert elapsed < 1.5, f"exit took {elapsed:.2f} s"  # 1 s, plus slack for a loaded machine
    # The node handles SIGTERM itself, so the context is still up while it stops: the
    # abandoned batch is answered (SOLVER_FAILURE, shutting down), not left silent.
    reply = client.batch_reply(request_id)
    got = verdict_array_to_numpy(reply)
    np.testing.assert_array_equal(got.ids, np.arange(len(msg.ids)))
    assert (got.status == Status.SOLVER_FAILURE).all()
    assert set(got.messages) == {SHUTDOWN_MESSAGE}
    assert "left unanswered" not in err


def test_second_ctrl_c_during_shutdown_exits_quietly(client, grasps):
    process = NodeProcess(node_command())
    try:
        client.wait_connected()
        positions, normals = grasps
        client.batch_pub.publish(grasps_to_batch_msg(np.arange(len(positions)), positions,
                                                     normals))
        wait_for_log(process, "ready")
        process.proc.send_signal(signal.SIGINT)
        process.proc.send_signal(signal.SIGINT)
    except BaseException:
        process.stop(signal.SIGKILL)
        raise
    code, _, err = process.stop(signal.SIGINT)
    assert code in (0, 130), err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err


def test_ctrl_c_right_after_start_exits_cleanly():
    # The node's threads, workers and service node are up when "ready" is logged; a
    # Ctrl-C at once once aborted the process at exit (threads left to the interpreter).
    for _ in range(3):
        process = NodeProcess(node_command())
        wait_for_log(process, "ready")
        assert_clean_exit(process, signal.SIGINT)


def test_client_resubmits_after_the_node_is_killed_and_restarted(ros, grasps):
    positions, normals = grasps
    namespace = f"/restart_{os.getpid()}"
    command = node_command() + ONE_WORKER + ["-r", f"__ns:={namespace}"]
    process = NodeProcess(command)
    client = GraspClient(f"{namespace}/force_closure")
    try:
        assert client.wait_for_node(30.0)
        # 300,000 grasps in ~300 parts: seconds through the node, so the kill (after the
        # next diagnostics, up to a period later) lands mid-batch.
        big = 3000
        batch = client.submit_batch(np.tile(positions, (big, 1, 1)), np.tile(normals, (big, 1, 1)))
        # The batch goes in parts (MAX_MESSAGE_CONTACTS): kill once the node has some.
        deadline = time.monotonic() + 60.0
        while int(client.next_diagnostics()["received"]) == 0:
            assert time.monotonic() < deadline, "the node never received the batch"
        singles = [client.submit(positions[i], normals[i]) for i in range(50)]
        process.proc.kill()  # SIGKILL mid-batch: the parts not answered are sent again
        process.proc.wait(timeout=10)
        assert not batch.done()
        process = NodeProcess(command)
        verdicts = batch.result(timeout=120.0)
        answers = [f.result(timeout=60.0) for f in singles]
        assert client.resubmitted > 0
    finally:
        client.close()
        process.stop(signal.SIGKILL)
    expected = check_force_closure(positions, normals, 0.5).status
    np.testing.assert_array_equal(verdicts.status, np.tile(expected, big))
    assert [a.status for a in answers] == expected[:50].tolist()


def test_demo_drives_a_running_node_by_name():
    namespace = f"/demo_target_{os.getpid()}"
    process = NodeProcess(node_command() + ["--ros-args", "-r", f"__ns:={namespace}"])
    try:
        demo = Path(sys.executable).with_name("grasp-fc-demo")
        done = subprocess.run([str(demo), "--grasps", "120", "--node-name",
                               f"{namespace}/force_closure"],
                              capture_output=True, text=True, timeout=90)
    finally:
        assert_clean_exit(process, signal.SIGTERM)
    assert done.returncode == 0, done.stderr
    assert f"-> node {namespace}/force_closure" in done.stdout
    assert re.search(r"^  queries\s+120$", done.stdout, re.M), done.stdout
