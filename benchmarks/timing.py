"""What the benchmark scripts share: the paper's friction and a median timer.

Imported by the scripts beside it (their folder is first on sys.path when they run).
"""

import statistics
import time

import numpy as np

#: The paper's friction coefficient, mu = tan(10 deg).
MU_PAPER = float(np.tan(np.radians(10.0)))


def median_seconds(function, repeats):
    """Median wall time of ``repeats`` calls, after one untimed warm-up call."""
    function()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return statistics.median(times)
