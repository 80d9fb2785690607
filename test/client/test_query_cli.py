"""grasp-fc-query as it ships: the installed console script, started as a subprocess
against a running node, as a venv user runs it from the shell."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

pytestmark = pytest.mark.timeout(180)

QUERY = Path(sys.executable).with_name("grasp-fc-query")
SQUARE = "1 0 0 -1 0 0; -1 0 0 1 0 0; 0 1 0 0 -1 0; 0 -1 0 0 1 0"
NAMESPACE = "/query_cli"


def query(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([str(QUERY), *args], capture_output=True, text=True,
                          timeout=timeout)


@pytest.fixture(scope="module")
def node_name(ros):
    from rclpy.parameter import Parameter

    from grasp_fc_ros.node import ForceClosureNode
    from ros_fixtures import SpinThread

    node = ForceClosureNode(namespace=NAMESPACE, parameter_overrides=[
        Parameter("workers", value=0), Parameter("compute_min_friction", value=True)])
    spinner = SpinThread(node)
    yield f"{NAMESPACE}/force_closure"
    spinner.stop()


def test_contacts_of_mixed_sizes_get_one_yaml_verdict_each_in_order(node_name):
    done = query("--node", node_name, "--first-id", "7", "--mu", "0.5",
                 "--contacts", SQUARE, "--contacts", "0 0 1 0 0 -1; 0,0,-1,0,0,1",
                 "--contacts", "1 0 0 -1 0 0; -1 0 0 1 0 0; 0 1 0 0 0 0")
    assert done.returncode == 0, done.stderr
    verdicts = yaml.safe_load(done.stdout)
    assert [v["id"] for v in verdicts] == [7, 8, 9]
    assert verdicts[0]["status"] == "FORCE_CLOSURE" and verdicts[0]["force_closure"] is True
    assert verdicts[0]["margin"] == pytest.approx(0.125, abs=1e-6)
    assert verdicts[0]["min_friction"] == pytest.approx(0.0, abs=1e-5)  # the node's field
    assert verdicts[1]["status"] in ("NOT_FORCE_CLOSURE", "FILTERED_OUT")
    assert verdicts[2]["status"] == "INVALID_INPUT"
    assert "contact 2: normal has zero length" in verdicts[2]["message"]


def test_npz_grasps_are_answered_as_the_core_decides_them(node_name, tmp_path):
    from grasp_fc_ros.core import check_force_closure
    from grasp_fc_ros.objects import make_object, sample_grasps

    positions, normals = sample_grasps(make_object("mug", 500), 30, 4,
                                       np.random.default_rng(2))
    np.savez(tmp_path / "g.npz", positions=positions, normals=normals, mu=np.full(30, 0.6))
    done = query("--node", node_name, "--npz", str(tmp_path / "g.npz"))
    assert done.returncode == 0, done.stderr
    verdicts = yaml.safe_load(done.stdout)
    expected = check_force_closure(positions, normals, 0.6)
    assert [v["force_closure"] for v in verdicts] == expected.force_closure.tolist()


@pytest.mark.parametrize("args,message", [
    (("--contacts", "1 0 0 -1 0"),
     "--contacts of grasp 0, contact 0: '1 0 0 -1 0' is not six numbers"),
    (("--npz", "missing.npz"), "missing.npz: [Errno 2] No such file"),
])
def test_bad_input_exits_2_naming_it_without_a_node(args, message):
    done = query("--node", "/nobody_here/force_closure", *args)
    assert done.returncode == 2 and message in done.stderr, done.stderr
    assert done.stdout == ""


def test_misshapen_npz_exits_2_naming_the_shapes(tmp_path):
    np.savez(tmp_path / "bad.npz", positions=np.ones((3, 4, 3)), normals=np.ones((3, 5, 3)))
    done = query("--node", "/nobody_here/force_closure", "--npz", str(tmp_path / "bad.npz"))
    assert done.returncode == 2, done.stderr
    assert "positions has shape (3, 4, 3) but normals (3, 5, 3)" in done.stderr


def test_no_node_exits_1_saying_how_to_start_one(ros):
    done = query("--node", "/nobody_here/force_closure", "--timeout", "1",
                 "--contacts", SQUARE)
    assert done.returncode == 1
    assert "no node /nobody_here/force_closure answers within 1 s" in done.stderr
    assert ".venv/bin/grasp-fc-node" in done.stderr
