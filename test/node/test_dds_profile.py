"""The node process's Fast DDS profile (grasp_fc_ros.node.dds_profile): reader times and
UDP receive buffers."""

from __future__ import annotations

import os
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from grasp_fc_ros.node.dds_profile import LISTEN_BUFFER_BYTES, PROFILE_VARIABLES, prompt_acks

NS = "{http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles}"


@pytest.fixture
def clean_env(monkeypatch):
    for name in (*PROFILE_VARIABLES, "RMW_IMPLEMENTATION"):
        monkeypatch.delenv(name, raising=False)
    return monkeypatch


def test_readers_acknowledge_at_once_while_entered_and_the_file_goes_after(clean_env):
    with prompt_acks() as set_profile:
        assert set_profile
        path = Path(os.environ[PROFILE_VARIABLES[0]])
        reader = ET.parse(path).getroot().find(f"{NS}data_reader")
        assert reader is not None and reader.get("is_default_profile") == "true"
        delay = reader.find(f"{NS}times/{NS}heartbeatResponseDelay")
        assert delay is not None
        assert [delay.find(f"{NS}{unit}").text for unit in ("sec", "nanosec")] == ["0", "0"]
        assert reader.find(f"{NS}qos") is None  # reader times only: ROS QoS untouched
    assert PROFILE_VARIABLES[0] not in os.environ
    assert not path.exists()


@pytest.mark.parametrize("name, value", [
    ("FASTRTPS_DEFAULT_PROFILES_FILE", "/etc/my_profiles.xml"),
    ("FASTDDS_DEFAULT_PROFILES_FILE", "/etc/my_profiles.xml"),
    ("RMW_IMPLEMENTATION", "rmw_cyclonedds_cpp"),
])
def test_a_users_profiles_file_or_middleware_is_left_alone(clean_env, name, value):
    clean_env.setenv(name, value)
    before = {key: os.environ.get(key) for key in PROFILE_VARIABLES}
    with prompt_acks() as set_profile:
        assert not set_profile
        assert {key: os.environ.get(key) for key in PROFILE_VARIABLES} == before
    assert os.environ[name] == value


def test_the_nodes_udp_sockets_ask_for_big_receive_buffers(clean_env):
    with prompt_acks():
        root = ET.parse(os.environ[PROFILE_VARIABLES[0]]).getroot()
    participant = root.find(f"{NS}participant")
    assert participant is not None and participant.get("is_default_profile") == "true"
    size = participant.find(f"{NS}rtps/{NS}listenSocketBufferSize")
    assert size is not None and int(size.text) == LISTEN_BUFFER_BYTES
    # Buffers only: the builtin transports (or FASTDDS_BUILTIN_TRANSPORTS) stay.
    assert [child.tag for child in participant.find(f"{NS}rtps")] == [size.tag]
    assert root.find(f"{NS}transport_descriptors") is None


@pytest.mark.timeout(120)
def test_the_node_process_gets_them_on_udp():
    # The console script on UDP only, discovering other hosts (as between hosts: with
    # discovery on localhost only, rmw makes a UDP transport of its own, which takes no
    # buffer size from the profile): its listening sockets' receive buffers are as large
    # as the kernel grants (Linux reports twice the size set, for its bookkeeping).
    import shutil
    import signal
    import subprocess
    import time

    from ros_fixtures import NodeProcess, node_command

    if shutil.which("ss") is None:
        pytest.skip("no `ss` (iproute2) to read socket buffer sizes")
    granted = 2 * min(LISTEN_BUFFER_BYTES,
                      int(Path("/proc/sys/net/core/rmem_max").read_text()))
    default = int(Path("/proc/sys/net/core/rmem_default").read_text())
    namespace = f"/udp_buffers_{os.getpid()}"
    process = NodeProcess(node_command() + ["--ros-args", "-r", f"__ns:={namespace}"],
                          {"FASTDDS_BUILTIN_TRANSPORTS": "UDPv4",
                           "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"})
    try:
        deadline = time.monotonic() + 60.0
        while True:
            sockets = subprocess.run(["ss", "-uanpm"], capture_output=True, text=True).stdout
            # Each socket: a line naming its process, then one with its skmem.
            lines = sockets.splitlines()
            buffers = [int(re.search(r"\brb(\d+)", after).group(1))
                       for line, after in zip(lines, lines[1:], strict=False)
                       if f"pid={process.proc.pid}," in line and "rb" in after]
            if len([b for b in buffers if b >= granted]) >= 2 or time.monotonic() > deadline:
                break
            time.sleep(0.5)
    finally:
        process.stop(signal.SIGINT)
    assert len([b for b in buffers if b >= granted]) >= 2, (buffers, granted, default)
