"""Measurements of the experiment: Tables I and II, the peer, and the sweeps.

Every number here is measured on this machine in this run; nothing is
extrapolated. Times are wall-clock seconds from time.perf_counter around the
public calls, so they include input validation and batching overheads.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from grasp_fc_ros.core import Status, check_force_closure
from grasp_fc_ros.objects import ContactSurface, sample_grasps

from .linearized_peer import linearized_force_closure

# Grasps run once, untimed, before the first timed call (imports, solver set-up).
WARMUP_GRASPS = 20


@dataclass(frozen=True)
class PipelineRun:
    """One timed call of check_force_closure on a batch."""

    wall_s: float
    filter_s: float
    exact_s: float
    force_closure: np.ndarray  # (N,) bool
    filtered_out: np.ndarray  # (N,) bool
    solver_failures: int


def run_pipeline(positions: np.ndarray, normals: np.ndarray, mu: float, use_filter: bool,
                 origins: str = "seed") -> PipelineRun:
    """Time check_force_closure on a batch (N, n, 3)."""
    start = time.perf_counter()
    result = check_force_closure(positions, normals, mu, use_filter=use_filter, origins=origins)
    wall = time.perf_counter() - start
    return PipelineRun(
        wall_s=wall,
        filter_s=float(result.timing.get("filter_s", 0.0)),
        exact_s=float(result.timing.get("exact_s", 0.0)),
        force_closure=np.asarray(result.force_closure, dtype=bool),
        filtered_out=np.asarray(result.filtered_out, dtype=bool),
        solver_failures=int(np.count_nonzero(result.status == Status.SOLVER_FAILURE)),
    )


def warm_up(surface: ContactSurface, n_fingers: int, mu: float) -> None:
    """Run both pipelines once on a few grasps so one-off costs stay out of the timings."""
    positions, normals = sample_grasps(surface, WARMUP_GRASPS, n_fingers,
                                       np.random.default_rng(0))
    for origins in ("seed", "all"):
        check_force_closure(positions, normals, mu, use_filter=True, origins=origins)
    check_force_closure(positions, normals, mu, use_filter=False)


@dataclass(frozen=True)
class FilterStats:
    """Table II columns for one choice of filter origins, against the exact verdicts."""

    origins: str
    wall_s: float
    filter_s: float
    exact_s: float
    force_closure: int  # force-closure verdicts of the filtered pipeline
    passed: int  # grasps the filter let through
    false_positives: int  # passed the filter, not force closure
    specificity: float  # non-FC grasps rejected by the filter / all non-FC grasps
    unsound: int  # force-closure grasps the filter rejected (must be 0)
    verdict_mismatches: int  # filtered verdict differs from the unfiltered one (must be 0)
    solver_failures: int


def filter_stats(run: PipelineRun, exact_fc: np.ndarray, origins: str) -> FilterStats:
    passed = ~run.filtered_out
    not_fc = ~exact_fc
    n_not_fc = int(np.count_nonzero(not_fc))
    rejected_not_fc = int(np.count_nonzero(run.filtered_out & not_fc))
    return FilterStats(
        origins=origins,
        wall_s=run.wall_s,
        filter_s=run.filter_s,
        exact_s=run.exact_s,
        force_closure=int(np.count_nonzero(run.force_closure)),
        passed=int(np.count_nonzero(passed)),
        false_positives=int(np.count_nonzero(passed & not_fc)),
        specificity=rejected_not_fc / n_not_fc if n_not_fc else float("nan"),
        unsound=int(np.count_nonzero(run.filtered_out & exact_fc)),
        verdict_mismatches=int(np.count_nonzero(run.force_closure != exact_fc)),
        solver_failures=run.solver_failures,
    )


@dataclass(frozen=True)
class PeerStats:
    """The linearized peer on a subsample of an object's grasps."""

    sides: int
    grasps: int
    seconds: float
    missed_fc: int  # exact says force closure, peer says not
    false_fc: int  # exact says not force closure, peer says it is

    @property
    def ms_per_grasp(self) -> float:
        return 1e3 * self.seconds / self.grasps if self.grasps else float("nan")


def run_peer(positions: np.ndarray, normals: np.ndarray, mu: float, sides: int,
             exact_fc: np.ndarray) -> PeerStats:
    """Time the linearized test on the given grasps and compare with exact verdicts."""
    start = time.perf_counter()
    verdict = linearized_force_closure(positions, normals, mu, sides)
    seconds = time.perf_counter() - start
    return PeerStats(
        sides=sides,
        grasps=len(positions),
        seconds=seconds,
        missed_fc=int(np.count_nonzero(exact_fc & ~verdict)),
        false_fc=int(np.count_nonzero(~exact_fc & verdict)),
    )


@dataclass(frozen=True)
class ObjectResult:
    """Everything measured on one object (one row of the main CSV)."""

    name: str
    n_points: int
    n_fingers: int
    mu: float
    grasps: int
    unfiltered: PipelineRun
    seed: FilterStats
    all_origins: FilterStats
    peer: PeerStats

    @property
    def force_closure(self) -> int:
        return int(np.count_nonzero(self.unfiltered.force_closure))

    @property
    def speedup(self) -> float:
        return self.unfiltered.wall_s / self.seed.wall_s

    @property
    def speedup_all(self) -> float:
        return self.unfiltered.wall_s / self.all_origins.wall_s


def measure_object(surface: ContactSurface, n_fingers: int, mu: float, n_grasps: int,
                   rng: np.random.Generator, peer_grasps: int,
                   peer_sides: int) -> ObjectResult:
    """Tables I and II, and the peer, for one object.

    The same N grasps go through the exact test alone (unfiltered), the filter
    with origins="seed" then the exact test, and the filter with origins="all"
    then the exact test. The peer runs on the first ``peer_grasps`` of them.
    """
    positions, normals = sample_grasps(surface, n_grasps, n_fingers, rng)
    warm_up(surface, n_fingers, mu)
    unfiltered = run_pipeline(positions, normals, mu, use_filter=False)
    exact_fc = unfiltered.force_closure
    seed = filter_stats(run_pipeline(positions, normals, mu, True, "seed"), exact_fc, "seed")
    all_origins = filter_stats(run_pipeline(positions, normals, mu, True, "all"), exact_fc,
                               "all")
    k = min(peer_grasps, n_grasps)
    peer = run_peer(positions[:k], normals[:k], mu, peer_sides, exact_fc[:k])
    return ObjectResult(surface.name, len(surface), n_fingers, mu, n_grasps, unfiltered, seed,
                        all_origins, peer)


@dataclass(frozen=True)
class FingerSweepRow:
    """Throughput of both pipelines for one finger count, summed over objects."""

    n_fingers: int
    grasps: int
    unfiltered_s: float
    filtered_s: float
    force_closure: int
    specificity: float

    @property
    def unfiltered_per_s(self) -> float:
        return self.grasps / self.unfiltered_s

    @property
    def filtered_per_s(self) -> float:
        return self.grasps / self.filtered_s


def finger_sweep(surfaces: Sequence[ContactSurface], finger_counts: Iterable[int], mu: float,
                 grasps_per_object: int, rng: np.random.Generator) -> list[FingerSweepRow]:
    """Throughput (grasps/s) of the unfiltered and filtered pipelines against n."""
    rows = []
    for n_fingers in finger_counts:
        totals = np.zeros(2)
        fc = not_fc = rejected_not_fc = 0
        for surface in surfaces:
            positions, normals = sample_grasps(surface, grasps_per_object, n_fingers, rng)
            unfiltered = run_pipeline(positions, normals, mu, use_filter=False)
            filtered = run_pipeline(positions, normals, mu, use_filter=True)
            totals += (unfiltered.wall_s, filtered.wall_s)
            fc += int(np.count_nonzero(unfiltered.force_closure))
            not_fc += int(np.count_nonzero(~unfiltered.force_closure))
            rejected_not_fc += int(np.count_nonzero(filtered.filtered_out
                                                    & ~unfiltered.force_closure))
        rows.append(FingerSweepRow(
            n_fingers=n_fingers,
            grasps=grasps_per_object * len(surfaces),
            unfiltered_s=float(totals[0]),
            filtered_s=float(totals[1]),
            force_closure=fc,
            specificity=rejected_not_fc / not_fc if not_fc else float("nan"),
        ))
    return rows


@dataclass(frozen=True)
class SidesSweepRow:
    """The peer with one number of pyramid sides, on force-closure and other grasps."""

    sides: int
    fc_grasps: int  # exact force-closure grasps tested
    other_grasps: int  # exact non-force-closure grasps tested
    seconds: float
    missed_fc: int
    false_fc: int

    @property
    def grasps(self) -> int:
        return self.fc_grasps + self.other_grasps

    @property
    def ms_per_grasp(self) -> float:
        return 1e3 * self.seconds / self.grasps

    @property
    def missed_share(self) -> float:
        return self.missed_fc / self.fc_grasps if self.fc_grasps else float("nan")


def sides_sweep(surfaces: Iterable[ContactSurface], n_fingers: int, mu: float,
                sides_list: Iterable[int], fc_per_object: int, pool_per_object: int,
                rng: np.random.Generator) -> list[SidesSweepRow]:
    """Peer time and disagreement with the exact test against the pyramid's sides.

    An inscribed pyramid can only lose force closure, so the interesting
    grasps are the force-closure ones: from a pool of random grasps per object
    the exact test classifies, up to ``fc_per_object`` force-closure grasps and
    a fifth as many non-force-closure ones (to confirm the peer accepts none)
    are run through the peer for each number of sides.
    """
    batches = []
    for surface in surfaces:
        positions, normals = sample_grasps(surface, pool_per_object, n_fingers, rng)
        exact_fc = run_pipeline(positions, normals, mu, use_filter=False).force_closure
        fc = np.flatnonzero(exact_fc)[:fc_per_object]
        other = np.flatnonzero(~exact_fc)[:max(1, fc_per_object // 5)]
        chosen = np.concatenate([fc, other])
        batches.append((positions[chosen], normals[chosen], exact_fc[chosen]))
    rows = []
    for sides in sides_list:
        per_object = [run_peer(p, n, mu, sides, fc) for p, n, fc in batches]
        rows.append(SidesSweepRow(
            sides=sides,
            fc_grasps=int(sum(np.count_nonzero(fc) for _, _, fc in batches)),
            other_grasps=int(sum(np.count_nonzero(~fc) for _, _, fc in batches)),
            seconds=sum(s.seconds for s in per_object),
            missed_fc=sum(s.missed_fc for s in per_object),
            false_fc=sum(s.false_fc for s in per_object),
        ))
    return rows
