"""Packaging hygiene: package.xml declares what the code imports, LICENSE, CHANGELOG,
and a built wheel ships py.typed, the parameters file and the license."""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from catkin_pkg.changelog import get_changelog_from_path
from catkin_pkg.package import parse_package

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "grasp_fc_ros"

# Python modules that are not ROS packages: their rosdep key, or None where there is
# none and pip installs them (then requirements.txt must pin them).
PYTHON_KEYS = {
    "numpy": "python3-numpy",
    "scipy": "python3-scipy",
    "matplotlib": "python3-matplotlib",
    "mpl_toolkits": "python3-matplotlib",
    "tqdm": "python3-tqdm",
    "yaml": "python3-yaml",
    "clarabel": None,
    "numba": None,
    "trimesh": None,
    "dask": None,
    "distributed": None,
    "pyarrow": None,
}
# Interfaces the node needs before its code lands here (the action's goal
# status and cancel services).
REQUIRED_ANYWAY = {"rcl_interfaces", "visualization_msgs", "action_msgs"}


def _imported_modules() -> set[str]:
    """Top-level names of every absolute import in grasp_fc_ros/ (stdlib left out)."""
    names = set()
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names.update(alias.name.split(".")[0] for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module.split(".")[0])
    return names - set(sys.stdlib_module_names) - {"grasp_fc_ros"}


@pytest.fixture(scope="module")
def package():
    package = parse_package(str(ROOT / "package.xml"))
    package.validate()
    return package


def test_package_xml_declares_every_import(package):
    runtime = {d.name for d in package.exec_depends + package.build_export_depends
               + package.build_depends}
    for module in sorted(_imported_modules()):
        assert module in PYTHON_KEYS or module in runtime, (
            f"grasp_fc_ros imports {module}, which package.xml does not declare")
        key = PYTHON_KEYS.get(module)
        if module in PYTHON_KEYS and key is not None:
            assert key in runtime, f"{module}: add <exec_depend>{key}</exec_depend>"
    assert REQUIRED_ANYWAY <= runtime


def test_pip_only_dependencies_are_pinned():
    pinned = {line.split("==")[0].split("[")[0].strip().lower()
              for line in (ROOT / "requirements.txt").read_text().splitlines()
              if "==" in line and not line.lstrip().startswith("#")}
    for module, key in PYTHON_KEYS.items():
        if key is None:
            assert module in pinned, f"{module} has no rosdep key and no pin"


def test_license_file_is_apache_2(package):
    [license_] = package.licenses
    assert str(license_) == "Apache-2.0" and license_.file == "LICENSE"
    text = (ROOT / "LICENSE").read_text()
    assert "Apache License" in text and "Version 2.0, January 2004" in text
    assert "END OF TERMS AND CONDITIONS" in text


def test_setup_py_has_the_package_xml_version(package):
    assert f'version="{package.version}"' in (ROOT / "setup.py").read_text()


def test_changelog_parses_and_matches_the_version(package):
    changelog = get_changelog_from_path(str(ROOT / "CHANGELOG.rst"), package.name)
    # catkin_pkg keeps the sections oldest first: reversed, the file's order (newest first).
    versions = [version for version, _, _ in changelog.foreach_version(reverse=True)]
    assert versions and versions[0] == package.version


def test_interface_package_has_the_version_a_changelog_and_urls(package):
    """grasp_fc_msgs is released with grasp_fc_ros: same version, its own changelog; both
    name a website and the maintainers' address (no placeholder domain)."""
    interfaces = parse_package(str(ROOT / "msg_defs" / "package.xml"))
    interfaces.validate()
    assert interfaces.version == package.version
    changelog = get_changelog_from_path(str(ROOT / "msg_defs" / "CHANGELOG.rst"),
                                        interfaces.name)
    assert [version for version, _, _ in changelog.foreach_version(reverse=True)][0] == (
        package.version)
    for manifest in (package, interfaces):
        assert [url.type for url in manifest.urls] == ["website"]
        assert (ROOT / manifest.urls[0].url).is_file(), manifest.urls[0].url
        assert [m.email for m in manifest.maintainers] == [
            "maintainers@users.noreply.h-seed-30dcbcef.example"]


@pytest.mark.timeout(300)
def test_wheel_ships_types_params_and_license(tmp_path):
    # Built from a copy: setuptools leaves build/ behind, whose stale files a later
    # build of the work tree would ship.
    source = tmp_path / "src"
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(
        ".*", "build", "install", "log", "*.egg-info", "__pycache__", "bench_out", "docs"))
    build = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
         "--disable-pip-version-check", "-q", "-w", str(tmp_path), str(source)],
        capture_output=True, text=True, timeout=240)
    assert build.returncode == 0, build.stderr
    [wheel] = tmp_path.glob("grasp_fc_ros-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    data = next(n.split("/")[0] for n in names if ".data/" in n)
    for expected in ("grasp_fc_ros/py.typed", "grasp_fc_ros/markers/build.py",
                     "grasp_fc_ros/node/__main__.py", "grasp_fc_ros/engine/worker.py",
                     f"{data}/data/share/grasp_fc_ros/config/force_closure.yaml",
                     f"{data}/data/share/grasp_fc_ros/package.xml",
                     f"{data}/data/share/grasp_fc_ros/LICENSE"):
        assert expected in names, f"{expected} missing from {wheel.name}"
    assert not any(n.startswith("test/") for n in names)
