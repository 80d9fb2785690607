"""Soak benchmark: the node in its own process under mixed load for minutes.

Three loops share one GraspClient: single-grasp queries back to back (the client's
window is the flow control), batches of --batch-size grasps one after the other, and
one-grasp service calls every --service-period seconds. At the end the load stops and
every query still unanswered is waited for (--drain seconds).

Prints loss (queries never answered: must be 0), p50/p99 latency per interface, and the
node's resident memory (its process and its worker processes) over time, with the
growth from the first sample after warm-up (a tenth of the run) to the last.

Usage: python benchmarks/bench_soak.py [--minutes M] [--batch-size S] [--object NAME]
       python benchmarks/bench_soak.py --quick    # the smoke test's form (~20 s)
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from collections.abc import Sequence
from concurrent.futures import Future
from pathlib import Path

import numpy as np
import rclpy

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_ros import REPLY_TIMEOUT_S, process_tree, start_node, stop_node  # noqa: E402
from grasp_fc_ros.objects import make_object, sample_grasps  # noqa: E402

N_FINGERS = 6
RSS_PERIOD_S = 5.0
TARGET_RSS_GROWTH = 0.05


def tree_rss_mib(pid: int) -> float:
    """Resident memory (MiB) of process ``pid`` and all its descendants (Linux /proc)."""
    total_kib = 0
    for member in process_tree(pid):
        try:
            for line in Path(f"/proc/{member}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    total_kib += int(line.split()[1])
        except OSError:
            continue
    return total_kib / 1024


class Recorder:
    """Latencies per interface and the futures not answered yet (thread-safe)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.latency_ms: dict[str, list[float]] = {"single": [], "batch": [], "service": []}
        self.sent = dict.fromkeys(self.latency_ms, 0)
        self.pending: set[Future] = set()

    def watch(self, kind: str, future: Future, n_queries: int = 1) -> None:
        start = time.perf_counter()
        with self.lock:
            self.sent[kind] += n_queries
            self.pending.add(future)

        def done(f: Future) -> None:
            with self.lock:
                self.pending.discard(f)
                if not f.cancelled() and f.exception() is None:
                    self.latency_ms[kind].append((time.perf_counter() - start) * 1e3)

        future.add_done_callback(done)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="soak benchmark of the force_closure node")
    parser.add_argument("--minutes", type=float, default=10.0, help="duration of the load")
    parser.add_argument("--batch-size", type=int, default=200, help="grasps per batch")
    parser.add_argument("--service-period", type=float, default=0.05,
                        help="seconds between service calls")
    parser.add_argument("--drain", type=float, default=120.0,
                        help="seconds to wait for the last answers")
    parser.add_argument("--object", default="box", help="built-in object")
    parser.add_argument("--quick", action="store_true",
                        help="the smoke test's form: 0.2 min of load, 60 s to drain")
    args = parser.parse_args(argv)
    if args.quick:
        args.minutes, args.drain = 0.2, 60.0

    positions, normals = sample_grasps(make_object(args.object), 5000, N_FINGERS,
                                       np.random.default_rng(0))
    rclpy.init()
    node, client = start_node("soak")
    record = Recorder()
    stop = threading.Event()
    rng = np.random.default_rng(1)

    def singles() -> None:
        i = 0
        while not stop.is_set():
            k = i % len(positions)
            record.watch("single", client.submit(positions[k], normals[k], timeout=REPLY_TIMEOUT_S))
            i += 1

    def batches() -> None:
        while not stop.is_set():
            pick = rng.integers(0, len(positions), args.batch_size)
            future = client.submit_batch(positions[pick], normals[pick])
            record.watch("batch", future, args.batch_size)
            future.result(REPLY_TIMEOUT_S)

    def service() -> None:
        while not stop.is_set():
            k = int(rng.integers(0, len(positions)))
            start = time.perf_counter()
            client.call(positions[k:k + 1], normals[k:k + 1], timeout=REPLY_TIMEOUT_S)
            with record.lock:
                record.sent["service"] += 1
                record.latency_ms["service"].append((time.perf_counter() - start) * 1e3)
            time.sleep(args.service_period)

    threads = [threading.Thread(target=f, daemon=True) for f in (singles, batches, service)]
    try:
        print(f"soak: {args.minutes:g} min of mixed load (singles back to back, batches of "
              f"{args.batch_size}, a service call every {args.service_period} s); "
              f"{os.cpu_count()} CPUs")
        start = time.monotonic()
        rss = [(0.0, tree_rss_mib(node.pid))]
        for thread in threads:
            thread.start()
        while time.monotonic() - start < 60 * args.minutes:
            time.sleep(RSS_PERIOD_S)
            rss.append((time.monotonic() - start, tree_rss_mib(node.pid)))
            print(f"  t={rss[-1][0]:6.0f} s  node RSS {rss[-1][1]:7.1f} MiB  answered "
                  f"{ {k: len(v) for k, v in record.latency_ms.items()} }", flush=True)
        stop.set()
        for thread in threads:
            thread.join(REPLY_TIMEOUT_S)
        deadline = time.monotonic() + args.drain
        while record.pending and time.monotonic() < deadline:
            time.sleep(0.1)
        lost = len(record.pending)
        print(f"sent: {record.sent}; lost (never answered): {lost}  "
              f"[target 0: {'meets target' if lost == 0 else 'BELOW target'}]")
        for kind, times in record.latency_ms.items():
            if times:
                print(f"  {kind:8s} latency p50 {np.percentile(times, 50):8.2f} ms, "
                      f"p99 {np.percentile(times, 99):8.2f} ms over {len(times)}")
        warm = next((r for t, r in rss if t >= 6 * args.minutes), rss[-1][1])
        growth = rss[-1][1] / warm - 1
        print(f"node RSS: start {rss[0][1]:.1f} MiB, after warm-up {warm:.1f} MiB, end "
              f"{rss[-1][1]:.1f} MiB, max {max(r for _, r in rss):.1f} MiB -> growth "
              f"{100 * growth:.1f}%  [target < {100 * TARGET_RSS_GROWTH:.0f}%: "
              f"{'meets target' if growth < TARGET_RSS_GROWTH else 'BELOW target'}]")
        return 0 if lost == 0 else 1
    finally:
        stop.set()
        stop_node(node, client)
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
