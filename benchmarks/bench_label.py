"""Benchmark of grasp-fc-label on a local Dask cluster: scaling, overhead, memory.

Prints:

* the core in-process on one core (``check_force_closure`` chunk after chunk);
* ``grasp-fc-label``'s run (checking pass, labelling, Parquet parts) on a LocalCluster of
  1 and of 2 worker processes: grasps/s, the 2-worker speed-up, and per-worker
  throughput against the core alone, by wall time and by CPU time (the workers' CPU
  seconds against the in-process core's: the overhead figure that survives a machine
  shared with other work, where wall-time ratios mostly measure the other work);
* a large synthetic ``.npz`` (default 10 million three-finger grasps, written chunk by
  chunk, never whole in memory) labelled by 2 workers: grasps/s and the peak resident
  memory of each worker and of the client.

Cluster times include everything after the cluster is up (the checking pass, labelling,
writing); worker start-up is left out. Only loopback addresses are used.

    python benchmarks/bench_label.py              # 200,000 six-finger grasps; 10 M large
    python benchmarks/bench_label.py --quick      # seconds (smoke test)
"""

from __future__ import annotations

import os

# One core per process, as the targets are stated (Dask's workers do the same).
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import resource  # noqa: E402
import shutil  # noqa: E402
import statistics  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import zipfile  # noqa: E402
from collections.abc import Sequence  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import TYPE_CHECKING  # noqa: E402

import numpy as np  # noqa: E402

from grasp_fc_ros.core import check_force_closure  # noqa: E402
from grasp_fc_ros.labelling import Plan, dask_client, open_input, run  # noqa: E402
from grasp_fc_ros.objects import make_object, sample_grasps  # noqa: E402

if TYPE_CHECKING:
    from distributed import Client

MU = float(np.tan(np.radians(10.0)))


def write_npz_by_chunks(path: Path, n_grasps: int, n_fingers: int, chunk: int,
                        seed: int, mu: float = MU) -> None:
    """An uncompressed .npz of random box grasps with friction ``mu``, written chunk by
    chunk (bounded memory)."""
    surface = make_object("box")

    def draw(c: int) -> tuple[np.ndarray, np.ndarray]:
        size = min(chunk, n_grasps - c * chunk)
        return sample_grasps(surface, size, n_fingers, np.random.default_rng([seed, c]))

    shape = (n_grasps, n_fingers, 3)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as archive:
        for which, name in enumerate(("positions", "normals")):
            with archive.open(f"{name}.npy", "w", force_zip64=True) as member:
                np.lib.format.write_array_header_2_0(
                    member, {"descr": "<f8", "fortran_order": False, "shape": shape})
                for c in range(-(-n_grasps // chunk)):
                    member.write(np.ascontiguousarray(draw(c)[which]).tobytes())
        with archive.open("mu.npy", "w") as member:
            np.lib.format.write_array(member, np.asarray(mu, dtype=np.float64))


def core_in_process(path: Path, chunk: int) -> tuple[float, float]:
    """Grasps per wall second and per CPU second of check_force_closure over the file's
    chunks, in this process."""
    source = open_input(path)
    start, cpu = time.perf_counter(), time.process_time()
    for begin in range(0, source.n_grasps, chunk):
        grasps = source.read(begin, min(begin + chunk, source.n_grasps))
        check_force_closure(grasps.positions, grasps.normals, grasps.mu)
    return (source.n_grasps / (time.perf_counter() - start),
            source.n_grasps / (time.process_time() - cpu))


def _warm_up() -> None:
    from grasp_fc_ros.core import check_force_closure as check

    p = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]])
    check(np.stack([p] * 8), -np.stack([p] * 8), MU)


def _peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _cpu_seconds() -> float:
    return time.process_time()


def back_to_back(client: Client, path: Path, chunk: int, repeats: int = 3) -> float:
    """CPU seconds of one chunk in this process and on a worker, alternately: the median
    ratio (worker / in-process) is the worker's overhead, measured under the same load."""
    from grasp_fc_ros.labelling.tasks import label_chunk

    source = open_input(path)
    stop = min(chunk, source.n_grasps)
    ratios: list[float] = []
    for _ in range(repeats):
        cpu = time.process_time()
        label_chunk(source, 0, stop, True, "seed")
        here = time.process_time() - cpu
        before = sum(client.run(_cpu_seconds).values())
        client.submit(label_chunk, source, 0, stop, True, "seed", pure=False).result()
        ratios.append((sum(client.run(_cpu_seconds).values()) - before) / here)
    return statistics.median(ratios)


def on_cluster(path: Path, chunk: int, workers: int,
               out: Path) -> tuple[float, float, float, list[float], float | None]:
    """One labelling run on a fresh cluster: grasps per wall second, seconds, grasps per
    worker CPU second (all workers' CPU time added up), peak RSS MiB of each worker."""
    plan = Plan([open_input(path)], chunk_size=chunk)
    with dask_client(workers=workers) as client:
        client.run(_warm_up)
        cpu_before = sum(client.run(_cpu_seconds).values())
        start = time.perf_counter()
        summary = run(plan, out, client, progress=False)
        seconds = time.perf_counter() - start
        cpu = sum(client.run(_cpu_seconds).values()) - cpu_before
        peaks = sorted(client.run(_peak_rss_mib).values())
        overhead = back_to_back(client, path, chunk) if workers == 1 else None
    shutil.rmtree(out)
    return (summary.grasps_written / seconds, seconds, summary.grasps_written / cpu, peaks,
            overhead)


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--grasps", type=int, default=200_000,
                        help="six-finger grasps of the scaling runs (default 200,000)")
    parser.add_argument("--chunk", type=int, default=20_000, help="chunk size of those runs")
    parser.add_argument("--large", type=int, default=10_000_000,
                        help="three-finger grasps of the large run (default 10 M; 0 skips)")
    parser.add_argument("--large-chunk", type=int, default=100_000)
    parser.add_argument("--quick", action="store_true", help="tiny sizes (smoke test)")
    args = parser.parse_args(argv)
    if args.quick:
        args.grasps, args.chunk, args.large, args.large_chunk = 4000, 1000, 60_000, 20_000

    folder = Path(tempfile.mkdtemp(prefix="bench_label_"))
    try:
        path = folder / "grasps.npz"
        write_npz_by_chunks(path, args.grasps, 6, args.chunk, seed=1)
        print(f"{args.grasps:,} six-finger grasps on the box, mu = tan 10 deg, chunks of "
              f"{args.chunk:,}; one thread per process; the machine may be shared (noisy)")
        core, core_cpu = core_in_process(path, args.chunk)
        print(f"core in-process, 1 core     : {core:10,.0f} grasps/s, {core_cpu:,.0f} per CPU s")
        rates = {}
        for workers in (1, 2):
            rate, seconds, per_cpu, peaks, overhead = on_cluster(path, args.chunk, workers,
                                                                 folder / "out")
            rates[workers] = rate
            print(f"grasp-fc-label, {workers} worker(s) : {rate:10,.0f} grasps/s "
                  f"({seconds:.1f} s), per worker {rate / workers / core:6.1%} of the core (wall), "
                  f"{per_cpu / core_cpu:6.1%} (CPU time), worker peak RSS "
                  f"{', '.join(f'{p:.0f}' for p in peaks)} MiB")
            if overhead is not None:
                print(f"one chunk, back to back     : worker / in-process CPU time "
                      f"{overhead:.3f} (per worker {1 / overhead:.1%} of the core)")
        print(f"2 workers / 1 worker        : {rates[2] / rates[1]:.2f}x (wall)")
        if args.large:
            large = folder / "large.npz"
            start = time.perf_counter()
            write_npz_by_chunks(large, args.large, 3, args.large_chunk, seed=2)
            size_gib = large.stat().st_size / 2**30
            print(f"large input: {args.large:,} three-finger grasps, {size_gib:.2f} GiB .npz "
                  f"(written in {time.perf_counter() - start:.0f} s), chunks of "
                  f"{args.large_chunk:,}, 2 workers")
            rate, seconds, _, peaks, _ = on_cluster(large, args.large_chunk, 2, folder / "out")
            print(f"large run                   : {rate:10,.0f} grasps/s ({seconds:.1f} s), "
                  f"worker peak RSS {', '.join(f'{p:.0f}' for p in peaks)} MiB, client peak "
                  f"RSS {_peak_rss_mib():.0f} MiB")
    finally:
        shutil.rmtree(folder)


if __name__ == "__main__":
    main()
