"""Several clients at once: does every answer reach its asker, and only its asker?

The force_closure node in its own process; beside it one busy process (a Python loop
taking a core) and --clients client processes, each a grasp_fc_ros.client.GraspClient
sending --singles single queries (ids 0..N-1, back to back within its window) and one
batch of --batch 6-finger grasps, all at once. --pause-first S stops the first client
(SIGSTOP) for S seconds meanwhile: a reader that falls behind the others.

Prints per client: single queries answered, lost (no answer within --timeout), wrong
(an answer not to this client, an id it did not send, or an id answered twice), the
batch answered whole, the grasps the client re-sent (a node (re)appeared, or no answer
within the client's bound) and its seconds; then the totals (target: 0 lost, 0 wrong)
and the throughput: all clients' single queries per second, and all grasps per second;
the CPU time of each client process per single query (what reading answers costs it);
and the CPU time of the node's own process (receiving, answering, publishing; its
workers not counted) per single query. The machine's other load changes the rates,
not the losses or the CPU time.

Usage: python benchmarks/bench_clients.py [--clients C] [--singles N] [--batch B]
       [--busy P] [--timeout S] [--pause-first S] [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Sequence

import numpy as np

N_FINGERS = 6
CONNECT_TIMEOUT_S = 60.0
# With --pause-first: how long after the start the first client is stopped (s).
PAUSE_AFTER_S = 0.5
# What the issue asks of 4 clients x (20,000 singles + a 50,000-grasp batch).
TARGET_LOST = 0


def run_client(namespace: str, singles: int, batch: int, timeout: float, seed: int,
               out: str) -> dict:
    """One client process's run: what it sent and what came back (see the module
    docstring). Once connected it makes ``<out>.ready`` and starts when ``<out>.go``
    exists (all clients start together)."""
    import rclpy

    from grasp_fc_ros.client import GraspClient
    from grasp_fc_ros.objects import make_object, sample_grasps

    rng = np.random.default_rng(seed)
    positions, normals = sample_grasps(make_object("box"), max(batch, 1000), N_FINGERS, rng)
    rclpy.init()
    client = GraspClient(f"{namespace}/force_closure")
    try:
        if not client.wait_for_node(CONNECT_TIMEOUT_S):
            return {"error": "node not found"}
        open(out + ".ready", "w").close()
        while not os.path.exists(out + ".go"):
            time.sleep(0.01)
        start, cpu_s = time.time(), time.process_time()
        deadline = time.monotonic() + timeout
        batch_future = client.submit_batch(positions[:batch], normals[:batch])
        futures = [client.submit(positions[i % len(positions)], normals[i % len(positions)],
                                 query_id=i, timeout=timeout) for i in range(singles)]
        answered, wrong, seen = 0, 0, set()
        for i, future in enumerate(futures):
            try:
                v = future.result(max(deadline - time.monotonic(), 0.0))
            except TimeoutError:
                continue
            answered += 1
            if v.client_id != client.client_id or v.id != i or v.id in seen:
                wrong += 1
            seen.add(v.id)
        try:
            verdicts = batch_future.result(max(deadline - time.monotonic(), 0.0))
            batch_ok = bool(np.array_equal(verdicts.ids, np.arange(batch)))
        except TimeoutError:
            batch_ok = False
        return {"client_id": client.client_id, "answered": answered,
                "lost": singles - answered, "wrong": wrong, "batch_ok": batch_ok,
                "resent": client.resubmitted, "start": start, "end": time.time(),
                "cpu_s": time.process_time() - cpu_s}
    finally:
        client.close()
        rclpy.try_shutdown()


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="several GraspClients at once")
    parser.add_argument("--clients", type=int, default=4)
    parser.add_argument("--singles", type=int, default=20_000, help="single queries per client")
    parser.add_argument("--batch", type=int, default=50_000, help="grasps of each client's batch")
    parser.add_argument("--busy", type=int, default=1, help="busy processes beside them")
    parser.add_argument("--timeout", type=float, default=300.0,
                        help="seconds a client waits for all its answers")
    parser.add_argument("--pause-first", type=float, default=0.0, metavar="S",
                        help="SIGSTOP the first client for S seconds once all have started "
                             "(a reader that falls behind)")
    parser.add_argument("--quick", action="store_true",
                        help="small sizes (2,000 singles, a 5,000-grasp batch), for the tests")
    parser.add_argument("--client", nargs=3, metavar=("NAMESPACE", "SEED", "OUT"),
                        help=argparse.SUPPRESS)  # one client process's run
    args = parser.parse_args(argv)
    if args.quick:
        args.singles, args.batch, args.timeout = 2_000, 5_000, 120.0
    if args.client:
        namespace, seed, out = args.client
        result = run_client(namespace, args.singles, args.batch, args.timeout, int(seed), out)
        with open(out, "w") as f:
            json.dump(result, f)
        return 0
    return run_all(args)


def run_all(args: argparse.Namespace) -> int:
    import tempfile

    import rclpy

    from bench_ros import process_cpu_s, start_node, stop_node

    rclpy.init()
    node, watcher = start_node("clients")
    namespace = f"/grasp_fc_clients_{os.getpid()}"  # start_node's for this tag
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
            for _ in range(args.busy)]
    results = []
    try:
        with tempfile.TemporaryDirectory() as folder:
            outs = [f"{folder}/client_{k}.json" for k in range(args.clients)]
            clients = [subprocess.Popen(
                [sys.executable, __file__, "--singles", str(args.singles), "--batch",
                 str(args.batch), "--timeout", str(args.timeout), "--client", namespace,
                 str(k), out]) for k, out in enumerate(outs)]
            ready = time.monotonic() + 2 * CONNECT_TIMEOUT_S
            while (not all(os.path.exists(out + ".ready") for out in outs)
                   and time.monotonic() < ready and all(c.poll() is None for c in clients)):
                time.sleep(0.05)
            node_cpu_s = process_cpu_s(node.pid)
            for out in outs:
                open(out + ".go", "w").close()
            if args.pause_first:
                time.sleep(PAUSE_AFTER_S)
                clients[0].send_signal(signal.SIGSTOP)
                time.sleep(args.pause_first)
                clients[0].send_signal(signal.SIGCONT)
            for process in clients:
                end_of(process, args.timeout + 2 * CONNECT_TIMEOUT_S)
            node_cpu_s = process_cpu_s(node.pid) - node_cpu_s
            for out in outs:
                try:
                    with open(out) as f:
                        results.append(json.load(f))
                except FileNotFoundError:
                    results.append({"error": "no result (the client process failed)"})
    finally:
        for process in busy:
            process.kill()
            process.wait()
        stop_node(node, watcher)
        rclpy.try_shutdown()
    return report(args, results, node_cpu_s)


def end_of(process: subprocess.Popen, timeout: float) -> None:
    """Wait for a client process; kill it if it has not ended within ``timeout`` (its
    result, written before it exits, still counts)."""
    try:
        process.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        print(f"a client process (pid {process.pid}) did not exit within {timeout:.0f} s: "
              f"killed", file=sys.stderr)
        process.kill()
        process.wait()


def report(args: argparse.Namespace, results: list[dict], node_cpu_s: float) -> int:
    print(f"{args.clients} clients x ({args.singles} single queries + a {args.batch}-grasp "
          f"batch), {args.busy} busy process(es) beside them"
          + (f", client 0 stopped for {args.pause_first} s" if args.pause_first else ""))
    for k, r in enumerate(results):
        if "error" in r:
            print(f"  client {k}: {r['error']}")
            continue
        print(f"  client {k}: {r['answered']} answered, {r['lost']} lost, {r['wrong']} wrong, "
              f"batch {'answered whole' if r['batch_ok'] else 'NOT answered whole'}, "
              f"{r['resent']} grasps re-sent, {r['end'] - r['start']:.1f} s")
    lost = sum(r.get("lost", args.singles) for r in results)
    wrong = sum(r.get("wrong", 0) for r in results)
    batches = sum(bool(r.get("batch_ok")) for r in results)
    ran = [r for r in results if "error" not in r]
    wall = (max(r["end"] for r in ran) - min(r["start"] for r in ran)) if ran else float("nan")
    print(f"lost answers: {lost} (target {TARGET_LOST}); wrong answers: {wrong}; "
          f"batches answered whole: {batches} of {args.clients}")
    print(f"throughput: {args.clients * args.singles / wall:.0f} single queries/s, "
          f"{args.clients * (args.singles + args.batch) / wall:.0f} grasps/s "
          f"({wall:.1f} s from the first client's start to the last one's end)")
    if ran:
        per_query = [1e6 * r["cpu_s"] / args.singles for r in ran]
        print(f"client process CPU per single query (its batch included): median "
              f"{np.median(per_query):.0f} us (min {min(per_query):.0f}, "
              f"max {max(per_query):.0f})")
    print(f"node process CPU (its workers not counted): {node_cpu_s:.2f} s, "
          f"{1e6 * node_cpu_s / (args.clients * args.singles):.0f} us per single query")
    return 0


if __name__ == "__main__":
    sys.exit(main())
