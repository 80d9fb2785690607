"""The node process's Fast DDS reader profile (grasp_fc_ros.node.dds_profile)."""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from grasp_fc_ros.node.dds_profile import PROFILE_VARIABLES, prompt_acks

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
