"""The lint gate: ruff (pinned in requirements-test.txt) with ruff.toml over the repository."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
RUFF_TIMEOUT_S = 120

pytestmark = pytest.mark.timeout(2 * RUFF_TIMEOUT_S)


def _ruff(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ruff", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=RUFF_TIMEOUT_S)


def test_repository_is_ruff_clean():
    """Every Python file of the repository (ruff.toml's excludes aside) passes ruff."""
    done = _ruff("check", "--config", str(ROOT / "ruff.toml"), "--no-cache",
                 "--output-format", "concise", ".")
    assert done.returncode == 0, "ruff findings:\n" + done.stdout + done.stderr


def test_gate_covers_the_package_tests_and_benchmarks():
    listed = _ruff("check", "--config", str(ROOT / "ruff.toml"), "--show-files", ".")
    assert listed.returncode == 0, listed.stderr
    files = {Path(line).resolve() for line in listed.stdout.split()}
    for folder in ("grasp_fc_ros", "test", "benchmarks", "scripts", "launch"):
        sources = set((ROOT / folder).rglob("*.py"))
        assert sources and sources <= files, (folder, sorted(map(str, sources - files)))


def test_config_reports_what_it_selects(tmp_path):
    """The repository's config finds unsorted imports and unused names (I, F)."""
    (tmp_path / "probe.py").write_text("import sys\nimport os\n\nx = os.sep\n")
    done = _ruff("check", "--config", str(ROOT / "ruff.toml"), "--no-cache",
                 "--output-format", "concise", "probe.py", cwd=tmp_path)
    assert done.returncode == 1, done.stdout + done.stderr
    assert "I001" in done.stdout and "F401" in done.stdout, done.stdout
