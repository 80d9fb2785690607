"""``grasp-fc-query``: send grasps to a running node from the shell; print the verdicts.

The venv's stand-in for ``ros2 topic pub`` / ``ros2 service call`` (the ``ros2`` CLI is
not on PyPI): a thin wrapper of :meth:`GraspClient.check_batch
<grasp_fc_ros.client.GraspClient.check_batch>`. Examples::

    grasp-fc-query --contacts "1 0 0 -1 0 0; -1 0 0 1 0 0; 0 1 0 0 -1 0; 0 -1 0 0 1 0" --mu 0.5
    grasp-fc-query --npz grasps.npz                  # positions, normals (N, n, 3)[, mu]
    grasp-fc-query --node /robot/force_closure --contacts "..." --contacts "..."

Each ``--contacts`` is one grasp: its contacts separated by ``;``, each the position
(m) and inward normal ``px py pz nx ny nz`` (spaces or commas). The verdicts print in
order, one YAML flow mapping per grasp (the whole output is a YAML list)::

    - {id: 0, status: FORCE_CLOSURE, force_closure: true, margin: 0.204124}

Exit status: 0 every grasp answered, 1 no node answered (or not within ``--timeout``),
2 bad input (nothing sent), 130 Ctrl-C.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence

import numpy as np

from grasp_fc_ros.cli_arguments import positive_float
from grasp_fc_ros.client import shapes
from grasp_fc_ros.core import Status
from grasp_fc_ros.interface.names import NODE_NAME
from grasp_fc_ros.packed import Verdicts

PROG = "grasp-fc-query"
DEFAULT_TIMEOUT_S = 10.0
# Verdict fields the node sends only with its parameters on (None or NaN otherwise).
OPTIONAL_VALUES = ("min_friction", "epsilon_lower", "epsilon_upper")


class QueryInputError(ValueError):
    """Grasps this command cannot send (exit status 2)."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG, description=__doc__.split("\n")[0],
        epilog="ROS arguments go after --ros-args (e.g. --ros-args --log-level warn); "
               "ROS_DOMAIN_ID as for any ROS program.")
    grasps = parser.add_mutually_exclusive_group(required=True)
    grasps.add_argument("--contacts", action="append", metavar='"px py pz nx ny nz; ..."',
                        help="one grasp: each contact's position (m) and inward normal, "
                             "contacts separated by ';' (repeat for more grasps)")
    grasps.add_argument("--npz", metavar="FILE",
                        help="grasps from a .npz: positions and normals (N, n, 3), "
                             "optional mu (scalar, (N,) or (N, n)), as grasp-fc-label reads")
    parser.add_argument("--mu", type=positive_float,
                        help="friction coefficient of every contact (default: the file's "
                             "mu, else the node's friction_coefficient parameter)")
    parser.add_argument("--first-id", type=int, default=0,
                        help="query id of the first grasp; the others count up (default 0)")
    parser.add_argument("--node", default=NODE_NAME,
                        help=f"the node to ask, with its namespace if any (default {NODE_NAME})")
    parser.add_argument("--timeout", type=positive_float, default=DEFAULT_TIMEOUT_S,
                        help="seconds to find the node, and again for the answers "
                             f"(default {DEFAULT_TIMEOUT_S:g})")
    return parser


def parse_contacts(texts: Sequence[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stacked positions and normals (K, 3) and counts (N,) of ``--contacts`` grasps.

    Raises
    ------
    QueryInputError
        A contact without six numbers, naming the grasp and the contact.
    """
    rows, counts = [], []
    for g, text in enumerate(texts):
        contacts = [c for c in text.split(";") if c.strip()]
        for c, contact in enumerate(contacts):
            try:
                values = [float(v) for v in contact.replace(",", " ").split()]
            except ValueError:
                values = []
            if len(values) != 6:
                raise QueryInputError(f"--contacts of grasp {g}, contact {c}: {contact.strip()!r} "
                                 "is not six numbers 'px py pz nx ny nz'")
            rows.append(values)
        counts.append(len(contacts))
    table = np.array(rows, dtype=np.float64).reshape(-1, 6)
    return table[:, :3], table[:, 3:], np.array(counts, dtype=np.int64)


def read_npz(path: str) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """positions, normals (N, n, 3) and mu (None, or as :meth:`check_batch` takes it) of
    a .npz of grasps."""
    try:
        with np.load(path) as npz:
            data = dict(npz)
    except (OSError, ValueError) as error:
        raise QueryInputError(f"{path}: {error}") from None
    missing = [key for key in ("positions", "normals") if key not in data]
    if missing:
        raise QueryInputError(f"{path}: missing array(s) {', '.join(missing)} (has "
                         f"{', '.join(data) or 'none'})")
    positions, normals, mu = data["positions"], data["normals"], data.get("mu")
    if mu is not None and mu.ndim == 1 and positions.ndim == 3 and len(mu) == len(positions):
        mu = mu[:, None]  # one per grasp
    return positions, normals, mu


def verdict_lines(verdicts: Verdicts) -> list[str]:
    """One YAML flow mapping per verdict, in order."""
    lines = []
    for k in range(len(verdicts)):
        fields = [f"id: {int(verdicts.ids[k])}",
                  f"status: {Status(int(verdicts.status[k])).name}",
                  f"force_closure: {str(bool(verdicts.force_closure[k])).lower()}",
                  f"margin: {_number(verdicts.margin[k])}"]
        for name in OPTIONAL_VALUES:
            values = getattr(verdicts, name)
            if values is not None and not math.isnan(values[k]):
                fields.append(f"{name}: {_number(values[k])}")
        if verdicts.messages[k]:
            fields.append(f"message: {json.dumps(verdicts.messages[k])}")
        lines.append("- {" + ", ".join(fields) + "}")
    return lines


def _number(value: float) -> str:
    """A float, 6 significant digits, as YAML 1.1 reads it back: .nan, .inf, and a
    decimal point in every exponent form (PyYAML reads 4e-06 as a string)."""
    if math.isnan(value):
        return ".nan"
    if math.isinf(value):
        return ".inf" if value > 0 else "-.inf"
    mantissa, e, exponent = f"{value:.6g}".partition("e")
    if e and "." not in mantissa:
        mantissa += ".0"
    return mantissa + e + exponent


def main(argv: Sequence[str] | None = None) -> int:
    import rclpy
    from rclpy.utilities import remove_ros_args

    arguments = list(sys.argv if argv is None else [PROG, *argv])
    args = build_parser().parse_args(remove_ros_args(arguments)[1:])
    try:
        if args.contacts:
            positions, normals, counts = parse_contacts(args.contacts)
            mu = args.mu
        else:
            positions, normals, mu = read_npz(args.npz)
            counts = None
            mu = args.mu if args.mu is not None else mu
        # The client checks them too, but only once a node is found.
        positions, normals, _ = shapes.grasp_batch(positions, normals, counts)
        shapes.per_contact(mu, "mu", positions, flat=True)
    except ValueError as error:  # QueryInputError, or the shapes: nothing sent
        print(f"{PROG}: error: {error}", file=sys.stderr)
        return 2
    rclpy.init(args=arguments)
    try:
        return _ask(args, positions, normals, mu, counts)
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    finally:
        rclpy.try_shutdown()


def _ask(args: argparse.Namespace, positions: np.ndarray, normals: np.ndarray,
         mu: np.ndarray | float | None, counts: np.ndarray | None) -> int:
    from grasp_fc_ros.client import GraspClient

    n_grasps = len(counts) if counts is not None else len(positions)
    ids = np.arange(args.first_id, args.first_id + n_grasps)
    with GraspClient(args.node) as client:
        if not client.wait_for_node(timeout=args.timeout):
            print(f"{PROG}: no node {args.node} answers within {args.timeout:g} s: start one "
                  "with `.venv/bin/grasp-fc-node` (or `ros2 run grasp_fc_ros "
                  "grasp-fc-node`), on the same ROS_DOMAIN_ID", file=sys.stderr)
            return 1
        try:
            verdicts = client.check_batch(positions, normals, mu, counts, ids,
                                          timeout=args.timeout)
        except TimeoutError:
            print(f"{PROG}: no verdicts from {args.node} within {args.timeout:g} s",
                  file=sys.stderr)
            return 1
    print("\n".join(verdict_lines(verdicts)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
