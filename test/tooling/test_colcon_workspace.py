"""The two packages build in a ROS 2 workspace with colcon, as the README says.

The venv running these tests stands in for a ROS 2 Jazzy install (the underlay):
it is laid out as a ROS prefix. colcon comes from PyPI (`make test` installs it).
The workspace follows the README's recipe: the repository in ``src/``, and colcon
given ``src`` and the repository's ``msg_defs/`` as base paths, because colcon's crawl
stops at the repository root, which is a package itself.
"""

import os
import select
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ros_domains import claim_domain_id

REPO = Path(__file__).resolve().parents[2]
VENV = Path(sys.prefix)
COLCON = Path(sys.executable).parent / "colcon"
# What `colcon list` prints as build type for each of the repository's packages.
PACKAGES = {"grasp_fc_msgs": "ros.ament_cmake", "grasp_fc_ros": "ros.ament_python"}
CONSOLE_SCRIPTS = ("grasp-fc-node", "grasp-fc-demo", "grasp-fc-experiment")
# Checkout debris that a user's fresh clone would not have.
NOT_SOURCE = shutil.ignore_patterns(
    ".git", "build", "install", "log", "bench_out", "__pycache__", "*.egg-info",
    ".pytest_cache", ".hypothesis",
)
COLCON_TIMEOUT_S = 600
# A fresh install path means a cold numba cache: the node and each worker compile the
# fast exact stage before "ready" (~25 s CPU each; measured 27-45 s wall on a loaded
# 2-core machine), so this is generous.
NODE_READY_TIMEOUT_S = 180.0
NODE_EXIT_TIMEOUT_S = 10.0
# What the node logs once its topics and service are up.
NODE_READY_TEXT = "ready"

pytestmark = pytest.mark.timeout(COLCON_TIMEOUT_S)


def _colcon():
    """Return the colcon executable of this venv; skip (or fail under make) without it."""
    if COLCON.exists():
        return str(COLCON)
    message = f"colcon is not installed next to {sys.executable} (`make test` installs it)"
    if os.environ.get("GRASP_FC_REQUIRE_COLCON"):
        pytest.fail(message)
    pytest.skip(message)


def _ignore_venvs_and_debris(directory, names):
    """Return the names copytree must skip: checkout debris and any virtual env."""
    skipped = set(NOT_SOURCE(directory, names))
    skipped.update(n for n in names if (Path(directory, n) / "pyvenv.cfg").exists())
    return skipped


def _underlay_env(tmp_path):
    """Return the environment of a shell that has sourced the venv as a ROS underlay."""
    env = dict(os.environ)
    env["PATH"] = f"{VENV / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    env["AMENT_PREFIX_PATH"] = str(VENV)
    env["CMAKE_PREFIX_PATH"] = str(VENV)
    # Keep a user's colcon defaults (~/.colcon) out of the test.
    env["COLCON_HOME"] = str(tmp_path / "colcon_home")
    return env


def _run(args, cwd, env):
    """Run a command; on failure, fail the test with the end of its output."""
    done = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=COLCON_TIMEOUT_S)
    if done.returncode != 0:
        pytest.fail(f"{' '.join(map(str, args))} exited {done.returncode}:\n"
                    f"{done.stdout[-4000:]}\n{done.stderr[-4000:]}")
    return done.stdout


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    """A colcon workspace with this checkout in src/grasp_fc_ros, built by the recipe."""
    colcon = _colcon()
    root = tmp_path_factory.mktemp("colcon_ws")
    src = root / "src" / "grasp_fc_ros"
    shutil.copytree(REPO, src, ignore=_ignore_venvs_and_debris)
    env = _underlay_env(root)
    base_paths = ["--base-paths", "src", "src/grasp_fc_ros/msg_defs"]
    listed = _run([colcon, "list", *base_paths], root, env)
    crawled = _run([colcon, "list", "--names-only"], root, env)
    order = _run([colcon, "list", "--topological-order", "--names-only", *base_paths],
                 root, env)
    _run([colcon, "build", *base_paths, "--cmake-args", "-DBUILD_TESTING=OFF"], root, env)
    return {"root": root, "env": env, "listed": listed, "crawled": crawled,
            "order": order.split()}


def test_default_crawl_stops_at_the_repository_root(workspace):
    """Why the recipe names msg_defs/: without it colcon never sees the messages."""
    assert workspace["crawled"].split() == ["grasp_fc_ros"]


def test_recipe_finds_both_packages_with_their_build_types(workspace):
    found = {}
    for line in workspace["listed"].splitlines():
        name, _path, build_type = line.split("\t")
        found[name] = build_type.strip("()")
    assert found == PACKAGES


def test_recipe_builds_the_messages_before_the_node_package(workspace):
    assert workspace["order"] == ["grasp_fc_msgs", "grasp_fc_ros"]


def _installed_script(workspace, script):
    """Return the path of a console script in the install space, or None."""
    install = workspace["root"] / "install" / "grasp_fc_ros"
    # lib/<package>/ is where `ros2 run` looks; bin/ is setuptools' default.
    for candidate in (install / "lib" / "grasp_fc_ros" / script, install / "bin" / script):
        if candidate.is_file():
            return candidate
    return None


def test_install_space_holds_the_console_scripts(workspace):
    for script in CONSOLE_SCRIPTS:
        assert _installed_script(workspace, script), f"{script} not installed"


def test_node_from_the_workspace_starts_and_stops_cleanly(workspace):
    """The workspace's grasp-fc-node comes up and ends with exit code 0 on Ctrl-C."""
    node = _installed_script(workspace, "grasp-fc-node")
    assert node, "grasp-fc-node not installed"
    env = dict(workspace["env"], ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               ROS_DOMAIN_ID=str(claim_domain_id()))  # a domain of its own
    env.pop("PYTHONPATH", None)
    process = subprocess.Popen(["sh", "-c", f'. install/setup.sh && exec "{node}"'],
                               cwd=workspace["root"], env=env, stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True)
    try:
        output = _read_until(process, NODE_READY_TEXT, NODE_READY_TIMEOUT_S)
        assert NODE_READY_TEXT in output, f"node did not get ready:\n{output}"
        process.send_signal(signal.SIGINT)
        rest, _ = process.communicate(timeout=NODE_EXIT_TIMEOUT_S)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == 0, f"exit code {process.returncode}:\n{output}{rest}"
    assert "Traceback" not in output + rest


def _read_until(process, text, timeout_s):
    """Return the process's output up to the line containing ``text`` (or the deadline)."""
    output = ""
    deadline = time.monotonic() + timeout_s
    while text not in output and process.poll() is None:
        remaining = deadline - time.monotonic()
        if remaining <= 0 or not select.select([process.stdout], [], [], remaining)[0]:
            break
        output += process.stdout.readline()
    return output


def test_sourced_workspace_imports_its_own_build(workspace):
    """After `. install/setup.sh` both packages import from the workspace, not the venv."""
    probe = (
        "import grasp_fc_msgs, grasp_fc_ros\n"
        "from grasp_fc_msgs.msg import Contact, ContactArray\n"
        "from grasp_fc_msgs.srv import CheckForceClosure\n"
        "from rclpy.serialization import serialize_message, deserialize_message\n"
        "query = ContactArray(id=7, contacts=[Contact(friction_coefficient=0.5)])\n"
        "back = deserialize_message(serialize_message(query), ContactArray)\n"
        "assert back.id == 7 and back.contacts[0].friction_coefficient == 0.5\n"
        "print(grasp_fc_msgs.__file__)\n"
        "print(grasp_fc_ros.__file__)\n"
    )
    command = f'. install/setup.sh && exec "{sys.executable}" -c "$PROBE"'
    env = dict(workspace["env"], PROBE=probe)
    env.pop("PYTHONPATH", None)
    printed = _run(["sh", "-c", command], workspace["root"], env).split()
    install = workspace["root"] / "install"
    assert Path(printed[-2]).is_relative_to(install / "grasp_fc_msgs")
    assert Path(printed[-1]).is_relative_to(install / "grasp_fc_ros")
