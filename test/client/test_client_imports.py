"""The client library stays a client: importing it loads no server module, and it names
the node's topics, services and action only through grasp_fc_ros.interface.names."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

from grasp_fc_ros.interface import names

CLIENT = Path(__file__).resolve().parents[2] / "grasp_fc_ros" / "client"
# What a client must never load: the node, its engine (the worker pool, long jobs, the
# evaluation of packed grasps), the marker process.
SERVER_MODULES = ("grasp_fc_ros.node", "grasp_fc_ros.engine", "grasp_fc_ros.markers.publisher")


def test_importing_the_client_loads_no_server_module():
    probe = ("import sys, grasp_fc_ros.client\n"
             "print('\\n'.join(sorted(m for m in sys.modules if m.startswith('grasp_fc_ros'))))")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    loaded = done.stdout.split()
    assert "grasp_fc_ros.client.grasp_client" in loaded  # the probe saw the client
    server = [m for m in loaded if m.startswith(SERVER_MODULES)]
    assert server == [], f"importing grasp_fc_ros.client loaded {server}"


def test_client_modules_spell_no_interface_name():
    """Every topic, service and action name comes from interface.names."""
    spelled = {value for key, value in vars(names).items()
               if key.endswith(("_TOPIC", "_SERVICE", "_ACTION")) and isinstance(value, str)}
    assert {"contacts", "verdicts", "check_force_closure", "label_grasps"} <= spelled
    found = []
    for path in sorted(CLIENT.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                if node.value.strip("/") in spelled or any(
                        node.value.endswith("/" + name) for name in spelled):
                    found.append(f"{path.name}:{node.lineno}: {node.value!r}")
    assert found == []
