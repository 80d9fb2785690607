"""Benchmark of grasp-fc-label as cluster work: what a chunk costs beyond its compute, what
the scheduler and the client sustain, what a grasp costs on disk, and a lost host.

Sections (``--sections``, default all):

* ``overhead``: for each column set (verdicts; + epsilon; + robustness radii; + radii and
  holds_under at errors of 2 mm, 3 degrees, friction 0.1; + radii and the probability of
  force closure, 1,000 samples at issue 29's noise: the same sigmas) at its default chunk
  size, ``--chunks`` chunks labelled in this process
  (``label_chunk``, the compute) and by ``run`` on a LocalCluster of one worker: the
  overhead per chunk by wall time and by the worker's CPU time (everything the labeller
  adds: checking pass, task, transfer; the part written by the client overlaps the next
  chunk), the client's CPU per chunk (it holds the scheduler too), output bytes per grasp,
  and grasps/s with 1 and 2 workers;
* ``tasks``: scheduler throughput: no-op tasks per second on 2 workers, and chunks per
  second through ``run`` at 10 grasps a chunk (the client's ceiling, parts included);
* ``hosts``: three hosts as network namespaces (test/net_hosts.py; skipped where they
  cannot be made): a scheduler and the client on one, a worker on each of two others;
  runs of ``--loss-grasps`` grasps without incident, with a worker host cut after a third
  of the chunks (under Dask's defaults, each setting of ``net_hosts.FAST_LOSS_CONFIG``
  alone, and all of them), and with it frozen instead (defaults, all): seconds from the
  incident to the scheduler removing the worker, what it added to the run, and every row
  checked once and equal to a one-process run; then the long forms, each in one run with
  a cut: ``--hosts-grasps`` (default 10^7) verdicts, and as many verdicts as samples of
  the probability (10^4 grasps x 1,000 samples, with ``--robustness``).

The machine may be shared: wall-time figures then include other work; CPU times less so.

    python benchmarks/bench_label_cluster.py                      # everything (~15 min)
    python benchmarks/bench_label_cluster.py --sections overhead
    python benchmarks/bench_label_cluster.py --quick              # smoke test
"""

from __future__ import annotations

import os

# One core per process, as Dask's workers run (and the targets are stated).
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import datetime  # noqa: E402
import re  # noqa: E402
import shutil  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections.abc import Sequence  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import TYPE_CHECKING, Any  # noqa: E402

import numpy as np  # noqa: E402
import pyarrow as pa  # noqa: E402
import pyarrow.parquet as pq  # noqa: E402

from grasp_fc_ros.labelling import Plan, dask_client, open_input, run  # noqa: E402
from grasp_fc_ros.labelling.robustness import Robustness  # noqa: E402
from grasp_fc_ros.labelling.tasks import label_chunk  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "test"))
import net_hosts  # noqa: E402
from bench_label import write_npz_by_chunks  # noqa: E402

if TYPE_CHECKING:
    from distributed import Client

SECTIONS = ("overhead", "tasks", "hosts")
MU = 0.5
BIN = Path(sys.executable).parent
# Issue 29's noise: 2 mm, 3 degrees, friction 0.1 (the objects are in metres).
PROBABILITY = Robustness(position_sigma=0.002, normal_sigma=float(np.radians(3.0)),
                         friction_sigma=0.1)
HOLDS = Robustness(position_error=0.002, normal_error=float(np.radians(3.0)),
                   friction_error=0.1)
COLUMN_SETS: dict[str, dict[str, Any]] = {
    "verdicts": {},
    "+ epsilon": {"quality_rtol": 1e-3},
    "+ radii": {"robustness": Robustness()},
    "+ holds": {"robustness": HOLDS},
    "+ probability": {"robustness": PROBABILITY},
}


def write_npz(path: Path, n_grasps: int, n_fingers: int, seed: int) -> Path:
    """Random box grasps with mu = MU, written block by block (bounded memory)."""
    write_npz_by_chunks(path, n_grasps, n_fingers, 100_000, seed=seed, mu=MU)
    return path


def _cpu_seconds() -> float:
    return time.process_time()


def _worker_cpu(client: Client) -> float:
    return float(sum(client.run(_cpu_seconds).values()))


def _idle_share(client: Client, seconds: float = 5.0) -> float:
    """The share of a core the workers use while idle (heartbeats, monitors, profiler):
    part of the worker CPU overhead, in proportion to wall time rather than chunks."""
    cpu, start = _worker_cpu(client), time.perf_counter()
    time.sleep(seconds)
    return (_worker_cpu(client) - cpu) / (time.perf_counter() - start)


def _in_process(path: Path, plan: Plan) -> tuple[list[float], list[float]]:
    """Wall and CPU seconds of label_chunk on each of the plan's chunks, here."""
    source = open_input(path)
    walls, cpus = [], []
    for chunk in plan.chunks:
        wall, cpu = time.perf_counter(), time.process_time()
        label_chunk(source, chunk.start, chunk.stop, plan.use_filter, plan.origins,
                    plan.quality_rtol, plan.robustness)
        walls.append(time.perf_counter() - wall)
        cpus.append(time.process_time() - cpu)
    return walls, cpus


def _warm(path: str, settings: dict[str, Any]) -> None:
    """Compile and import on a worker what a chunk of these columns needs."""
    plan = Plan([open_input(path)], **{**settings, "chunk_size": 2})
    label_chunk(plan.sources[0], 0, 2, plan.use_filter, plan.origins, plan.quality_rtol,
                plan.robustness)


def timed_run(client: Client, plan: Plan, out: Path) -> dict[str, float]:
    """One run of ``plan``: wall seconds, the workers' and this process's (client and
    scheduler) CPU seconds, output bytes."""
    worker_cpu, client_cpu = _worker_cpu(client), time.process_time()
    start = time.perf_counter()
    run(plan, out, client, progress=False)
    measured = {"seconds": time.perf_counter() - start,
                "worker_cpu": _worker_cpu(client) - worker_cpu,
                "client_cpu": time.process_time() - client_cpu,
                "bytes": float(sum(part.stat().st_size for part in out.glob("part-*")))}
    shutil.rmtree(out)
    return measured


def overhead(folder: Path, chunks: int, fingers: int, repeats: int) -> None:
    print(f"\n== overhead per chunk at the default chunk sizes ({chunks} chunks of "
          f"{fingers}-finger box grasps, mu = {MU}); medians of {repeats} rounds of: the "
          "chunks in this process, then a run on 1 worker less a run of 2 grasps (the "
          "run's fixed cost)")
    print(f"{'columns':15} {'chunk':>7} {'compute/chunk wall, CPU':>24} {'overhead wall':>20} "
          f"{'overhead worker CPU':>20} {'client CPU':>11} {'fixed':>7} {'B/grasp':>8} "
          f"{'grasps/s 1 w':>13} {'2 w':>9} {'idle worker':>12}")
    tiny = write_npz(folder / "tiny.npz", 2, fingers, seed=9)
    for name, settings in COLUMN_SETS.items():
        size = Plan([], **settings).chunk_size
        assert size is not None
        path = write_npz(folder / "overhead.npz", chunks * size, fingers, seed=3)
        plan = Plan([open_input(path)], **settings)
        small = Plan([open_input(tiny)], **settings)
        n, rows = len(plan.chunks), plan.n_grasps
        _warm(str(path), settings)
        rounds: dict[str, list[float]] = {key: [] for key in (
            "compute", "compute_cpu", "wall", "cpu", "client", "fixed", "rate")}
        with dask_client(workers=1) as client:
            client.run(_warm, str(path), settings)
            idle = _idle_share(client)
            for _ in range(repeats):
                walls, cpus = _in_process(path, plan)
                fixed = timed_run(client, small, folder / "out")
                whole = timed_run(client, plan, folder / "out")
                rounds["compute"].append(statistics.median(walls))
                rounds["compute_cpu"].append(statistics.median(cpus))
                rounds["wall"].append((whole["seconds"] - fixed["seconds"]) / n
                                      - statistics.median(walls))
                rounds["cpu"].append((whole["worker_cpu"] - fixed["worker_cpu"]) / n
                                     - statistics.median(cpus))
                rounds["client"].append((whole["client_cpu"] - fixed["client_cpu"]) / n)
                rounds["fixed"].append(fixed["seconds"])
                rounds["rate"].append(rows / whole["seconds"])
        with dask_client(workers=2) as client:
            client.run(_warm, str(path), settings)
            two = timed_run(client, plan, folder / "out")
        m = {key: statistics.median(values) for key, values in rounds.items()}
        print(f"{name:15} {size:7,} {m['compute']:10.3f} s, {m['compute_cpu']:8.3f} s "
              f"{1e3 * m['wall']:9.1f} ms ({m['wall'] / m['compute']:6.1%}) "
              f"{1e3 * m['cpu']:9.1f} ms ({m['cpu'] / m['compute_cpu']:6.1%}) "
              f"{1e3 * m['client']:8.1f} ms {m['fixed']:5.2f} s "
              f"{whole['bytes'] / rows:8.1f} {m['rate']:13,.1f} {rows / two['seconds']:9,.1f} "
              f"{idle:8.1%} CPU")
        path.unlink()


def _noop(i: int) -> int:
    return i


def tasks(folder: Path, n_tasks: int, n_grasps: int) -> None:
    from distributed import wait

    print("\n== scheduler and client throughput (LocalCluster, 2 workers)")
    with dask_client(workers=2) as client:
        client.map(_noop, range(100), pure=False)  # warm-up
        start = time.perf_counter()
        futures = client.map(_noop, range(n_tasks), pure=False)
        wait(futures)
        seconds = time.perf_counter() - start
        del futures
        print(f"no-op tasks: {n_tasks:,} in {seconds:.2f} s = {n_tasks / seconds:,.0f} "
              "tasks/s (submitted together, results left on the workers)")
        path = write_npz(folder / "tiny.npz", n_grasps, 4, seed=4)
        plan = Plan([open_input(path)], chunk_size=10)
        start = time.perf_counter()
        run(plan, folder / "tiny", client, progress=False)
        seconds = time.perf_counter() - start
        n = len(plan.chunks)
        print(f"grasp-fc-label, chunks of 10 grasps: {n:,} chunks in {seconds:.2f} s = "
              f"{n / seconds:,.0f} chunks/s (checking pass, tasks, results to the client, "
              "one Parquet part each)")
        shutil.rmtree(folder / "tiny")


# --- three hosts ----------------------------------------------------------------------

_LOG_TIME = re.compile(r"^(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3}) .*Remove worker addr: "
                       r"(tcp://[0-9.]+):", re.M)


def _removed_at(log: str, address: str) -> float | None:
    """When the scheduler removed the worker at ``address`` (epoch seconds), from its log."""
    for stamp, where in _LOG_TIME.findall(log):
        if where == f"tcp://{address}":
            local = datetime.datetime.strptime(stamp, "%Y-%m-%d %H:%M:%S,%f")
            return local.timestamp()
    return None


def hosts_run(folder: Path, path: Path, chunk: int, config: dict[str, str],
              incident: str | None = None, cap: float = 120.0,
              options: Sequence[str] = ()) -> dict[str, float]:
    """One grasp-fc-label run across three hosts. ``incident`` ("cut" or "freeze") hits
    worker host 2 once a third of the parts are written (while it holds chunks); a frozen
    host not removed by the scheduler within ``cap`` seconds is resumed so the run ends.
    ``options`` go to grasp-fc-label. Returns seconds, parts at the incident, seconds from
    it to the worker's removal, and how many workers the scheduler removed."""
    out = folder / "hosts-out"
    shutil.rmtree(out, ignore_errors=True)
    n_chunks = len(Plan([open_input(path)], chunk_size=chunk).chunks)
    env = net_hosts.dask_environment(config)
    result: dict[str, float] = {}
    with net_hosts.Hosts(3, folder / "hosts") as hosts:
        address = net_hosts.start_dask(hosts, BIN / "dask", (1, 2), env)
        scheduler = hosts.processes[0][1]
        watcher = net_hosts.Watcher(hosts, sys.executable, address)
        start = time.perf_counter()
        labeller = hosts.popen(0, [str(BIN / "grasp-fc-label"), str(path), "--out", str(out),
                                   "--chunk-size", str(chunk), "--scheduler", address,
                                   "--no-progress", *options], env=env)
        if incident is not None:
            lost = f"tcp://{hosts.address(2)}:"
            while labeller.poll() is None and not (
                    len(list(out.glob("part-*"))) >= n_chunks / 3
                    and any(w.startswith(lost) and k
                            for w, k in watcher.processing().items())):
                time.sleep(0.02)
            hit_at = time.time()
            if incident == "cut":
                hosts.cut(2)
            else:
                hosts.freeze(2)
            result["parts_at_incident"] = len(list(out.glob("part-*")))
            while (incident == "freeze" and labeller.poll() is None
                   and _removed_at(hosts.log(scheduler), hosts.address(2)) is None):
                if time.time() - hit_at > cap:
                    hosts.freeze(2, resume=True)
                    break
                time.sleep(0.1)
        labeller.wait()
        result["seconds"] = time.perf_counter() - start
        if labeller.returncode:
            raise RuntimeError(f"grasp-fc-label failed:\n{hosts.log(labeller)}")
        if incident is not None:
            removed = _removed_at(hosts.log(scheduler), hosts.address(2))
            result["to_removal"] = float("nan") if removed is None else removed - hit_at
        result["removed"] = len(_LOG_TIME.findall(hosts.log(scheduler)))
    return result


def _check_one_process(folder: Path, path: Path, chunk: int,
                       robustness: Robustness | None = None) -> str:
    """Every row once, in order, and equal to label_chunk in this process, chunk by chunk
    (every column; NaN equal to NaN)."""
    source = open_input(path)
    parts = sorted((folder / "hosts-out").glob("part-*.parquet"))
    n_chunks = -(-source.n_grasps // chunk)
    if len(parts) != n_chunks:
        return f"WRONG: {len(parts)} parts for {n_chunks} chunks"
    for index, part in enumerate(parts):
        table = pq.read_table(part)
        start = index * chunk
        expected = label_chunk(source, start, min(start + chunk, source.n_grasps), "auto",
                               "seed", robustness=robustness)
        if table.column_names != expected.column_names or not all(
                np.array_equal(table[key].to_numpy(), expected[key].to_numpy(),
                               equal_nan=True)
                if pa.types.is_floating(table[key].type) else table[key].equals(expected[key])
                for key in table.column_names):
            return f"WRONG: {part.name} differs from a one-process run"
    return "every row once, equal to a one-process run"


#: Dask settings tried against a lost host: each of FAST_LOSS_CONFIG's alone, and all.
LOSS_CONFIGS: dict[str, dict[str, str]] = {
    "Dask defaults": {},
    **{f"{key.split('.')[-1]} {value}": {key: value}
       for key, value in net_hosts.FAST_LOSS_CONFIG.items()},
    "FAST_LOSS_CONFIG": net_hosts.FAST_LOSS_CONFIG,
}


def hosts(folder: Path, loss_grasps: int, long_grasps: int, chunk: int, cap: float) -> None:
    reason = net_hosts.unavailable()
    print("\n== three hosts (network namespaces): a scheduler and the client, 2 worker hosts "
          "with a worker (and its nanny) each")
    if reason is not None:
        print(f"skipped: {reason}")
        return
    path = write_npz(folder / "loss.npz", loss_grasps, 6, seed=5)
    print(f"{loss_grasps:,} six-finger grasps, chunks of {chunk:,}; worker host 2 hit after "
          "a third of the chunks: cut (link down, processes killed) or frozen (SIGSTOP, "
          f"link up; resumed after {cap:.0f} s if still there)")
    whole = hosts_run(folder, path, chunk, net_hosts.FAST_LOSS_CONFIG)
    print(f"{'no incident':22}: {whole['seconds']:6.1f} s")
    runs = [(name, config, "cut") for name, config in LOSS_CONFIGS.items()]
    runs += [(name, LOSS_CONFIGS[name], "freeze") for name in ("Dask defaults",
                                                                "FAST_LOSS_CONFIG")]
    for name, config, incident in runs:
        hit = hosts_run(folder, path, chunk, config, incident, cap)
        removal = hit["to_removal"]
        removed = (f"{removal:5.1f} s" if removal == removal
                   else f"not within {cap:.0f} s")
        print(f"{incident + ', ' + name:22}: {hit['seconds']:6.1f} s "
              f"(+{hit['seconds'] - whole['seconds']:5.1f} s); to the worker's removal "
              f"{removed}; parts at the incident {hit['parts_at_incident']:.0f}; "
              f"workers removed {hit['removed']:.0f}; {_check_one_process(folder, path, chunk)}")
    path.unlink()
    if not long_grasps:
        return
    long_chunk = 100_000
    path = write_npz(folder / "long.npz", long_grasps, 3, seed=6)
    long = hosts_run(folder, path, long_chunk, net_hosts.FAST_LOSS_CONFIG, "cut")
    print(f"long form: {long_grasps:,} three-finger grasps (verdicts), chunks of "
          f"{long_chunk:,}, FAST_LOSS_CONFIG, a worker host cut after a third: "
          f"{long['seconds']:.1f} s ({long_grasps / long['seconds']:,.0f} grasps/s); cut -> "
          f"removed {long['to_removal']:.1f} s; workers removed {long['removed']:.0f}; "
          f"{_check_one_process(folder, path, long_chunk)}")
    path.unlink()
    # The same verdicts' worth as samples of the probability, in its default chunks.
    grasps = long_grasps // PROBABILITY.samples
    path = write_npz(folder / "long.npz", grasps, 6, seed=7)
    chunk = Plan([], robustness=PROBABILITY).rows_per_chunk
    options = ["--robustness", "--position-sigma", str(PROBABILITY.position_sigma),
               "--normal-sigma", str(PROBABILITY.normal_sigma), "--friction-sigma",
               str(PROBABILITY.friction_sigma)]
    long = hosts_run(folder, path, chunk, net_hosts.FAST_LOSS_CONFIG, "cut", options=options)
    print(f"long form: {grasps:,} six-finger grasps x {PROBABILITY.samples:,} samples "
          f"(--robustness with the probability), chunks of {chunk:,}, FAST_LOSS_CONFIG, a "
          f"worker host cut after a third: {long['seconds']:.1f} s "
          f"({grasps * PROBABILITY.samples / long['seconds']:,.0f} samples/s); cut -> "
          f"removed {long['to_removal']:.1f} s; workers removed {long['removed']:.0f}; "
          f"{_check_one_process(folder, path, chunk, PROBABILITY)}")


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sections", default=",".join(SECTIONS),
                        help=f"comma-separated, of {', '.join(SECTIONS)} (default all)")
    parser.add_argument("--chunks", type=int, default=3,
                        help="chunks per column set in the overhead section (default 3)")
    parser.add_argument("--repeats", type=int, default=3,
                        help="rounds per column set in the overhead section (default 3)")
    parser.add_argument("--fingers", type=int, default=6)
    parser.add_argument("--columns", default=",".join(COLUMN_SETS),
                        help="comma-separated column sets of the overhead section "
                             f"({', '.join(COLUMN_SETS)}; default all)")
    parser.add_argument("--tasks", type=int, default=20_000, help="no-op tasks (20,000)")
    parser.add_argument("--loss-grasps", type=int, default=600_000,
                        help="grasps of the lost-host runs (default 600,000)")
    parser.add_argument("--loss-chunk", type=int, default=20_000)
    parser.add_argument("--cap", type=float, default=120.0,
                        help="seconds a frozen host may stay before it is resumed (120)")
    parser.add_argument("--hosts-grasps", type=int, default=10_000_000,
                        help="verdicts of the long three-host run (default 10^7; 0 skips)")
    parser.add_argument("--quick", action="store_true", help="tiny sizes (smoke test)")
    args = parser.parse_args(argv)
    if args.quick:
        args.chunks, args.tasks, args.loss_grasps, args.loss_chunk = 2, 2000, 60_000, 5000
        args.repeats, args.cap = 1, 20.0
        args.hosts_grasps = 0
        for name in ("+ epsilon", "+ radii", "+ holds", "+ probability"):
            COLUMN_SETS[name] = {**COLUMN_SETS[name], "chunk_size": 20}
    sections = args.sections.split(",")
    for name in set(COLUMN_SETS) - set(args.columns.split(",")):
        del COLUMN_SETS[name]
    folder = Path(tempfile.mkdtemp(prefix="bench_label_cluster_"))
    try:
        if "overhead" in sections:
            overhead(folder, args.chunks, args.fingers, args.repeats)
        if "tasks" in sections:
            tasks(folder, args.tasks, 2000 if args.quick else 20_000)
        if "hosts" in sections:
            hosts(folder, args.loss_grasps, args.hosts_grasps, args.loss_chunk, args.cap)
    finally:
        shutil.rmtree(folder)


if __name__ == "__main__":
    main()
