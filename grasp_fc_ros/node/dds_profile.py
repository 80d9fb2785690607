"""Fast DDS reader timing for the node's process: acknowledge a sample at once.

A Fast DDS reader answers a writer's heartbeat only after its ``heartbeatResponseDelay``.
``GraspClient`` sends a large batch in parts, each once the node acknowledged the one
before (docs/performance.md#big-batches), so that delay, not the node, set the pace of
a batch (docs/performance.md#worker-messages). :func:`prompt_acks` gives the node's readers a
delay of 0 through a Fast DDS XML profile of reader times only (no transport), unless
the user chose a profiles file or another middleware.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

# The default data reader profile: reader times only, everything else Fast DDS's
# defaults (ROS QoS settings still apply on top).
READER_PROFILE = """<?xml version="1.0" encoding="UTF-8" ?>
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <data_reader profile_name="grasp_fc_prompt_acks" is_default_profile="true">
    <times>
      <heartbeatResponseDelay><sec>0</sec><nanosec>0</nanosec></heartbeatResponseDelay>
    </times>
  </data_reader>
</profiles>
"""
#: Environment variables naming a Fast DDS profiles file (Fast DDS 2 and 3 spellings).
PROFILE_VARIABLES = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")
FASTDDS_RMW = "rmw_fastrtps_cpp"


@contextlib.contextmanager
def prompt_acks() -> Iterator[bool]:
    """While entered (around ``rclpy.init`` and the node's construction, when Fast DDS
    reads its profiles), Fast DDS readers acknowledge at once; yields whether the
    profile was set (not if ``RMW_IMPLEMENTATION`` names another middleware or a
    profiles file is already chosen: the user's settings win)."""
    if (os.environ.get("RMW_IMPLEMENTATION", FASTDDS_RMW) != FASTDDS_RMW
            or any(os.environ.get(name) for name in PROFILE_VARIABLES)):
        yield False
        return
    with tempfile.TemporaryDirectory(prefix="grasp_fc_dds_") as folder:
        path = Path(folder) / "reader_times.xml"
        path.write_text(READER_PROFILE)
        os.environ[PROFILE_VARIABLES[0]] = str(path)
        try:
            yield True
        finally:
            os.environ.pop(PROFILE_VARIABLES[0], None)
