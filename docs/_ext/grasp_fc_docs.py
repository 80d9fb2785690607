"""Sphinx directives that render reference pages from the code, so they cannot drift.

- ``grasp-fc-api MODULE``: the API of a package or module: its public names (``__all__``,
  else the public names it defines), then every public submodule with the members it
  defines (each object documented once, where users import it from).
- ``grasp-fc-parameters``: the node's parameters, read from ``grasp_fc_ros.node.PARAMETERS``
  (type, default, accepted range, read-only, description).
- ``grasp-fc-interfaces KIND``: the node's topics, services or action (KIND one of
  ``subscriptions``, ``publications``, ``services``, ``actions``) from :data:`INTERFACES`,
  with the QoS read from the profile objects the code uses.
  ``test/test_docs.py`` checks :data:`INTERFACES` against a running node's graph.
- ``grasp-fc-definitions``: every ``.msg``, ``.srv`` and ``.action`` under ``msg_defs/``,
  included verbatim.
"""

from __future__ import annotations

import importlib
import inspect
import os
import pkgutil
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

from docutils import nodes
from docutils.parsers.rst import directives
from docutils.statemachine import StringList
from sphinx.application import Sphinx
from sphinx.util import logging
from sphinx.util.docutils import SphinxDirective
from sphinx.util.nodes import nested_parse_with_titles

logger = logging.getLogger(__name__)
REPO = Path(__file__).resolve().parents[2]
MSG_DEFS = REPO / "msg_defs"
# Interface folders of the message package, in the order the page shows them.
DEFINITION_KINDS = ("msg", "srv", "action")
# Where the node's parameter table lives (kept importable there by the package layout).
PARAMETERS_PATH = "grasp_fc_ros.node.PARAMETERS"
# The node's default name, standing for ``{name}`` in :data:`INTERFACES`.
DEFAULT_NODE_NAME = "force_closure"


@dataclass(frozen=True)
class Endpoint:
    """One topic, service or action of the node, as the reference page lists it.

    ``name`` is relative to the node's namespace unless it starts with ``/``; ``node``
    is the node that owns it, ``{name}`` standing for the main node's name; ``qos``
    names the profile object(s) in the code, tried in order (the first that imports);
    ``depth`` stands for a plain history depth given in the code instead of a profile.
    """

    name: str
    kind: str
    type: str
    node: str
    description: str
    qos: tuple[str, ...] = ()
    depth: int | None = None
    condition: str = ""


# The node's interface. Descriptions say what a user needs; the QoS column comes from
# the code's profiles. test/test_docs.py compares names, kinds, types and owning nodes
# with the graph of a running node, both ways.
INTERFACES = (
    Endpoint("contacts", "subscription", "grasp_fc_msgs/msg/ContactArray", "{name}",
             "One grasp query; answered by one verdict with the same ``id``, "
             "``client_id`` and ``header``, on the asker's reply topic (see ``verdicts``).",
             qos=("grasp_fc_ros.interface.names.QUERY_QOS",)),
    Endpoint("contacts_batch", "subscription", "grasp_fc_msgs/msg/ContactArrayBatch",
             "{name}_batches",
             "Many grasps in one packed message; answered by one verdict array, in "
             "order, on the asker's reply topic (see ``verdicts_batch``). Served on a DDS "
             "participant of its own, so that a huge message holds up no service "
             "call; its QoS overrides are the main node's parameters.",
             qos=("grasp_fc_ros.interface.names.QUERY_QOS",)),
    Endpoint("verdicts", "publisher", "grasp_fc_msgs/msg/ForceClosureVerdict", "{name}",
             "One verdict per query on ``contacts`` with ``client_id`` 0; a query with "
             "a client id is answered on ``verdicts/c<client_id, 16 hex digits>`` "
             "instead, made at the client's first answer (:ref:`answers`).",
             qos=("grasp_fc_ros.interface.names.VERDICT_QOS",)),
    Endpoint("verdicts_batch", "publisher", "grasp_fc_msgs/msg/ForceClosureVerdictArray",
             "{name}",
             "One verdict array per batch on ``contacts_batch`` with ``client_id`` 0: "
             "the batch's ``header``, ``client_id`` and ``request_id``; a batch with a "
             "client id is answered on ``verdicts_batch/c<client_id, 16 hex digits>``.",
             qos=("grasp_fc_ros.interface.names.VERDICT_QOS",)),
    Endpoint("/diagnostics", "publisher", "diagnostic_msgs/msg/DiagnosticArray", "{name}",
             "About once a second: counters of queries, verdicts per status, overload, "
             "action goals, timings and markers (see :ref:`diagnostics`).", depth=10),
    Endpoint("markers", "publisher", "visualization_msgs/msg/MarkerArray", "{name}_markers",
             "RViz markers of answered queries, in each query's ``header.frame_id`` "
             "(see :doc:`markers`).",
             qos=("grasp_fc_ros.markers.publisher.MARKER_QOS",),
             condition="with ``publish_markers``"),
    Endpoint("check_force_closure", "service", "grasp_fc_msgs/srv/CheckForceClosure",
             "{name}_service",
             "Verdicts on a list of grasps, one per grasp, in order."),
    Endpoint("compute_contact_forces", "service", "grasp_fc_msgs/srv/ComputeContactForces",
             "{name}_service",
             "The contact forces that hold one grasp under a load with the least largest "
             "normal force (see :doc:`quality`)."),
    Endpoint("assess_robustness", "service", "grasp_fc_msgs/srv/AssessRobustness",
             "{name}_robustness",
             "How well each grasp holds when its contacts are off: the certified radii, "
             "whether it holds under given errors (with a witness where it breaks) and "
             "its probability of force closure under random errors (see "
             ":doc:`robustness`). Served on a thread of its own, so that an assessment "
             "never holds up ``check_force_closure``."),
    Endpoint("clear_markers", "service", "std_srvs/srv/Empty", "{name}",
             "Publishes a DELETEALL on ``markers`` (queued marker work is dropped first)."),
    Endpoint("label_grasps", "action", "grasp_fc_msgs/action/LabelGrasps", "{name}_action",
             "A long batch as one goal: feedback about 4 times a second, cancel keeps "
             "the verdicts decided so far (a prefix, in order)."),
)
# The keys of the node's /diagnostics status, in the order it sends them, with what they
# count. test/test_docs.py compares them with a running node's status.
DIAGNOSTIC_KEYS = (
    ("received", "queries received: single topic queries, batch grasps, service grasps, "
                 "goal grasps"),
    ("answered", "queries answered (every received query is answered once)"),
    ("queries", "the same as ``answered`` (kept for older dashboards)"),
    ("force_closure", "verdicts FORCE_CLOSURE"),
    ("rejected_by_filter", "verdicts FILTERED_OUT"),
    ("decided_by_exact_test", "verdicts FORCE_CLOSURE or NOT_FORCE_CLOSURE"),
    ("invalid_input", "verdicts INVALID_INPUT"),
    ("solver_failures", "verdicts SOLVER_FAILURE, overload and shutdown answers included"),
    ("callback_errors", "internal errors caught in a callback (each logged)"),
    ("overloaded", "queries refused at once because the node's queues were full"),
    ("messages_lost", "messages (queries, batches) the middleware reports lost before the "
                      "node took them: a publisher whose KEEP_LAST history overwrote them; "
                      "they get no answer. The rmw's count, a lower bound (Fast DDS may "
                      "count a run skipped at once as one; an rmw that reports none "
                      "leaves 0)"),
    ("pending_single_queries", "single topic queries waiting to be decided"),
    ("pending_batch_grasps", "batch grasps waiting to be decided"),
    ("action_goals_queued", "``label_grasps`` goals waiting for a goal thread"),
    ("action_goals_running", "goals being decided"),
    ("markers_published", "grasps whose markers were published (with ``publish_markers``)"),
    ("markers_dropped", "grasps whose markers were dropped because marker work fell "
                        "behind (with ``publish_markers``)"),
    ("worker_restarts", "worker processes replaced since start: died, or silent for longer "
                        "than ``worker_timeout_s`` plus a time per contact and killed"),
    ("action_goals_received", "goals received"),
    ("action_goals_succeeded", "goals that ended with all their verdicts"),
    ("action_goals_canceled", "goals canceled (their result holds the decided prefix)"),
    ("action_goals_aborted", "goals aborted (the node shut down)"),
    ("action_grasps_undecided", "grasps of canceled or aborted goals never decided"),
    ("conversion_time_total_s", "seconds spent converting messages to arrays"),
    ("validation_time_total_s", "seconds spent validating grasps"),
    ("filter_time_total_s", "seconds in the torque filter"),
    ("exact_time_total_s", "seconds in the exact test"),
    ("processing_time_mean_ms", "mean processing time of the answered messages of the "
                                "last 2,000 (failures add none)"),
    ("processing_time_p99_ms", "their 99th percentile"),
)
# Keys present only while the node publishes markers.
MARKER_DIAGNOSTIC_KEYS = ("markers_published", "markers_dropped")
# Table heading per kind of endpoint, and which kinds each directive argument shows.
KIND_GROUPS = {"subscriptions": ("subscription",), "publications": ("publisher",),
               "services": ("service",), "actions": ("action",)}


def import_object(path: str) -> Any:
    """Return the object at the dotted ``path`` (module, then attributes)."""
    parts = path.split(".")
    for split in range(len(parts) - 1, 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:split]))
        except ImportError:
            continue
        try:
            for attribute in parts[split:]:
                obj = getattr(obj, attribute)
        except AttributeError:
            break
        return obj
    raise ImportError(f"cannot import {path}")


def resolve_qos(endpoint: Endpoint) -> Any:
    """Return the QoS profile the code uses for ``endpoint`` (None for services/actions)."""
    if endpoint.depth is not None:
        from rclpy.qos import QoSProfile

        return QoSProfile(depth=endpoint.depth)
    errors = []
    for path in endpoint.qos:
        try:
            return import_object(path)
        except ImportError as exc:
            errors.append(str(exc))
    if endpoint.qos:
        raise ImportError(f"QoS of {endpoint.name}: none of {', '.join(endpoint.qos)} "
                          "imports; update INTERFACES in docs/_ext/grasp_fc_docs.py")
    return None


def describe_qos(profile: Any) -> str:
    """``reliable, keep all`` / ``reliable, keep last 10,000, transient local``."""
    if profile is None:
        return ""
    words = [profile.reliability.name.lower().replace("_", " ")]
    history = profile.history.name.lower()
    words.append("keep all" if history == "keep_all" else f"keep last {profile.depth:,}")
    if profile.durability.name != "VOLATILE":
        words.append(profile.durability.name.lower().replace("_", " "))
    return ", ".join(words)


def _definition_link(type_name: str) -> str:
    """The type as inline code, linked to its definition when it is one of ours."""
    package, kind, name = type_name.split("/")
    if package == "grasp_fc_msgs":
        return f":ref:`{type_name} <{_label(kind, name)}>`"
    return f"``{type_name}``"


def _from_srcdir(srcdir: str | Path, path: Path) -> str:
    """``path`` relative to the Sphinx source folder (a leading ``/`` in an include
    means that folder)."""
    return os.path.relpath(path, srcdir)


def _label(kind: str, name: str) -> str:
    return f"definition-{kind}-{name.lower()}"


def _list_table(headers: list[str], rows: list[list[str]], widths: str = "auto") -> list[str]:
    lines = [".. list-table::", "   :header-rows: 1", f"   :widths: {widths}", ""]
    for row in [headers, *rows]:
        lines.append(f"   * - {row[0] or ' '}")
        lines.extend(f"     - {cell or ' '}" for cell in row[1:])
    return lines + [""]


class _GeneratedRst(SphinxDirective):
    """A directive whose output is reStructuredText made by :meth:`lines`."""

    def lines(self) -> list[str]:
        raise NotImplementedError

    def run(self) -> list[nodes.Node]:
        holder = nodes.section()
        holder.document = self.state.document
        content = StringList(self.lines(), source=f"<{self.name}>")
        nested_parse_with_titles(self.state, content, holder)
        return holder.children


class InterfacesDirective(_GeneratedRst):
    """Topics, services or the action of the node, from :data:`INTERFACES`."""

    required_arguments = 1

    def lines(self) -> list[str]:
        group = self.arguments[0]
        if group not in KIND_GROUPS:
            raise self.error(f"grasp-fc-interfaces: {group!r} is not one of "
                             f"{', '.join(KIND_GROUPS)}")
        endpoints = [e for e in INTERFACES if e.kind in KIND_GROUPS[group]]
        topics = group in ("subscriptions", "publications")
        headers = ["name", "type", *(["QoS"] if topics else []), "served by", "what"]
        rows = []
        for e in endpoints:
            what = e.description + (f" Only {e.condition}." if e.condition else "")
            qos = [describe_qos(resolve_qos(e))] if topics else []
            rows.append([f"``{e.name}``", _definition_link(e.type), *qos,
                         f"``{e.node.format(name=DEFAULT_NODE_NAME)}``", what])
        return _list_table(headers, rows)


class DiagnosticsDirective(_GeneratedRst):
    """The keys of the node's diagnostics status, from :data:`DIAGNOSTIC_KEYS`."""

    def lines(self) -> list[str]:
        return _list_table(["key", "what"], [[f"``{k}``", what] for k, what in DIAGNOSTIC_KEYS],
                           widths="30 70")


class ParametersDirective(_GeneratedRst):
    """The node's parameters from ``PARAMETERS``: type, default, range, description."""

    def lines(self) -> list[str]:
        from rcl_interfaces.msg import ParameterType

        parameters = import_object(PARAMETERS_PATH)
        type_names = {ParameterType.PARAMETER_BOOL: "bool",
                      ParameterType.PARAMETER_INTEGER: "integer",
                      ParameterType.PARAMETER_DOUBLE: "double",
                      ParameterType.PARAMETER_STRING: "string"}
        rows = []
        for name, (default, descriptor) in parameters.items():
            if descriptor.type not in type_names:
                raise self.error(f"parameter {name}: type {descriptor.type} has no name "
                                 "in docs/_ext/grasp_fc_docs.py")
            rows.append([f"``{name}``", type_names[descriptor.type], f"``{_value(default)}``",
                         _accepted(descriptor),
                         "read-only" if descriptor.read_only else "at run time",
                         descriptor.description.rstrip(".") + "."])
        return _list_table(["name", "type", "default", "accepted", "set", "what"], rows,
                           widths="14 7 9 16 9 45")


def _value(value: object) -> str:
    """A parameter value as it is written on the command line or in YAML."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float):
        return f"{value:,.1f}" if value.is_integer() else f"{value:g}"
    if isinstance(value, int):
        return f"{value:,}"
    return str(value)


def _accepted(descriptor: Any) -> str:
    """The accepted values as the descriptor states them."""
    for r in descriptor.integer_range:
        return f"{r.from_value:,} to {r.to_value:,}"
    for r in descriptor.floating_point_range:
        return f"{_value(r.from_value)} to {_value(r.to_value)}"
    return descriptor.additional_constraints or ("true, false" if descriptor.type == 1 else "")


class DefinitionsDirective(_GeneratedRst):
    """Every interface definition of ``msg_defs/``, included verbatim with a label."""

    def lines(self) -> list[str]:
        lines: list[str] = []
        titles = {"msg": "Messages", "srv": "Services", "action": "Actions"}
        for kind in DEFINITION_KINDS:
            files = sorted((MSG_DEFS / kind).glob(f"*.{kind}"))
            if not files:
                continue
            lines += [titles[kind], "-" * len(titles[kind]), ""]
            for path in files:
                self.env.note_dependency(str(path))
                name = path.stem
                heading = f"grasp_fc_msgs/{kind}/{name}"
                lines += [f".. _{_label(kind, name)}:", "", heading, "~" * len(heading), "",
                          f".. literalinclude:: /{_from_srcdir(self.env.srcdir, path)}",
                          "   :language: text", ""]
        return lines


class ApiDirective(_GeneratedRst):
    """The public API of a package or module, each object documented once.

    Option ``:also:``: names the module imports from elsewhere that its users handle
    (e.g. the result classes a client returns), documented here under this module.
    """

    required_arguments = 1
    option_spec = {"also": directives.unchanged}

    def lines(self) -> list[str]:
        module = importlib.import_module(self.arguments[0])
        lines = [f".. automodule:: {module.__name__}", "   :no-members:", ""]
        documented = public_names(module)
        documented += [n for n in self.options.get("also", "").split() if n not in documented]
        for name in documented:
            lines += _autodoc(module, name)
        for sub in public_submodules(module):
            defined = [n for n in public_names(sub, defined_only=True) if n not in documented]
            if not defined and not (sub.__doc__ or "").strip():
                continue
            title = sub.__name__
            lines += [title, "-" * len(title), "",
                      f".. automodule:: {sub.__name__}", "   :no-members:"]
            # A module named like a public function (core.quality.minimum_friction): the
            # function keeps the index entry, the module its section.
            if sub.__name__.rpartition(".")[2] in documented:
                lines.append("   :no-index:")
            lines.append("")
            for name in defined:
                lines += _autodoc(sub, name)
        return lines


def public_names(module: ModuleType, defined_only: bool = False) -> list[str]:
    """``__all__`` (unless ``defined_only``), else the public names ``module`` defines."""
    if not defined_only and hasattr(module, "__all__"):
        return list(module.__all__)
    names = []
    for name, obj in vars(module).items():
        if name.startswith("_") or inspect.ismodule(obj):
            continue
        if getattr(obj, "__module__", None) == module.__name__ and (
                inspect.isclass(obj) or inspect.isfunction(obj)):
            names.append(name)
    return names


def public_submodules(module: ModuleType) -> list[ModuleType]:
    """Every submodule of a package whose dotted name has no part starting with ``_``."""
    if not hasattr(module, "__path__"):
        return []
    found = []
    for info in pkgutil.walk_packages(module.__path__, module.__name__ + "."):
        if any(part.startswith("_") for part in info.name.split(".")):
            continue
        found.append(importlib.import_module(info.name))
    return sorted(found, key=lambda m: m.__name__)


def _autodoc(module: ModuleType, name: str) -> list[str]:
    obj = getattr(module, name)
    target = f"{module.__name__}.{name}"
    if inspect.isclass(obj):
        return [f".. autoclass:: {target}", "   :members:", ""]
    if callable(obj):
        return [f".. autofunction:: {target}", ""]
    return [f".. autodata:: {target}", "   :no-value:", ""]


def plain_text_maths(app: Sphinx, what: str, name: str, obj: object, options: object,
                     lines: list[str]) -> None:
    """Make the docstrings' plain-text maths render as written.

    The package's docstrings write formulas as plain text: ``|f_t|`` for a norm, and
    displays as an indented block after a blank line. reStructuredText would read the
    first as a substitution and the second as a block quote (which breaks on deeper
    indentation), so displays become literal blocks and bars outside literals are
    escaped. Runs before napoleon, on the docstring as written.
    """
    lines[:] = _escape_bars(_displays_as_literal(lines))


def _indent(line: str) -> int:
    return len(line) - len(line.lstrip())


# Paragraph starts after which an indented block is not a display: list items, fields,
# directives, doctest lines.
_NOT_DISPLAY_OPENERS = ("* ", "- ", "+ ", ":", ".. ", ">>>")


def _displays_as_literal(lines: list[str]) -> list[str]:
    out: list[str] = []
    literal_indent = None   # indentation of the paragraph that opened a literal block
    after_blank = False
    for line in lines:
        blank = not line.strip()
        if literal_indent is not None and (blank or _indent(line) > literal_indent):
            out.append(line)
            continue
        literal_indent = None
        if not blank and after_blank:
            opener = _previous_paragraph(out)
            if opener is not None and _indent(line) > _indent(out[opener[0]]) and not \
                    out[opener[0]].lstrip().startswith(_NOT_DISPLAY_OPENERS):
                text = out[opener[1]].rstrip()
                out[opener[1]] = text + ":" if text.endswith(":") else text + " ::"
                literal_indent = _indent(out[opener[0]])
        out.append(line)
        after_blank = blank
        if not blank and literal_indent is None and line.rstrip().endswith("::"):
            literal_indent = _indent(line)
    return out


def _previous_paragraph(out: list[str]) -> tuple[int, int] | None:
    """(first, last) index of the last paragraph in ``out`` before trailing blanks."""
    last = len(out) - 1
    while last >= 0 and not out[last].strip():
        last -= 1
    if last < 0:
        return None
    first = last
    while first > 0 and out[first - 1].strip() and \
            _indent(out[first - 1]) == _indent(out[last]):
        first -= 1
    return first, last


def _escape_bars(lines: list[str]) -> list[str]:
    out = []
    literal_indent = None
    for line in lines:
        if literal_indent is not None and (not line.strip() or _indent(line) > literal_indent):
            out.append(line)
            continue
        literal_indent = None
        parts = line.split("``")
        # Even parts are outside inline literals.
        out.append("``".join(p.replace("|", r"\|") if i % 2 == 0 else p
                             for i, p in enumerate(parts)))
        if line.rstrip().endswith("::"):
            literal_indent = _indent(line)
    return out


# Pages another part of the project writes: listed in the index's toctree, left out of it
# (with a note in the build log) while their file does not exist yet.
OPTIONAL_PAGES = ("epsilon",)


def drop_missing_optional_pages(app: Sphinx, docname: str, source: list[str]) -> None:
    """Remove toctree lines of :data:`OPTIONAL_PAGES` that have no file from the index."""
    if docname != app.config.root_doc:
        return
    missing = [page for page in OPTIONAL_PAGES
               if not any((Path(app.srcdir) / f"{page}{suffix}").exists()
                          for suffix in app.config.source_suffix)]
    if missing:
        logger.info("grasp_fc_docs: not in the index yet (no file): %s", ", ".join(missing))
        source[0] = "\n".join(line for line in source[0].split("\n")
                               if line.strip() not in missing)


def setup(app: Sphinx) -> dict[str, Any]:
    app.connect("source-read", drop_missing_optional_pages)
    # Before napoleon (priority 500), which rewrites the numpy sections.
    app.connect("autodoc-process-docstring", plain_text_maths, priority=400)
    app.add_directive("grasp-fc-api", ApiDirective)
    app.add_directive("grasp-fc-parameters", ParametersDirective)
    app.add_directive("grasp-fc-interfaces", InterfacesDirective)
    app.add_directive("grasp-fc-definitions", DefinitionsDirective)
    app.add_directive("grasp-fc-diagnostics", DiagnosticsDirective)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
