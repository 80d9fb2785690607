"""The documentation site: it builds with warnings as errors, renders the public API, and
its generated node reference agrees with a running node.

docs/_ext/grasp_fc_docs.py declares the node's topics, services, action and diagnostics
keys (the parameters and QoS it reads from the code); these tests compare the
declarations with a live node's graph and status, both ways, so the page cannot drift.
"""

from __future__ import annotations

import importlib.util
import os
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
sys.path.insert(0, str(DOCS / "_ext"))
import grasp_fc_docs  # noqa: E402 - the Sphinx extension under test

if TYPE_CHECKING:
    from rclpy.node import Node

SPHINX_TIMEOUT_S = 300
# Discovery of the helper nodes and of the marker process (a process of its own that
# compiles or loads the core before it publishes).
GRAPH_TIMEOUT_S = 60.0
# Names every rclpy node has besides its own interface.
STANDARD_TOPICS = {"/rosout", "/parameter_events"}
PARAMETER_SERVICES = ("describe_parameters", "get_parameters", "get_parameter_types",
                      "list_parameters", "set_parameters", "set_parameters_atomically",
                      "get_type_description")
# The anchors docs/performance.md must have: code comments point at them.
PERFORMANCE_ANCHORS = (
    "exact-stage", "one-grasp", "filter", "epsilon", "minimum-friction", "contact-forces",
    "worker-chunks", "worker-pool", "single-topic", "batch-topic", "service-latency",
    "wire-format", "markers", "labelling", "action", "soak", "clients")
# Where pointers such as docs/performance.md#worker-chunks may be written.
POINTER_SOURCES = ("grasp_fc_ros", "benchmarks", "docs", "test", "scripts", "README.md",
                   "CHANGELOG.rst", "Makefile")


def github_slug(heading: str) -> str:
    """The anchor GitHub (and MyST's heading anchors) give a Markdown heading."""
    slug = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return slug.replace(" ", "-")


def markdown_anchors(path: Path) -> set[str]:
    """Anchors of a Markdown file's headings (code blocks skipped)."""
    anchors, fenced = set(), False
    for line in path.read_text().splitlines():
        if line.startswith("```"):
            fenced = not fenced
        elif not fenced and line.startswith("#"):
            anchors.add(github_slug(line.lstrip("#")))
    return anchors


@pytest.mark.timeout(SPHINX_TIMEOUT_S)
def test_docs_build_with_warnings_as_errors_and_render_the_api(tmp_path: Path) -> None:
    if importlib.util.find_spec("sphinx") is None:
        pytest.skip("sphinx is not installed (requirements-test.txt pins it: make setup-test)")
    out = tmp_path / "html"
    done = subprocess.run(
        [sys.executable, "-m", "sphinx", "-E", "-a", "-W", "--keep-going", "-q", "-b", "html",
         "-d", str(tmp_path / "doctrees"), str(DOCS), str(out)],
        capture_output=True, text=True, timeout=SPHINX_TIMEOUT_S)
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-8000:]
    import grasp_fc_ros.core as core
    import grasp_fc_ros.labelling as labelling

    core_page = (out / "api" / "core.html").read_text()
    for name in core.__all__:
        assert f'id="grasp_fc_ros.core.{name}"' in core_page, f"core.{name} not rendered"
    labelling_page = (out / "api" / "labelling.html").read_text()
    for name in labelling.__all__:
        assert f'id="grasp_fc_ros.labelling.{name}"' in labelling_page, name
    assert 'id="grasp_fc_ros.client.GraspClient"' in (out / "api" / "client.html").read_text()
    import grasp_fc_ros.objects as objects

    objects_page = (out / "api" / "objects.html").read_text()
    for name in objects.__all__:
        assert f'id="grasp_fc_ros.objects.{name}"' in objects_page, f"objects.{name}"
    node_page = (out / "node.html").read_text()
    from grasp_fc_ros.node import PARAMETERS

    for name in PARAMETERS:
        assert f"<span class=\"pre\">{name}</span>" in node_page, f"parameter {name} missing"
    for definition in (ROOT / "msg_defs").glob("*/*.*"):
        if definition.suffix in (".msg", ".srv", ".action"):
            assert f"grasp_fc_msgs/{definition.suffix[1:]}/{definition.stem}" in \
                (out / "interfaces.html").read_text()
    for page in ("performance", "install", "markers", "labelling", "quality", "soft_fingers",
                 "objects"):
        assert (out / f"{page}.html").is_file(), page


def test_performance_page_has_the_agreed_anchors() -> None:
    anchors = markdown_anchors(DOCS / "performance.md")
    missing = [a for a in PERFORMANCE_ANCHORS if a not in anchors]
    assert not missing, f"docs/performance.md lacks sections for #{', #'.join(missing)}"


def test_every_pointer_into_performance_md_has_its_section() -> None:
    anchors = markdown_anchors(DOCS / "performance.md")
    pointer = re.compile(r"performance\.md#([\w-]+)")
    dangling = []
    for source in POINTER_SOURCES:
        path = ROOT / source
        files = [path] if path.is_file() else [
            p for p in path.rglob("*") if p.suffix in (".py", ".md", ".rst", ".txt")]
        for file in files:
            for anchor in pointer.findall(file.read_text(errors="replace")):
                if anchor not in anchors:
                    dangling.append(f"{file.relative_to(ROOT)}: #{anchor}")
    assert not dangling, "pointers to missing sections: " + ", ".join(dangling)


def _graph(probe: Node, namespace: str, node_name: str) -> set[tuple[str, str, str]]:
    """(fully qualified name, kind, type) of what node ``namespace/node_name`` offers."""
    from rclpy.action import get_action_server_names_and_types_by_node

    found: set[tuple[str, str, str]] = set()
    queries = (("publisher", probe.get_publisher_names_and_types_by_node),
               ("subscription", probe.get_subscriber_names_and_types_by_node),
               ("service", probe.get_service_names_and_types_by_node))
    for kind, query in queries:
        try:
            entries = query(node_name, namespace)
        except Exception:  # noqa: BLE001 - the node is not discovered yet
            continue
        for name, types in entries:
            if name in STANDARD_TOPICS or "/_action/" in name or \
                    name.rsplit("/", 1)[-1] in PARAMETER_SERVICES:
                continue
            found.update((name, kind, t) for t in types)
    try:
        actions = get_action_server_names_and_types_by_node(probe, node_name, namespace)
    except Exception:  # noqa: BLE001 - not discovered yet
        actions = []
    found.update((name, "action", t) for name, types in actions for t in types)
    return found


def _declared(namespace: str) -> dict[str, set[tuple[str, str, str]]]:
    """Node name -> (fully qualified name, kind, type) as the reference page lists them."""
    declared: dict[str, set] = {}
    for e in grasp_fc_docs.INTERFACES:
        node = e.node.format(name=grasp_fc_docs.DEFAULT_NODE_NAME)
        name = e.name if e.name.startswith("/") else f"{namespace}/{e.name}"
        declared.setdefault(node, set()).add((name, e.kind, e.type))
    return declared


@pytest.mark.timeout(180)
def test_node_reference_lists_exactly_what_a_running_node_offers(own_node: Callable) -> None:
    namespace = "/docs_reference"
    node, _spinner, client = own_node(namespace, workers=0, publish_markers=True)
    assert node.get_name() == grasp_fc_docs.DEFAULT_NODE_NAME
    declared = _declared(namespace)
    deadline = time.monotonic() + GRAPH_TIMEOUT_S
    while True:
        live = {name: _graph(client.node, namespace, name) for name in declared}
        if live == declared or time.monotonic() > deadline:
            break
        time.sleep(0.25)
    for name in declared:
        assert live[name] == declared[name], (
            f"node {namespace}/{name}: documented but not offered "
            f"{sorted(declared[name] - live[name])}; offered but not documented "
            f"{sorted(live[name] - declared[name])} (update INTERFACES in "
            "docs/_ext/grasp_fc_docs.py)")


@pytest.mark.timeout(120)
def test_diagnostics_keys_are_the_documented_ones(own_node: Callable) -> None:
    node, _spinner, client = own_node("/docs_diagnostics", workers=0, publish_markers=True)
    documented = {key for key, _ in grasp_fc_docs.DIAGNOSTIC_KEYS}
    deadline = time.monotonic() + GRAPH_TIMEOUT_S
    while True:  # the marker keys appear once the marker process is up
        keys = set(client.diagnostics_after(time.time(), f"/docs_diagnostics/{node.get_name()}"))
        if keys == documented or time.monotonic() > deadline:
            break
    assert keys == documented, (f"not documented: {sorted(keys - documented)}; "
                                f"documented but not sent: {sorted(documented - keys)}")
    assert set(grasp_fc_docs.MARKER_DIAGNOSTIC_KEYS) <= documented


def test_documented_qos_is_the_code_profiles() -> None:
    """Every topic's QoS resolves to the profile object the code uses."""
    for endpoint in grasp_fc_docs.INTERFACES:
        profile = grasp_fc_docs.resolve_qos(endpoint)
        if endpoint.kind in ("publisher", "subscription"):
            assert profile is not None, endpoint.name
            assert grasp_fc_docs.describe_qos(profile).startswith("reliable")


def test_a_symlink_to_msg_defs_lets_a_plain_colcon_crawl_find_both_packages(
        tmp_path: Path) -> None:
    """docs/install.md's alternative to --base-paths: ln -s grasp_fc_ros/msg_defs src/."""
    colcon = Path(sys.executable).parent / "colcon"
    if not colcon.exists():
        message = f"colcon is not installed next to {sys.executable} (`make test` installs it)"
        if os.environ.get("GRASP_FC_REQUIRE_COLCON"):
            pytest.fail(message)
        pytest.skip(message)
    src = tmp_path / "src"
    shutil.copytree(ROOT / "msg_defs", src / "grasp_fc_ros" / "msg_defs")
    for name in ("package.xml", "setup.py", "setup.cfg"):
        shutil.copy(ROOT / name, src / "grasp_fc_ros" / name)
    (src / "grasp_fc_msgs").symlink_to("grasp_fc_ros/msg_defs")
    env = dict(os.environ, COLCON_HOME=str(tmp_path / "colcon_home"))
    done = subprocess.run([str(colcon), "list", "--topological-order", "--names-only"],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["grasp_fc_msgs", "grasp_fc_ros"]
