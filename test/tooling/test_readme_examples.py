"""The README's examples work as written, in the setup it describes.

Every ```python and ```sh block of the README runs, in README order, with a node running
for the client examples: Python blocks in a fresh interpreter, shell blocks in bash, both
in one folder standing for the repository's (it holds a link to this venv as ``.venv``,
so ``.venv/bin/grasp-fc-...`` runs as the README writes it; the labelling blocks share
their files there) and ``make`` commands in the repository itself. A ``# -> text``
comment is output the block must print. Not run, and said so: ``make test`` (the suite
running this test), and the blocks the README marks ``<!-- readme-examples: not run
(reason) -->`` on the line before them, which must be the ones that need the ``ros2`` CLI
or an apt ROS install (the CLI is not on PyPI). Of those, every name they use must
exist (topics, services, action, types, executables, parameters, launch arguments, make
targets), and the payloads of ``ros2 topic pub`` and ``ros2 service call`` are sent to
the node as those commands would send them, and must be answered as the README says. The
Python blocks of the ROS-free guides (docs/core.md, docs/soft_fingers.md,
docs/objects.md, docs/robustness.md) run too.
"""

from __future__ import annotations

import importlib
import os
import re
import shlex
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
# Guides whose Python blocks are ROS-free and self-contained.
GUIDES_WITH_RUNNABLE_PYTHON = (ROOT / "docs" / "core.md", ROOT / "docs" / "soft_fingers.md",
                               ROOT / "docs" / "objects.md", ROOT / "docs" / "robustness.md")
# Documents whose shell blocks are checked for the names they use.
SHELL_DOCUMENTS = (README, ROOT / "docs" / "install.md", ROOT / "docs" / "markers.md",
                   ROOT / "docs" / "params.md", ROOT / "docs" / "labelling.md",
                   ROOT / "docs" / "client.md")
# The limits: at most 300 lines; the four uses on the first screens.
MAX_README_LINES = 300
FIRST_SCREENS_LINES = 160
EXAMPLE_TIMEOUT_S = 180
REPLY_TIMEOUT_S = 30.0
EXPECTED_OUTPUT = re.compile(r"#\s*->\s*(.+?)\s*$")
# The marker of a README block the tests do not run, on the line before its fence.
NOT_RUN = re.compile(r"^<!-- readme-examples: not run \((.+)\) -->$")
# What only a ROS 2 install has (the ros2 CLI, apt's setup file): the marked blocks'.
NEEDS_ROS_INSTALL = re.compile(r"^\s*ros2 |/opt/ros/", re.M)
# The one README command never run here, and why.
SUITE_ITSELF = (["make", "test"], "the test suite that runs this test")

sys.path.insert(0, str(ROOT / "docs" / "_ext"))
import grasp_fc_docs  # noqa: E402 - the node reference's interface table


def code_blocks(path: Path) -> list[tuple[str, str, int]]:
    """(language, code, first line number) of every fenced block of a Markdown file."""
    blocks, lines = [], path.read_text().splitlines()
    i = 0
    while i < len(lines):
        match = re.match(r"^(\s*)```(\S*)", lines[i])
        if match:
            indent, language, start = len(match.group(1)), match.group(2), i + 1
            i += 1
            body = []
            while not re.match(r"^\s*```\s*$", lines[i]):
                body.append(lines[i][indent:])
                i += 1
            blocks.append((language, "\n".join(body) + "\n", start + 1))
        i += 1
    return blocks


def expected_outputs(code: str) -> list[str]:
    return [m.group(1) for line in code.splitlines()
            if (m := EXPECTED_OUTPUT.search(line))]


def _normalised(text: str) -> str:
    return " ".join(text.split())


def assert_prints_in_order(stdout: str, expected: list[str], where: str) -> None:
    lines = [_normalised(line) for line in stdout.splitlines()]
    position = 0
    for text in expected:
        wanted = _normalised(text)
        hits = [i for i in range(position, len(lines)) if wanted in lines[i]]
        assert hits, f"{where}: expected output {text!r} not printed; output:\n{stdout}"
        position = hits[0] + 1


def _commands(code: str) -> list[list[str]]:
    """Shell commands of a block: continuation lines and multi-line quotes joined, then
    split at ``&&``; comments dropped."""
    commands, pending = [], ""
    for line in code.splitlines():
        pending += line + "\n"
        if pending.rstrip().endswith("\\"):
            pending = pending.rstrip()[:-1] + " "
            continue
        try:
            tokens = shlex.split(pending, comments=True)
        except ValueError:  # an open quote: the command goes on
            continue
        pending = ""
        command: list[str] = []
        for token in tokens + ["&&"]:
            if token in ("&&", "||", ";", "&"):
                if command:
                    commands.append(command)
                command = []
            else:
                command.append(token)
    assert not pending.strip(), f"unterminated command: {pending!r}"
    return commands


# --- what the names must match ----------------------------------------------------------

def _console_scripts() -> set[str]:
    text = (ROOT / "setup.py").read_text()
    return set(re.findall(r'"([\w-]+) = grasp_fc_ros[\w.]*:\w+"', text))


def _make_targets() -> set[str]:
    return set(re.findall(r"^([\w-]+):", (ROOT / "Makefile").read_text(), re.M))


def _launch_arguments() -> set[str]:
    text = (ROOT / "launch" / "force_closure.launch.py").read_text()
    return set(re.findall(r'DeclareLaunchArgument\(\s*"(\w+)"', text))


def _parameters() -> set[str]:
    from grasp_fc_ros.node import PARAMETERS

    return set(PARAMETERS)


def _interface(name: str, kinds: tuple[str, ...]) -> grasp_fc_docs.Endpoint:
    bare = name.lstrip("/")
    found = [e for e in grasp_fc_docs.INTERFACES
             if e.kind in kinds and e.name.lstrip("/") == bare]
    assert found, f"{name} is not a {' or '.join(kinds)} of the node"
    return found[0]


def _pins() -> dict[str, str]:
    pins = {}
    for line in (ROOT / "requirements.txt").read_text().splitlines():
        if "==" in line and not line.lstrip().startswith("#"):
            name, version = line.split("==")
            pins[name.split("[")[0].strip().lower()] = version.strip()
    return pins


def _check_ros_arguments(arguments: list[str], where: str) -> None:
    for i, token in enumerate(arguments):
        if token == "-p":
            name = arguments[i + 1].split(":=")[0]
            assert name in _parameters() or name == "use_sim_time", \
                f"{where}: no parameter {name}"


def check_command(command: list[str], where: str, payloads: list) -> None:
    """Fail if ``command`` names something that does not exist; collect payloads."""
    program, args = command[0], command[1:]
    if program == "make":
        for target in args:
            if "=" not in target:
                assert target in _make_targets(), f"{where}: no make target {target}"
    elif program.startswith("grasp-fc-") or program.startswith(".venv/bin/grasp-fc-"):
        assert program.rsplit("/", 1)[-1] in _console_scripts(), f"{where}: {program}"
        _check_ros_arguments(args, where)
    elif program == "pip" or program.endswith("/pip"):
        for requirement in args:
            if "==" in requirement:
                name, version = requirement.split("==")
                assert _pins().get(name.lower()) == version, (
                    f"{where}: {requirement} differs from requirements.txt")
    elif program == "colcon" or (program == "python" and args[:2] == ["-m", "colcon"]):
        paths = [a for a in args if a.startswith("src/grasp_fc_ros/")]
        for path in paths:
            assert (ROOT / path.removeprefix("src/grasp_fc_ros/")).is_dir(), f"{where}: {path}"
    elif program == "ros2":
        check_ros2(args, where, payloads)


# Options of the ros2 verbs used in the docs that take a value.
ROS2_OPTIONS_WITH_VALUE = {"--wait-matching-subscriptions", "-w", "--max-wait-time-secs",
                           "--qos-profile", "--qos-depth", "--qos-history",
                           "--qos-reliability", "--qos-durability", "-r", "--rate", "-t",
                           "--times", "-n", "--node-name", "-p", "--print", "--keep-alive"}


def _positional(args: list[str]) -> list[str]:
    """The arguments that are neither options nor option values."""
    found, skip = [], False
    for arg in args:
        if skip:
            skip = False
        elif arg in ROS2_OPTIONS_WITH_VALUE:
            skip = True
        elif not arg.startswith("-"):
            found.append(arg)
    return found


def check_ros2(args: list[str], where: str, payloads: list) -> None:
    verb = args[:2]
    positional = _positional(args[2:])
    if verb == ["run", "grasp_fc_ros"]:
        assert args[2] in _console_scripts(), f"{where}: no executable {args[2]}"
        _check_ros_arguments(args[3:], where)
    elif verb == ["launch", "grasp_fc_ros"]:
        assert (ROOT / "launch" / args[2]).is_file(), f"{where}: no launch file {args[2]}"
        for argument in args[3:]:
            assert argument.split(":=")[0] in _launch_arguments(), f"{where}: {argument}"
    elif verb == ["topic", "pub"]:
        topic, type_name, payload = positional[:3]
        endpoint = _interface(topic, ("subscription",))
        assert endpoint.type == type_name, f"{where}: {topic} takes {endpoint.type}"
        payloads.append(("topic", endpoint, yaml.safe_load(payload), where))
    elif verb == ["topic", "echo"]:
        _interface(positional[0], ("publisher",))
    elif verb == ["service", "call"]:
        name, type_name, payload = positional[:3]
        endpoint = _interface(name, ("service",))
        assert endpoint.type == type_name, f"{where}: {name} is a {endpoint.type}"
        payloads.append(("service", endpoint, yaml.safe_load(payload), where))
    elif verb == ["action", "send_goal"]:
        name, type_name, payload = positional[:3]
        endpoint = _interface(name, ("action",))
        assert endpoint.type == type_name, f"{where}: {name} is a {endpoint.type}"
        payloads.append(("action", endpoint, yaml.safe_load(payload), where))
    elif verb[0] == "param":
        node = positional[0]
        assert node.rsplit("/", 1)[-1] == grasp_fc_docs.DEFAULT_NODE_NAME, f"{where}: {node}"
        for parameter in positional[1:2]:
            assert parameter in _parameters(), f"{where}: no parameter {parameter}"


def shell_blocks() -> Iterator[tuple[Path, str, int]]:
    for document in SHELL_DOCUMENTS:
        for language, code, line in code_blocks(document):
            if language in ("sh", "bash"):
                yield document, code, line


# --- filling messages as the ros2 CLI does ----------------------------------------------

def message_class(type_name: str) -> Any:
    """grasp_fc_msgs/msg/ContactArray -> the class; .../srv/X -> its Request;
    .../action/X -> its Goal."""
    package, kind, name = type_name.split("/")
    cls = getattr(importlib.import_module(f"{package}.{kind}"), name)
    return {"msg": cls, "srv": getattr(cls, "Request", None),
            "action": getattr(cls, "Goal", None)}[kind]


def _element_class(msg: Any, field: str) -> Any:
    slot = msg.__slots__.index(f"_{field}")
    value_type = msg.SLOT_TYPES[slot].value_type
    module = importlib.import_module(".".join(value_type.namespaces))
    return getattr(module, value_type.name)


def fill(msg: Any, values: dict) -> Any:
    """Set ``msg``'s fields from a YAML mapping, as ``ros2 topic pub`` does (numbers
    given as integers for floating-point fields become floats)."""
    fields = msg.get_fields_and_field_types()
    for key, value in values.items():
        assert key in fields, f"{type(msg).__name__} has no field {key!r}"
        kind = fields[key]
        if isinstance(value, dict):
            fill(getattr(msg, key), value)
        elif isinstance(value, list) and value and isinstance(value[0], dict):
            setattr(msg, key, [fill(_element_class(msg, key)(), v) for v in value])
        elif kind in ("double", "float") and isinstance(value, int):
            setattr(msg, key, float(value))
        elif kind.startswith(("sequence<double", "sequence<float")):
            setattr(msg, key, [float(v) for v in value])
        else:
            setattr(msg, key, value)
    return msg


# --- the node the examples talk to -------------------------------------------------------

@pytest.fixture(scope="module")
def readme_node(ros: None) -> Iterator[Any]:
    """A force_closure node in the root namespace, as the README's examples expect."""
    from rclpy.parameter import Parameter

    from grasp_fc_ros.node import ForceClosureNode
    from ros_fixtures import SpinThread

    node = ForceClosureNode(parameter_overrides=[Parameter("workers", value=0)])
    spinner = SpinThread(node)
    yield node
    spinner.stop()


@pytest.fixture(scope="module")
def example_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("readme_examples")


def _run(args: list[str], cwd: Path, where: str) -> str:
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}"
                                f"{os.environ.get('PATH', '')}")
    done = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=EXAMPLE_TIMEOUT_S)
    assert done.returncode == 0, (f"{where} exited {done.returncode}:\n"
                                  f"{done.stdout[-3000:]}\n{done.stderr[-5000:]}")
    return done.stdout


def not_run_reason(path: Path, line: int) -> str | None:
    """The reason given on the line before the fence of the block whose code starts at
    ``line`` (1-based), if the block is marked not to be run."""
    lines = path.read_text().splitlines()
    match = NOT_RUN.match(lines[line - 3]) if line >= 3 else None
    return match.group(1) if match else None


def _runnable_readme_blocks() -> Iterator[Any]:
    """The README's python and sh blocks that are not marked, in order."""
    for language, code, line in code_blocks(README):
        if language in ("python", "sh") and not_run_reason(README, line) is None:
            yield pytest.param(language, code, id=f"README.md:{line}")


def _venv_folder(example_dir: Path) -> Path:
    """``example_dir`` with ``.venv`` linked to this interpreter's venv, as the README's
    repository folder has it."""
    if sys.prefix == sys.base_prefix:
        pytest.skip("the README's .venv/bin commands need the tests to run in a venv")
    link = example_dir / ".venv"
    if not link.exists():
        link.symlink_to(sys.prefix)
    return example_dir


def _shell_block(code: str, example_dir: Path) -> tuple[str, Path]:
    """The commands of a README shell block to run, and where: ``make`` in the
    repository (only in its own .venv, which the Makefile would otherwise build), the
    others in the example folder; ``make test`` left out."""
    commands = _commands(code)
    run = [c for c in commands if c != SUITE_ITSELF[0]]
    if run and all(c[0] == "make" for c in run):
        if Path(sys.prefix).resolve() != (ROOT / ".venv").resolve():
            pytest.skip(f"make targets build {ROOT / '.venv'}; these tests run in {sys.prefix}")
        return " && ".join(shlex.join(c) for c in run), ROOT
    assert not any(c[0] == "make" for c in run), "a block mixes make and other commands"
    assert run == commands, f"{SUITE_ITSELF[0]} beside other commands"
    return code, _venv_folder(example_dir)


# --- the tests ---------------------------------------------------------------------------

def test_readme_is_short_and_shows_the_four_uses_first() -> None:
    lines = README.read_text().splitlines()
    assert len(lines) <= MAX_README_LINES, f"README.md has {len(lines)} lines"
    first = "\n".join(lines[:FIRST_SCREENS_LINES])
    for use in ("ros2 topic pub", "ros2 service call", "GraspClient(",
                "from grasp_fc_ros.core import", "grasp-fc-label ", "make demo", "make test"):
        assert use in first, f"{use!r} is not in the README's first {FIRST_SCREENS_LINES} lines"
    assert "wait_for_node" in first and "raise SystemExit" in first


@pytest.mark.timeout(EXAMPLE_TIMEOUT_S * 2)
@pytest.mark.parametrize("language,code", list(_runnable_readme_blocks()))
def test_readme_example_runs(language: str, code: str, readme_node: Any, example_dir: Path,
                             request: pytest.FixtureRequest) -> None:
    where = request.node.callspec.id
    if language == "python":
        stdout = _run([sys.executable, "-c", code], example_dir, where)
    else:
        script, folder = _shell_block(code, example_dir)
        stdout = _run(["bash", "-euo", "pipefail", "-c", script], folder, where)
    assert_prints_in_order(stdout, expected_outputs(code), where)


def test_only_blocks_that_need_a_ros_install_are_marked_not_run() -> None:
    """A marker cannot hide a runnable block; every block is run or marked with why."""
    marked = []
    for language, code, line in code_blocks(README):
        reason = not_run_reason(README, line)
        if reason is not None:
            assert NEEDS_ROS_INSTALL.search(code), f"README.md:{line} runs here: {reason}"
            marked.append(line)
        else:
            assert language in ("python", "sh"), f"README.md:{line}: a ```{language} block"
    assert len(marked) == 3, marked  # the workspace, ros2 topic and ros2 service blocks


@pytest.mark.timeout(EXAMPLE_TIMEOUT_S)
@pytest.mark.parametrize("path,code", [
    pytest.param(path, code, id=f"{path.name}:{line}")
    for path in GUIDES_WITH_RUNNABLE_PYTHON
    for language, code, line in code_blocks(path) if language == "python"])
def test_guide_python_example_runs(path: Path, code: str, tmp_path: Path) -> None:
    # A guide's later block may continue its first one (same names).
    blocks = [c for language, c, _ in code_blocks(path) if language == "python"]
    prefix = "".join(blocks[:blocks.index(code)])
    stdout = _run([sys.executable, "-c", prefix + code], tmp_path, path.name)
    expected = expected_outputs(prefix + code)
    assert_prints_in_order(stdout, expected, path.name)


@pytest.mark.parametrize("document,code,line", [
    pytest.param(document, code, line, id=f"{document.name}:{line}")
    for document, code, line in shell_blocks()])
def test_shell_example_names_exist(document: Path, code: str, line: int) -> None:
    for command in _commands(code):
        check_command(command, f"{document.name}:{line}", [])


def test_readme_links_resolve() -> None:
    from test_docs import markdown_anchors

    text = README.read_text()
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        if re.match(r"[a-z]+:", target):
            continue
        path, _, anchor = target.partition("#")
        assert (ROOT / path).exists(), f"README links to missing {path}"
        if anchor and path.endswith(".md"):
            assert anchor in markdown_anchors(ROOT / path), f"README: {target} has no section"


@pytest.mark.timeout(120)
def test_ros2_cli_payloads_are_answered_as_the_readme_says(readme_node: Any) -> None:
    """The payloads of the README's ros2 commands, sent to the node as those would."""
    from rclpy.node import Node

    from ros_fixtures import SpinThread

    payloads: list = []
    for language, code, line in code_blocks(README):
        if language == "sh":
            for command in _commands(code):
                check_command(command, f"README.md:{line}", payloads)
    kinds = sorted(kind for kind, *_ in payloads)
    assert kinds == ["service", "topic"], kinds
    probe = Node("readme_cli_probe")
    spinner = SpinThread(probe)
    try:
        for kind, endpoint, values, where in payloads:
            request = fill(message_class(endpoint.type)(), values)
            if kind == "topic":
                verdict = _publish_and_wait(probe, endpoint, request, where)
                assert verdict.id == request.id and verdict.force_closure, f"{where}: {verdict}"
            else:
                [verdict] = _call(probe, endpoint, request, where).verdicts
                assert verdict.id == request.grasps[0].id and verdict.force_closure, verdict
    finally:
        spinner.stop()


def _publish_and_wait(probe: Any, endpoint: grasp_fc_docs.Endpoint, request: Any,
                      where: str) -> Any:
    """Publish ``request`` on the endpoint's topic; the verdict with its id."""
    from grasp_fc_msgs.msg import ForceClosureVerdict

    from grasp_fc_ros.interface.names import QUERY_QOS

    answered = threading.Event()
    verdicts = []

    def on_verdict(msg: Any) -> None:
        if msg.id == request.id:
            verdicts.append(msg)
            answered.set()

    probe.create_subscription(ForceClosureVerdict, "/verdicts", on_verdict, QUERY_QOS)
    publisher = probe.create_publisher(type(request), "/" + endpoint.name, QUERY_QOS)
    _wait(lambda: publisher.get_subscription_count() > 0
          and probe.count_publishers("/verdicts") > 0, where)
    publisher.publish(request)
    assert answered.wait(REPLY_TIMEOUT_S), f"{where}: no verdict"
    return verdicts[0]


def _call(probe: Any, endpoint: grasp_fc_docs.Endpoint, request: Any, where: str) -> Any:
    """Call the endpoint's service with ``request``; its response."""
    service = probe.create_client(message_service(endpoint.type), "/" + endpoint.name)
    assert service.wait_for_service(timeout_sec=REPLY_TIMEOUT_S), where
    done = threading.Event()
    future = service.call_async(request)
    future.add_done_callback(lambda _: done.set())
    assert done.wait(REPLY_TIMEOUT_S), f"{where}: no response"
    return future.result()


def message_service(type_name: str) -> Any:
    package, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)


def _wait(condition: Callable[[], bool], where: str,
          timeout: float = REPLY_TIMEOUT_S) -> None:
    import time

    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"{where}: the node's topics did not match"
        time.sleep(0.05)


def _readme_table(first_header: str) -> list[list[str]]:
    """Rows of the README table whose first header cell is ``first_header``."""
    lines = README.read_text().splitlines()
    start = next(i for i, line in enumerate(lines)
                 if line.startswith(f"| {first_header} |"))
    rows = []
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        rows.append([cell.replace("`", "").strip() for cell in line.strip("|").split("|")])
    return rows


def test_readme_interface_tables_match_the_node_reference() -> None:
    kinds = {"subscribed": "subscription", "published": "publisher"}
    for name, direction, type_name, _ in _readme_table("topic"):
        endpoint = _interface(name, (kinds[direction],))
        assert endpoint.type == type_name, f"README: {name} is a {endpoint.type}"
    for name, type_name, _ in _readme_table("service or action"):
        endpoint = _interface(name.split()[0], ("service", "action"))
        assert endpoint.type == type_name, f"README: {name} is a {endpoint.type}"
    documented = {e.name for e in grasp_fc_docs.INTERFACES}
    listed = {row[0] for row in _readme_table("topic")} | {
        row[0].split()[0] for row in _readme_table("service or action")}
    assert listed == documented, f"README lacks {documented - listed}"


def test_readme_parameter_table_matches_the_node() -> None:
    """Every parameter the node declares (and config/force_closure.yaml sets), each
    with its type and default."""
    from grasp_fc_ros.node import PARAMETERS

    types = {bool: "bool", int: "integer", float: "double", str: "string"}
    rows = _readme_table("parameter")
    assert [row[0] for row in rows] == list(PARAMETERS), "README's parameter table"
    for name, type_name, default, _ in rows:
        assert name in PARAMETERS, f"README: no parameter {name}"
        value = PARAMETERS[name][0]
        assert types[type(value)] == type_name, f"README: {name} is a {types[type(value)]}"
        shown = str(value).lower() if isinstance(value, bool) else str(value)
        assert default.replace(",", "") == shown, f"README: {name} defaults to {shown}"


def test_readme_lists_every_documentation_page() -> None:
    """Every page of docs/ (but the site's index, which the README stands for) is
    linked from the README's documentation list."""
    text = README.read_text()
    listed = set(re.findall(r"\]\((docs/[^)#\s]+)", text[text.index("\n## Documentation"):]))
    pages = {f"docs/{page.name}" for page in (ROOT / "docs").iterdir()
             if page.suffix in (".md", ".rst") and page.name != "index.md"}
    assert pages <= listed, f"README's documentation list lacks {sorted(pages - listed)}"
