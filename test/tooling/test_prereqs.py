"""scripts/check_prereqs.sh: which Python versions it accepts, and what it says otherwise.

The interpreters here are stand-ins (shell scripts answering the version question), so
the test needs no second Python; scripts/check_python312.sh (test_python312.py) builds
and tests a real 3.12 venv.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "check_prereqs.sh"


def fake_python(tmp_path: Path, version: str) -> Path:
    """An 'interpreter' that prints ``version`` for any -c program and succeeds."""
    path = tmp_path / f"python{version}"
    path.write_text(f"#!/bin/sh\necho {version}\n")
    path.chmod(0o755)
    return path


def run(python: Path | str) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", str(SCRIPT), str(python)], capture_output=True, text=True,
                          timeout=60)


@pytest.mark.parametrize("version", ["3.11", "3.12"])
def test_supported_versions_are_accepted(tmp_path, version):
    done = run(fake_python(tmp_path, version))
    assert "is Python" not in done.stderr, done.stderr
    if done.returncode == 0:  # the machine has cmake and compilers
        assert f"prerequisites ok: Python {version}" in done.stdout


@pytest.mark.parametrize("version", ["3.10", "3.13"])
def test_other_versions_are_refused_naming_the_supported_ones(tmp_path, version):
    done = run(fake_python(tmp_path, version))
    assert done.returncode == 1
    assert f"is Python {version}" in done.stderr
    assert "need Python 3.11 or 3.12" in done.stderr


def test_this_interpreter_passes_its_own_check():
    done = run(sys.executable)
    assert "is Python" not in done.stderr, done.stderr
