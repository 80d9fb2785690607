"""What the benchmark scripts share: the paper's friction, a median timer and a ratio
of measured quantities.

Imported by the scripts beside it (their folder is first on sys.path when they run).
"""

import statistics
import time
from collections.abc import Callable

import numpy as np

#: The paper's friction coefficient, mu = tan(10 deg).
MU_PAPER = float(np.tan(np.radians(10.0)))


def median_seconds(function: Callable[[], object], repeats: int,
                   clock: Callable[[], float] = time.perf_counter) -> float:
    """Median time of ``repeats`` calls on ``clock`` (default: wall time), after one
    untimed warm-up call."""
    function()
    times = []
    for _ in range(repeats):
        start = clock()
        function()
        times.append(clock() - start)
    return statistics.median(times)


def median_cpu_seconds(function: Callable[[], object], repeats: int) -> float:
    """Median CPU time of this process over ``repeats`` calls, after one untimed warm-up
    call (other processes on a shared machine do not inflate it)."""
    return median_seconds(function, repeats, time.process_time)


def ratio_or_nan(numerator: float, denominator: float) -> float:
    """``numerator / denominator``, or NaN (printed "nan") when the denominator is not
    positive.

    CPU times come from the kernel in ticks (~10 ms), so a short run can measure 0 s: a
    benchmark run with tiny sizes then prints "nan" instead of failing on a division.
    """
    return numerator / denominator if denominator > 0 else float("nan")
