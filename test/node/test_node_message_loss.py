"""Messages lost before the node takes them are counted in /diagnostics: a raw publisher
with a KEEP_LAST history (not the documented RELIABLE KEEP_ALL) bursts single queries
while the node's process is stopped (SIGSTOP), so its history overwrites queries the node
has not received; Fast DDS reports them through rclpy's message_lost QoS event."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from ros_fixtures import Client, NodeProcess, node_command

pytestmark = pytest.mark.timeout(180)

BURST = 2_000
# How long the loss may take to show in /diagnostics after the burst (s).
LOSS_REPORT_WAIT_S = 15.0
NAMESPACE = f"/loss_test_{os.getpid()}"
PUBLISHER = """
import sys, time
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from grasp_fc_msgs.msg import Contact, ContactArray
rclpy.init()
node = rclpy.create_node("burst_publisher")
pub = node.create_publisher(ContactArray, sys.argv[1],
                            QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
deadline = time.monotonic() + 30
while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
    time.sleep(0.05)
print("matched", flush=True)
sys.stdin.readline()
msg = ContactArray(client_id=7, contacts=[Contact()])  # one contact: INVALID_INPUT
for i in range(int(sys.argv[2])):
    msg.id = i
    pub.publish(msg)
print("sent", flush=True)
sys.stdin.readline()
time.sleep(2.0)  # let the reliable protocol deliver what the history still holds
"""


def test_queries_overwritten_by_a_keep_last_publisher_are_counted_lost(ros):
    node = NodeProcess(node_command() + ["--ros-args", "-r", f"__ns:={NAMESPACE}",
                                         "-p", "workers:=0"])
    client = Client("loss_test_client", namespace=NAMESPACE)
    publisher = subprocess.Popen([sys.executable, "-c", PUBLISHER, f"{NAMESPACE}/contacts",
                                  str(BURST)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                 text=True)
    name = f"{NAMESPACE}/force_closure"
    try:
        client.wait_connected()
        before = client.diagnostics_after(time.time(), name)
        assert publisher.stdout.readline().strip() == "matched"
        node.proc.send_signal(signal.SIGSTOP)  # the node takes nothing meanwhile
        try:
            publisher.stdin.write("go\n")
            publisher.stdin.flush()
            assert publisher.stdout.readline().strip() == "sent"
        finally:
            node.proc.send_signal(signal.SIGCONT)
        publisher.stdin.write("end\n")
        publisher.stdin.flush()
        assert publisher.wait(60) == 0
        # Fast DDS reports a loss when it sees the gap, and the node's event callback
        # runs when its executor gets to it: on a loaded machine after the first reading.
        deadline = time.monotonic() + LOSS_REPORT_WAIT_S
        while True:
            after = client.diagnostics_after(time.time() + 1.0, name)
            lost = int(after["messages_lost"]) - int(before["messages_lost"])
            if lost > 0 or time.monotonic() > deadline:
                break
    finally:
        publisher.kill()
        client.close()
        node.stop()
    received = int(after["received"]) - int(before["received"])
    assert received < BURST
    assert lost > 0 and received + lost <= BURST  # the rmw may count a run as one
    assert int(after["answered"]) - int(before["answered"]) == received
