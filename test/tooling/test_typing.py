"""mypy on the annotated modules (mypy.ini), and the core's public signatures as mypy sees them."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
MYPY_TIMEOUT_S = 240

pytestmark = pytest.mark.timeout(2 * MYPY_TIMEOUT_S)


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    # Outside the work tree; shared by this module's runs.
    return tmp_path_factory.mktemp("mypy_cache")


def _mypy(cache_dir: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mypy", "--cache-dir", str(cache_dir), *args],
                          cwd=ROOT, capture_output=True, text=True, timeout=MYPY_TIMEOUT_S)


def test_annotated_modules_type_check(cache_dir):
    done = _mypy(cache_dir)  # files and settings from mypy.ini
    assert done.returncode == 0, done.stdout + done.stderr
    assert done.stdout.startswith("Success"), done.stdout


def test_py_typed_marker_is_in_the_package():
    assert (ROOT / "grasp_fc_ros" / "py.typed").is_file()


def test_core_public_api_has_real_signatures(cache_dir, tmp_path):
    """Importing the core gives mypy its signatures and return types, without stubs."""
    probe = tmp_path / "probe.py"
    probe.write_text(
        "from grasp_fc_ros.core import (Status, check_force_closure, exact_force_closure,\n"
        "                               torque_filter, validate_grasps)\n"
        "reveal_type(check_force_closure)\n"
        "reveal_type(torque_filter)\n"
        "reveal_type(exact_force_closure)\n"
        "reveal_type(validate_grasps)\n"
        "status: Status = Status.FORCE_CLOSURE\n")
    done = _mypy(cache_dir, str(probe))
    assert done.returncode == 0, done.stdout + done.stderr
    revealed = re.findall(r'Revealed type is "(.*)"', done.stdout)
    returns = [r.rsplit(" -> ", 1)[-1] for r in revealed]
    assert returns[0] == "grasp_fc_ros.core.pipeline.ForceClosureResult"
    # torque_filter: the verdicts, or (verdicts, wrenches) with certificates=True.
    certified = r"numpy\.ndarray\[.*\] \| tuple\[numpy\.ndarray.*\]"
    assert re.fullmatch(certified, returns[1]), returns[1]
    assert returns[2].startswith("numpy.ndarray")
    assert returns[3] == "grasp_fc_ros.core.model.grasp_input.GraspValidation"
