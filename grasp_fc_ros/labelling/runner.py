"""Chunks on Dask: check every chunk, then label them and stream the parts to disk.

The client plans fixed chunks (``chunk_size`` rows of one source each), so the output does
not depend on the number of workers. Workers read and label; the client receives each
chunk's small table (about 20 bytes per grasp without the grasp columns) and writes it as
one part, atomically, as soon as it arrives. A worker that dies mid-chunk has no part
written for it; the scheduler runs the chunk again elsewhere and the client still writes
it once, so no row is lost or duplicated.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import sys
import time
import uuid
from collections.abc import Callable, Hashable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import IO, TYPE_CHECKING, Any, TypeVar

import numpy as np

from .output import Output
from .robustness import Robustness
from .schema import STATUS_NAMES, output_schema
from .sources import InputError, Source, SurfaceSource, open_input
from .tasks import label_chunk, validate_chunk

if TYPE_CHECKING:
    import pyarrow as pa
    from distributed import Client, Future

Result = TypeVar("Result")

# Grasps per chunk of verdicts alone: large enough that the core's vectorised filter and
# batched exact test run at full speed and the per-task overhead of Dask (~1 ms) is
# negligible, small enough that a chunk's arrays stay far below a worker's memory (50,000
# six-finger grasps are 15 MB of input) and a retried chunk loses little work (a few
# seconds). Also the default block of grasps drawn on objects from one random stream.
DEFAULT_CHUNK_SIZE = 50_000

# Costlier columns get smaller chunks, sized by cost. The unit of cost is one exact-test
# verdict of one grasp (~5 us of a core here, six fingers). A chunk of the costlier columns
# is CHUNK_WORK verdicts' worth (measured 6-11 s of a core): the labeller's own cost per
# chunk (task, transfer, part: milliseconds) is within 5 % of it, a chunk lost with its
# worker costs seconds, and 10^8 grasps at a 1,000-sample probability make 55,067 tasks,
# about 150 a second on a thousand cores (docs/labelling.md, "Planning 10^8 grasps").
CHUNK_WORK = 2_000_000
# Verdicts' worth of one grasp's columns, measured on six-finger box grasps, mu 0.5, by CPU
# time (bench_label_cluster.py, compute per chunk against the verdicts'; docs/
# performance.md#labelling), rounded: epsilon_quality at the default rtol 85-134 (fewer
# with fewer fingers); robustness()'s three radii 117 (35 at four fingers); holds_under at
# errors of every kind (2 mm, 3 degrees, friction 0.1: the position error's search
# dominates) 990, about 2 with a normal error alone (the worst case is taken: a smaller
# chunk costs little, a larger one may last minutes).
EPSILON_COST = 100
RADII_COST = 100
HOLDS_COST = 1000
# One Monte-Carlo sample of the probability is one batched exact test (a verdict).
PROBABILITY_SAMPLE_COST = 1
MANIFEST_FORMAT = 1


#: Dask settings of the local cluster's workers (docs/labelling.md says how to set them on
#: a cluster's): Dask's nanny starts workers with MALLOC_TRIM_THRESHOLD_=65536, which also
#: stops glibc from raising its mmap threshold, so every large temporary array of the core
#: is a fresh mmap with its page faults: the probability's chunks took 8-17 % more CPU on
#: a worker than in-process with it and 0-2 % without (docs/performance.md#labelling). A
#: chunk's memory is bounded, so trimming gains little here.
WORKER_CONFIG = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}

def cost_per_grasp(quality_rtol: float | None = None,
                   robustness: Robustness | None = None) -> int:
    """What labelling one grasp costs, in exact-test verdicts."""
    cost = 1 + (EPSILON_COST if quality_rtol is not None else 0)
    if robustness is not None:
        cost += RADII_COST + (HOLDS_COST if robustness.holds else 0)
        if robustness.probability:
            cost += PROBABILITY_SAMPLE_COST * robustness.samples
    return cost


def default_chunk_size(quality_rtol: float | None = None,
                       robustness: Robustness | None = None) -> int:
    """Grasps per chunk for the columns asked for: :data:`DEFAULT_CHUNK_SIZE` for the
    verdicts, :data:`CHUNK_WORK` verdicts' worth for costlier columns."""
    cost = cost_per_grasp(quality_rtol, robustness)
    return DEFAULT_CHUNK_SIZE if cost == 1 else max(1, min(DEFAULT_CHUNK_SIZE,
                                                           CHUNK_WORK // cost))


@dataclass(frozen=True)
class Chunk:
    """Rows ``start:stop`` of source number ``source``; its output part is :attr:`part`."""

    source: int
    index: int
    start: int
    stop: int

    @property
    def part(self) -> str:
        return f"part-{self.source:05d}-{self.index:06d}.parquet"

    @property
    def size(self) -> int:
        return self.stop - self.start


@dataclass(frozen=True)
class Plan:
    """What to label and how.

    Attributes
    ----------
    sources : sequence of Source
        :mod:`~grasp_fc_ros.labelling.sources` objects, in output order.
    chunk_size : int or None
        Grasps per chunk and output part (the last chunk of a source may be smaller);
        None: :func:`default_chunk_size` of the columns asked for.
    use_filter : bool or "auto"
        Run the torque filter before the exact test: as ``check_force_closure`` takes it
        (same verdicts either way; "auto" runs it where it pays).
    origins : {"seed", "all"}
        The filter's torque origins.
    quality_rtol : float or None
        Also label the certified Ferrari-Canny epsilon, to this relative accuracy
        (``--quality``); None: not.
    robustness : Robustness or None
        Also label the robustness columns (``--robustness``); None: not.
    """

    sources: Sequence[Source]
    chunk_size: int | None = None
    use_filter: bool | str = "auto"
    origins: str = "seed"
    quality_rtol: float | None = None
    robustness: Robustness | None = None

    def __post_init__(self) -> None:
        if self.chunk_size is None:
            object.__setattr__(self, "chunk_size",
                               default_chunk_size(self.quality_rtol, self.robustness))

    @property
    def rows_per_chunk(self) -> int:
        assert self.chunk_size is not None  # set by __post_init__
        return self.chunk_size

    @classmethod
    def from_files(cls, paths: Iterable[str | os.PathLike[str]], **settings: Any) -> Plan:
        """The plan of input files, ids defaulting to the running index across them all.

        Raises
        ------
        InputError
            A file with missing keys or wrong shapes (see :func:`open_input`).
        """
        sources: list[Source] = []
        offset = 0
        for path in paths:
            sources.append(open_input(path, id_offset=offset))
            offset += sources[-1].n_grasps
        return cls(sources, **settings)

    @property
    def chunks(self) -> list[Chunk]:
        size = self.rows_per_chunk
        return [Chunk(s, index, start, min(start + size, source.n_grasps))
                for s, source in enumerate(self.sources)
                for index, start in enumerate(range(0, source.n_grasps, size))]

    @property
    def n_grasps(self) -> int:
        return sum(source.n_grasps for source in self.sources)

    @property
    def schema(self) -> pa.Schema:
        with_grasps = any(source.object_name is not None for source in self.sources)
        fingers = self.sources[0].n_contacts if self.sources else 0
        return output_schema(with_grasps, fingers, quality=self.quality_rtol is not None,
                             robustness=self.robustness)

    def manifest(self) -> dict[str, Any]:
        # Entries of later options only when set: outputs of runs without them keep
        # their manifest (and resume).
        optional: dict[str, Any] = {}
        if self.quality_rtol is not None:
            optional["quality_rtol"] = self.quality_rtol
        if self.robustness is not None:
            optional["robustness"] = self.robustness.manifest()
        blocks = {source.draw_block for source in self.sources
                  if isinstance(source, SurfaceSource)}
        if blocks - {self.chunk_size}:
            optional["draw_block"] = sorted(blocks)
        return {"format": MANIFEST_FORMAT, "chunk_size": self.chunk_size,
                "use_filter": self.use_filter, "origins": self.origins, **optional,
                "sources": [source.describe() for source in self.sources]}


def check_ranges(chunks: Sequence[Chunk], rows: int = DEFAULT_CHUNK_SIZE) -> list[Chunk]:
    """The row ranges that the checking pass reads: runs of consecutive ``chunks`` of one
    source merged up to ``rows`` rows (or one chunk, if larger), so that small chunks of
    costly columns do not multiply the checking tasks."""
    ranges: list[Chunk] = []
    for chunk in chunks:
        last = ranges[-1] if ranges else None
        if (last is not None and last.source == chunk.source and last.stop == chunk.start
                and chunk.stop - last.start <= rows):
            ranges[-1] = Chunk(last.source, last.index, last.start, chunk.stop)
        else:
            ranges.append(chunk)
    return ranges


@dataclass
class Summary:
    """What a run did. ``status_counts`` covers the chunks labelled by this run only."""

    out: str
    n_grasps: int
    chunks_written: int = 0
    chunks_skipped: int = 0
    grasps_written: int = 0
    seconds: float = 0.0
    status_counts: dict[str, int] = field(default_factory=dict)


class TaskFailed(RuntimeError):
    """A chunk failed on a worker for a reason other than bad input."""


@contextlib.contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None,
                scheduler_file: str | None = None) -> Iterator[Client]:
    """A Dask client: on ``scheduler`` (``tcp://HOST:PORT``), on the scheduler that
    ``scheduler_file`` names (``dask scheduler --scheduler-file``), or on a new local cluster.

    The local cluster has ``workers`` processes (default: this machine's cores), one
    thread each (the core is single-threaded numpy and Clarabel), on 127.0.0.1 only.
    """
    import dask
    from distributed import Client, LocalCluster

    if scheduler or scheduler_file:
        with Client(scheduler, scheduler_file=scheduler_file, timeout="30s") as client:
            yield client
        return
    with dask.config.set(WORKER_CONFIG), LocalCluster(
            n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
            host="127.0.0.1", dashboard_address=None,
            silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        yield client


class Progress:
    """A progress line on stderr: chunks and grasps done, rate, time left."""

    def __init__(self, total_grasps: int, total_chunks: int, stream: IO[str] | None = None,
                 enabled: bool = True) -> None:
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.total_grasps, self.total_chunks = total_grasps, total_chunks
        self.grasps = self.chunks = 0
        self.start = self.last_line = time.perf_counter()
        self.tty = self.stream.isatty()

    def update(self, grasps: int) -> None:
        self.grasps += grasps
        self.chunks += 1
        now = time.perf_counter()
        if not self.enabled or (not self.tty and now - self.last_line < 10.0
                                and self.chunks < self.total_chunks):
            return
        self.last_line = now
        rate = self.grasps / max(now - self.start, 1e-9)
        left = (self.total_grasps - self.grasps) / rate if rate else float("inf")
        width = 30
        filled = int(width * self.grasps / max(self.total_grasps, 1))
        digits = 0 if rate >= 10 else 2  # costly columns run at a few grasps/s a worker
        line = (f"[{'#' * filled}{'.' * (width - filled)}] {self.chunks}/{self.total_chunks} "
                f"chunks, {self.grasps:,}/{self.total_grasps:,} grasps, "
                f"{rate:,.{digits}f} grasps/s, {duration(left)} left")
        self.stream.write(("\r" + line) if self.tty else line + "\n")
        if self.tty and self.chunks == self.total_chunks:
            self.stream.write("\n")
        self.stream.flush()


def duration(seconds: float) -> str:
    """``seconds`` as ``H:MM:SS`` (``M:SS`` under an hour)."""
    if not math.isfinite(seconds):
        return "?"
    minutes, secs = divmod(round(seconds), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


def run(plan: Plan, out: str | os.PathLike[str], client: Client,
        progress: bool = True) -> Summary:
    """Label every chunk of ``plan`` not yet in ``out``, on the Dask ``client``.

    Raises
    ------
    InputError
        A chunk holds bad input (checked for every chunk before anything is written).
    grasp_fc_ros.labelling.output.OutputConflict
        ``out`` belongs to another run.
    TaskFailed
        A chunk failed on a worker for another reason (parts written so far stay valid).
    """
    start = time.perf_counter()
    output = Output(out, plan.manifest())
    done = output.existing_parts()
    summary = Summary(str(output.out), plan.n_grasps)
    chunks = plan.chunks
    if done is None:  # the single output file is complete
        output.discard_parts()
        summary.chunks_skipped = len(chunks)
        return summary
    todo = [chunk for chunk in chunks if chunk.part not in done]
    summary.chunks_skipped = len(chunks) - len(todo)
    run_id = uuid.uuid4().hex[:12]
    # Each source enters the task graph once, as a task of its own, and the chunks refer
    # to it: a source holding an object's surface is not copied into every chunk's task,
    # and unlike scattered data it is recomputed if the worker holding it dies.
    sources = [client.submit(_identity, source, key=f"grasp-fc-source-{run_id}-{s}")
               for s, source in enumerate(plan.sources)]

    problems = _map_chunks(client, validate_chunk, sources, check_ranges(todo),
                           (plan.robustness is not None,), f"check-{run_id}",
                           stop_on=lambda problem: problem is not None)
    if problems:
        raise InputError(problems[0][1])

    output.create()
    bar = Progress(sum(chunk.size for chunk in todo), len(todo), enabled=progress)
    counts = np.zeros(len(STATUS_NAMES), dtype=np.int64)

    def write(chunk: Chunk, table: pa.Table) -> None:
        output.write_part(chunk.part, table)
        counts[:] += np.bincount(table.column("status").to_numpy(), minlength=len(counts))
        summary.chunks_written += 1
        summary.grasps_written += table.num_rows
        bar.update(table.num_rows)

    _map_chunks(client, label_chunk, sources, todo,
                (plan.use_filter, plan.origins, plan.quality_rtol, plan.robustness),
                f"label-{run_id}",
                on_result=write)
    del sources
    output.finish([chunk.part for chunk in chunks], plan.schema)
    summary.status_counts = {name: int(n) for name, n in zip(STATUS_NAMES, counts, strict=True)}
    summary.seconds = time.perf_counter() - start
    return summary


def _identity(value: Source) -> Source:
    return value


def _map_chunks(client: Client, function: Callable[..., Result], sources: Sequence[Future],
                chunks: Iterable[Chunk], extra_args: tuple[object, ...], key_prefix: str,
                on_result: Callable[[Chunk, Result], None] | None = None,
                stop_on: Callable[[Result], bool] | None = None) -> list[tuple[Chunk, Result]]:
    """Run ``function(source, start, stop, *extra_args)`` per chunk on the cluster.

    ``sources`` are futures of the plan's sources.

    Results are handed to ``on_result(chunk, result)`` as they arrive and released at
    once (the client holds at most the results not yet handled). Returns the
    ``(chunk, result)`` pairs for which ``stop_on(result)`` is true; the first one
    cancels the chunks still pending.
    """
    from distributed import as_completed

    pending: dict[Hashable, tuple[Chunk, Future]] = {}
    for chunk in chunks:
        future = client.submit(function, sources[chunk.source], chunk.start, chunk.stop,
                               *extra_args, key=f"grasp-fc-{key_prefix}-{chunk.part}")
        pending[future.key] = (chunk, future)
    stopped = []
    completed = as_completed([future for _, future in pending.values()])
    try:
        for future in completed:
            chunk, _ = pending.pop(future.key)
            try:
                result = future.result()
            except InputError:
                raise
            except Exception as error:
                raise TaskFailed(f"chunk {chunk.part} (rows {chunk.start}:{chunk.stop} of "
                                 f"input {chunk.source + 1}) failed: "
                                 f"{type(error).__name__}: {error}") from error
            del future
            if on_result is not None:
                on_result(chunk, result)
            if stop_on is not None and stop_on(result):
                stopped.append((chunk, result))
                break
    finally:
        if pending:
            client.cancel([future for _, future in pending.values()])
    return stopped
