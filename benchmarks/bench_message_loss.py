"""Queries overwritten by a KEEP_LAST publisher: how many the node received and answered,
and how many the rmw reported lost (/diagnostics ``messages_lost``).

A raw publisher process with a RELIABLE KEEP_LAST --depth history (not the documented
RELIABLE KEEP_ALL) bursts --burst single queries at the node while the node's process
is stopped (SIGSTOP), so its history overwrites queries the node has not received; then
the node goes on (SIGCONT) and takes what reached it. Each of --rounds rounds prints
the queries received and answered and the loss the rmw reported within the settling
time (the node's /diagnostics, read until its counts stop changing).

What the rmw reports is its own: Fast DDS reports such a loss late, as fewer messages
than were overwritten (a run skipped at once counts as one) or not at all, which is why
the tests feed the node known events instead (test/node/test_node_message_loss.py).
What the node controls is checked here: every query it received is answered, and it
counts no more lost than were overwritten; a round that breaks either prints
"miscount".

The node runs from its console script (grasp-fc-node) in a namespace of its own,
without worker processes (the queries have one contact: INVALID_INPUT, no core work).

Usage: python benchmarks/bench_message_loss.py [--burst N] [--depth D] [--rounds R]
       python benchmarks/bench_message_loss.py --quick    # the smoke test's form
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import time
from dataclasses import dataclass

import rclpy

from bench_ros import node_namespace, start_node, stop_node
from grasp_fc_ros.client import GraspClient

BURST = 10_000
QUICK_BURST = 2_000
ROUNDS = 5
DEPTH = 10
# The node's /diagnostics (once a second) are read until their counts have stayed the
# same this many times in a row, all received queries answered, or for SETTLE_S at most.
STABLE_READINGS = 3
SETTLE_S = 60.0
# The publisher's wait for the node's subscription (discovery on a loaded machine).
MATCH_TIMEOUT_S = 60.0
COUNTS = ("received", "answered", "messages_lost", "pending_single_queries")
PUBLISHER = """
import sys, time
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from grasp_fc_msgs.msg import Contact, ContactArray
topic, burst, depth, match_timeout_s = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), \
    float(sys.argv[4])
rclpy.init()
node = rclpy.create_node("burst_publisher")
pub = node.create_publisher(ContactArray, topic,
                            QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE))
deadline = time.monotonic() + match_timeout_s
while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
    time.sleep(0.05)
print("matched" if pub.get_subscription_count() else "unmatched", flush=True)
msg = ContactArray(client_id=7, contacts=[Contact()])  # one contact: INVALID_INPUT
sent = 0
for line in sys.stdin:  # "go": one burst; end of input: exit
    for _ in range(burst):
        msg.id = sent
        sent += 1
        pub.publish(msg)
    print("sent", flush=True)
"""


@dataclass
class Round:
    """One burst, counted from the node's /diagnostics."""

    burst: int
    received: int
    answered: int
    lost: int
    settled_s: float

    @property
    def overwritten(self) -> int:
        return self.burst - self.received

    @property
    def miscounted(self) -> str | None:
        """What the node got wrong, or None."""
        if self.answered != self.received:
            return f"miscount: {self.received} received, {self.answered} answered"
        if self.lost > self.overwritten:
            return f"miscount: {self.lost} counted lost, {self.overwritten} overwritten"
        return None


def counts(client: GraspClient) -> dict[str, int]:
    values = client.next_diagnostics(timeout=10.0)
    return {key: int(values[key]) for key in COUNTS}


def settled(client: GraspClient, before: dict[str, int]) -> tuple[dict[str, int], float]:
    """The node's counts once they stop changing (see STABLE_READINGS) with every
    received query answered, or after SETTLE_S; and the seconds that took."""
    began = time.monotonic()
    last, same = counts(client), 1
    while time.monotonic() - began < SETTLE_S:
        now = counts(client)
        same = same + 1 if now == last else 1
        last = now
        answered_all = (now["answered"] - before["answered"]
                        == now["received"] - before["received"])
        if same >= STABLE_READINGS and answered_all and not now["pending_single_queries"]:
            break
    return last, time.monotonic() - began


def burst_round(node: subprocess.Popen[bytes], publisher: subprocess.Popen[str],
                client: GraspClient, burst: int) -> Round:
    assert publisher.stdin is not None and publisher.stdout is not None
    before, _ = settled(client, counts(client))
    node.send_signal(signal.SIGSTOP)  # the node takes nothing meanwhile
    try:
        publisher.stdin.write("go\n")
        publisher.stdin.flush()
        if publisher.stdout.readline().strip() != "sent":
            raise RuntimeError("the publisher did not send its burst")
    finally:
        node.send_signal(signal.SIGCONT)
    after, seconds = settled(client, before)
    change = {key: after[key] - before[key] for key in COUNTS}
    return Round(burst, change["received"], change["answered"], change["messages_lost"],
                 seconds)


def report(index: int, done: Round, depth: int) -> None:
    print(f"round {index}: {done.burst:,} queries from a KEEP_LAST {depth} publisher while "
          f"the node was stopped: {done.received:,} received ({done.overwritten:,} "
          f"overwritten), {done.answered:,} answered, {done.lost:,} reported lost by the "
          f"rmw (counts settled in {done.settled_s:.1f} s)")
    if done.miscounted:
        print(f"    {done.miscounted}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="queries overwritten by a KEEP_LAST "
                                                 "publisher: received, answered, reported")
    parser.add_argument("--burst", type=int, default=None,
                        help=f"queries per burst (default {BURST:,}; --quick {QUICK_BURST:,})")
    parser.add_argument("--depth", type=int, default=DEPTH,
                        help=f"the publisher's KEEP_LAST depth (default {DEPTH})")
    parser.add_argument("--rounds", type=int, default=None,
                        help=f"bursts (default {ROUNDS}; --quick 1)")
    parser.add_argument("--quick", action="store_true", help="the smoke test's short form")
    args = parser.parse_args(argv)
    burst = args.burst or (QUICK_BURST if args.quick else BURST)
    rounds = args.rounds or (1 if args.quick else ROUNDS)
    rclpy.init()
    node, client = start_node("loss", ["-p", "workers:=0"])
    publisher = subprocess.Popen(
        [sys.executable, "-c", PUBLISHER, f"{node_namespace('loss')}/contacts", str(burst),
         str(args.depth), str(MATCH_TIMEOUT_S)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert publisher.stdout is not None
        if publisher.stdout.readline().strip() != "matched":
            raise RuntimeError(f"the publisher found no subscription within "
                               f"{MATCH_TIMEOUT_S:g} s")
        done = [burst_round(node, publisher, client, burst) for _ in range(rounds)]
    finally:
        publisher.kill()
        publisher.wait()
        stop_node(node, client)
        rclpy.try_shutdown()
    for index, one in enumerate(done, 1):
        report(index, one, args.depth)
    overwritten = sum(one.overwritten for one in done)
    lost = sum(one.lost for one in done)
    print(f"{rounds} round(s): {burst * rounds:,} sent, {overwritten:,} overwritten, "
          f"{lost:,} reported lost by the rmw"
          + (f" ({lost / overwritten:.2%} of the overwritten)" if overwritten else "")
          + f"; rounds where the rmw reported a loss: {sum(one.lost > 0 for one in done)}")
    wrong = [one for one in done if one.miscounted]
    print(f"every received query answered, no more counted lost than overwritten: "
          f"{'no' if wrong else 'yes'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
