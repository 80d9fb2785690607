"""launch/force_closure.launch.py and rviz/force_closure.rviz: they name only what exists,
and setup.py installs them where `ros2 launch` and the launch file look.

launch and launch_ros are not on PyPI (no ros-jazzy-launch* wheels), so the test that
generates the launch description runs only where they are importable (a ROS install);
the others read the files as data and run everywhere.
"""

from __future__ import annotations

import ast
import importlib.util
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path
from typing import Any

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
LAUNCH_FILE = ROOT / "launch" / "force_closure.launch.py"
RVIZ_FILE = ROOT / "rviz" / "force_closure.rviz"
PACKAGE = "grasp_fc_ros"
# The arguments issue 23 asks the launch file to take.
REQUIRED_ARGUMENTS = {"params_file", "namespace", "node_name", "use_sim_time",
                      "publish_markers", "rviz"}
# Parameters every ROS 2 node has besides its own.
ROS_PARAMETERS = {"use_sim_time"}
# Executables of other packages the launch file may start.
OTHER_EXECUTABLES = {("rviz2", "rviz2")}


def _console_scripts() -> set[str]:
    """The console script names setup.py declares."""
    tree = ast.parse((ROOT / "setup.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Dict):
            for key, value in zip(node.keys, node.values, strict=True):
                if isinstance(key, ast.Constant) and key.value == "console_scripts" and \
                        isinstance(value, ast.List):
                    return {ast.literal_eval(item).split("=")[0].strip()
                            for item in value.elts}
    raise AssertionError("setup.py declares no console_scripts")


def _launch_tree() -> tuple[ast.Module, dict[str, Any]]:
    """The launch file's AST and its module-level string constants."""
    tree = ast.parse(LAUNCH_FILE.read_text(), str(LAUNCH_FILE))
    constants = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and isinstance(node.value, ast.Constant):
            for target in node.targets:
                if isinstance(target, ast.Name):
                    constants[target.id] = node.value.value
    return tree, constants


def _value(node: ast.expr | None, constants: dict[str, Any]) -> Any:
    """A keyword's value when it is a constant or a module-level constant, else None."""
    if isinstance(node, ast.Constant):
        return node.value
    if isinstance(node, ast.Name):
        return constants.get(node.id)
    return None


def _calls(tree: ast.AST, name: str) -> list[ast.Call]:
    return [n for n in ast.walk(tree) if isinstance(n, ast.Call)
            and isinstance(n.func, ast.Name) and n.func.id == name]


def _declared_arguments(tree: ast.AST, constants: dict[str, Any]) -> dict[str, Any]:
    """DeclareLaunchArgument name -> default value."""
    declared = {}
    for call in _calls(tree, "DeclareLaunchArgument"):
        name = _value(call.args[0], constants)
        defaults = [k.value for k in call.keywords if k.arg == "default_value"]
        assert name is not None, f"line {call.lineno}: argument name is not a constant"
        declared[name] = defaults[0] if defaults else None
    return declared


def test_launch_file_declares_the_documented_arguments() -> None:
    tree, constants = _launch_tree()
    declared = _declared_arguments(tree, constants)
    assert REQUIRED_ARGUMENTS <= set(declared), REQUIRED_ARGUMENTS - set(declared)
    used = {_value(call.args[0], constants) for call in _calls(tree, "LaunchConfiguration")}
    assert used <= set(declared), f"LaunchConfiguration of undeclared {used - set(declared)}"
    assert set(declared) <= used, f"declared but unused: {set(declared) - used}"


def test_launch_file_starts_only_existing_executables() -> None:
    tree, constants = _launch_tree()
    scripts = _console_scripts()
    started = []
    for call in _calls(tree, "Node"):
        keywords = {k.arg: _value(k.value, constants) for k in call.keywords}
        package, executable = keywords.get("package"), keywords.get("executable")
        assert package and executable, f"line {call.lineno}: package/executable not constant"
        if package == PACKAGE:
            assert executable in scripts, f"{executable} is not a console script of setup.py"
        else:
            assert (package, executable) in OTHER_EXECUTABLES, (package, executable)
        started.append((package, executable))
    assert (PACKAGE, "grasp-fc-node") in started


def test_launch_file_sets_only_parameters_the_node_has() -> None:
    from grasp_fc_ros.node import PARAMETERS

    tree, constants = _launch_tree()
    node_call = next(c for c in _calls(tree, "Node")
                     if any(k.arg == "executable" and _value(k.value, constants) == "grasp-fc-node"
                            for k in c.keywords))
    [parameters] = [k.value for k in node_call.keywords if k.arg == "parameters"]
    names = {_value(key, constants) for d in ast.walk(parameters) if isinstance(d, ast.Dict)
             for key in d.keys}
    assert names, "the node gets no parameter from the launch arguments"
    assert names <= set(PARAMETERS) | ROS_PARAMETERS, names - set(PARAMETERS) - ROS_PARAMETERS


def test_launch_defaults_name_installed_files() -> None:
    """The default params file and the RViz config are files setup.py installs."""
    setup = (ROOT / "setup.py").read_text()
    source = LAUNCH_FILE.read_text()
    for installed in ("config/force_closure.yaml", "rviz/force_closure.rviz"):
        assert f"/{installed}" in source, f"the launch file does not use {installed}"
        assert (ROOT / installed).is_file()
        assert f'"{installed}"' in setup, f"setup.py does not install {installed}"


def test_rviz_config_shows_the_node_markers() -> None:
    sys.path.insert(0, str(ROOT / "docs" / "_ext"))
    try:
        from grasp_fc_docs import INTERFACES, describe_qos, resolve_qos
    finally:
        sys.path.pop(0)
    config = yaml.safe_load(RVIZ_FILE.read_text())
    manager = config["Visualization Manager"]
    [display] = [d for d in manager["Displays"]
                 if d["Class"] == "rviz_default_plugins/MarkerArray"]
    assert display["Enabled"] is True
    markers = next(e for e in INTERFACES if e.name == "markers")
    assert display["Topic"]["Value"] == "/" + markers.name
    # RViz subscribes with the QoS of the marker process's publisher.
    qos = resolve_qos(markers)
    assert display["Topic"]["Reliability Policy"].lower() == qos.reliability.name.lower()
    assert display["Topic"]["Durability Policy"].lower().replace(" ", "_") == \
        qos.durability.name.lower()
    assert display["Topic"]["Depth"] == qos.depth, describe_qos(qos)
    _, constants = _launch_tree()
    assert manager["Global Options"]["Fixed Frame"] == constants["FIXED_FRAME"]


def test_package_xml_declares_what_the_launch_file_needs() -> None:
    from catkin_pkg.package import parse_package

    package = parse_package(str(ROOT / "package.xml"))
    runtime = {d.name for d in package.exec_depends}
    assert {"launch", "launch_ros", "ament_index_python", "rviz2"} <= runtime


@pytest.mark.timeout(300)
def test_setup_py_installs_the_launch_file_and_rviz_config(tmp_path: Path) -> None:
    # Built from a copy, as test_packaging does: setuptools leaves build/ behind.
    source = tmp_path / "src"
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(
        ".*", "build", "install", "log", "*.egg-info", "__pycache__", "bench_out", "docs",
        "test"))
    build = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
         "--disable-pip-version-check", "-q", "-w", str(tmp_path), str(source)],
        capture_output=True, text=True, timeout=240)
    assert build.returncode == 0, build.stderr
    [wheel] = tmp_path.glob("grasp_fc_ros-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    data = next(n.split("/")[0] for n in names if ".data/" in n)
    for installed in ("launch/force_closure.launch.py", "rviz/force_closure.rviz"):
        assert f"{data}/data/share/{PACKAGE}/{installed}" in names, f"{installed} not installed"


def test_launch_description_generates_where_launch_ros_is_installed(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    try:
        from launch.actions import DeclareLaunchArgument
        from launch_ros.actions import Node
    except ImportError as exc:  # a bare launch/ here is this repository's folder
        pytest.skip(f"launch and launch_ros are not importable here ({exc}): they are not on "
                    "PyPI (no ros-jazzy-launch* wheels), only in a ROS 2 install; the other "
                    "tests of this file check the launch file as data")

    # The launch file finds its share folder through the ament index: give it this
    # checkout's files as an installed package.
    prefix = tmp_path / "prefix"
    share = prefix / "share" / PACKAGE
    (prefix / "share" / "ament_index" / "resource_index" / "packages").mkdir(parents=True)
    (prefix / "share" / "ament_index" / "resource_index" / "packages" / PACKAGE).touch()
    for folder in ("config", "launch", "rviz"):
        shutil.copytree(ROOT / folder, share / folder)
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(prefix))
    spec = importlib.util.spec_from_file_location("force_closure_launch", LAUNCH_FILE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    description = module.generate_launch_description()
    declared = {a.name for a in description.entities if isinstance(a, DeclareLaunchArgument)}
    assert REQUIRED_ARGUMENTS <= declared
    nodes = [e for e in description.entities if isinstance(e, Node)]
    executables = {(n.node_package, n.node_executable) for n in nodes}
    assert executables == {(PACKAGE, "grasp-fc-node"), *OTHER_EXECUTABLES}
    assert "grasp-fc-node" in _console_scripts()
