"""Fast DDS settings for the node's process: acknowledge a sample at once, and UDP
receive buffers that hold a batch part.

A Fast DDS reader answers a writer's heartbeat only after its ``heartbeatResponseDelay``.
``GraspClient`` sends a large batch in parts, each once the node acknowledged the one
before (docs/performance.md#big-batches), so that delay, not the node, set the pace of
a batch (docs/performance.md#worker-messages). Over UDP (clients on other hosts), a
part arrives as datagrams faster than a busy node's receive thread may take them, and a
socket buffer of the Linux default (208 KiB) drops them, to be sent again after a
negative acknowledgement (docs/performance.md#service-calls-between-hosts).
:func:`prompt_acks` gives the node's readers a delay of 0 and its participants' UDP
sockets :data:`LISTEN_BUFFER_BYTES` of receive buffer through a Fast DDS XML profile
(no transport: the builtin ones, or ``FASTDDS_BUILTIN_TRANSPORTS``, stay), unless the
user chose a profiles file or another middleware.

The profile is a temporary file named by ``FASTRTPS_DEFAULT_PROFILES_FILE``, and it
lives as long as the node (``grasp-fc-node`` enters :func:`prompt_acks` before rclpy
starts and leaves it after the node and rclpy are shut down), not only while the node
is made: the node's child processes inherit the environment, and the marker process
starts whenever ``publish_markers`` turns on or it must be replaced, and then its own
Fast DDS reads the file. A variable naming a file already removed made that Fast DDS
print an XML parser error, which on the marker process's old stdout channel was read as
a message (issue 28). Keeping the variable out of the children instead would give the
marker process other Fast DDS settings than the node's, and every spawner would have to know
of it; the file is a few hundred bytes. Only a SIGKILLed node leaves it behind (in the
temporary directory).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

# Receive buffer asked for each UDP socket of the node's participants (bytes): a batch
# part (MAX_MESSAGE_CONTACTS contacts, ~0.3 MB) several times over. Linux grants at most
# net.core.rmem_max (its default, 208 KiB, grants nothing more: docs/node.rst says how
# to raise it); Fast DDS takes what it is granted.
LISTEN_BUFFER_BYTES = 4 * 1024 * 1024
# The default participant and data reader profiles: socket buffers and reader times
# only, everything else Fast DDS's defaults (ROS QoS settings still apply on top).
READER_PROFILE = f"""<?xml version="1.0" encoding="UTF-8" ?>
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <participant profile_name="grasp_fc_receive_buffers" is_default_profile="true">
    <rtps>
      <listenSocketBufferSize>{LISTEN_BUFFER_BYTES}</listenSocketBufferSize>
    </rtps>
  </participant>
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
    """While entered (from before ``rclpy.init`` until the node and its child processes
    are gone: each Fast DDS reads its profiles as it starts), Fast DDS readers
    acknowledge at once and UDP sockets get LISTEN_BUFFER_BYTES of receive buffer;
    yields whether the profile was set (not if ``RMW_IMPLEMENTATION`` names another
    middleware or a profiles file is already chosen: the user's settings win, and the
    children inherit them)."""
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
