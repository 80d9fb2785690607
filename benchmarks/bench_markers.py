"""Cost of building one answered query's markers next to deciding it with the core.

Random 6-finger grasps on the built-in box; each figure is the median over 7 rounds of
100 calls, the three measurements interleaved so that a change of machine load hits all
of them alike. Prints milliseconds per call and the ratio markers / core.

    .venv/bin/python benchmarks/bench_markers.py
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import numpy as np

from grasp_fc_ros.core import check_force_closure
from grasp_fc_ros.markers import grasp_markers
from grasp_fc_ros.objects import make_object, sample_grasps

CALLS, ROUNDS, FINGERS = 100, 7, 6


def per_call_s(f: Callable[[int], object]) -> float:
    start = time.perf_counter()
    for i in range(CALLS):
        f(i)
    return (time.perf_counter() - start) / CALLS


def main() -> None:
    p, n = sample_grasps(make_object("box"), CALLS, FINGERS, np.random.default_rng(0))
    cases: dict[str, Callable[[int], object]] = {
        "core (check_force_closure)": lambda i: check_force_closure(p[i], n[i], 0.5),
        "markers, 12 segments": lambda i: grasp_markers(
            p[i], n[i], 0.5, 0, query_id=i, frame_id="f", margin=0.01),
        "markers, 8 segments": lambda i: grasp_markers(
            p[i], n[i], 0.5, 0, query_id=i, frame_id="f", margin=0.01, cone_segments=8),
    }
    runs: dict[str, list[float]] = {name: [] for name in cases}
    for _ in range(ROUNDS):
        for name, f in cases.items():
            runs[name].append(per_call_s(f))
    medians = {name: statistics.median(v) for name, v in runs.items()}
    core = medians["core (check_force_closure)"]
    for name, seconds in medians.items():
        print(f"{name:28s} {seconds * 1e3:8.3f} ms   {seconds / core:5.2f} x core")


if __name__ == "__main__":
    main()
