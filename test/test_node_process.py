"""The node as a separate process started from its console script (grasp-fc-node).

Each test pays for a process start and DDS discovery (about two seconds).
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from ros_fixtures import Client, NodeProcess, node_command, ros  # noqa: F401 - ros: fixture

from grasp_fc_ros.conversions import (
    grasp_to_contact_array,
    grasps_to_batch_msg,
    verdict_array_to_numpy,
)
from grasp_fc_ros.core import Status, check_force_closure
from grasp_fc_ros.objects import make_object, sample_grasps

pytestmark = pytest.mark.timeout(120)

MARGIN_ABS_TOL = 1e-6


@pytest.fixture(scope="module")
def client(ros):  # noqa: F811
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


def test_demo_console_script_streams_grasps_and_prints_table():
    demo = Path(sys.executable).with_name("grasp-fc-demo")
    assert demo.exists(), "console script grasp-fc-demo not installed (pip install -e .)"
    done = subprocess.run([str(demo), "--grasps", "300", "--object", "torus"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    rows = (re.match(r"^  (\S.*?)\s{2,}(\S.*)$", line) for line in done.stdout.splitlines())
    table = dict(row.groups() for row in rows if row)
    assert table["queries"] == "300"
    assert table["invalid input"] == "0" and table["solver failures"] == "0"
    decided = sum(int(table[key]) for key in ("rejected by the filter",
                                              "decided by the exact test"))
    assert decided == 300
    assert table["throughput"].endswith("grasps/s")
