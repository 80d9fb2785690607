"""How requests are cut into chunks for the worker processes: one policy (no ROS).

:func:`chunk_size` sizes the chunks of a request that :class:`.pool.EvaluationPool`
queues at once; :func:`adapted_chunk_contacts` the chunks that a long job
(:mod:`.long_jobs`) paces itself, from how long its last chunk took.
"""

from __future__ import annotations

import math

import numpy as np

# Contacts per chunk: ~2,700 6-finger grasps, ~20 ms of work on the latest 2-core EPYC
# (~35 ms on the slower one), under the ~50 ms that a request of more than INLINE_GRASPS
# grasps or a shutdown may wait for a chunk in progress. The core's own cost per grasp
# levels off from ~680 grasps a call (0.023 ms per grasp in calls of 42, 0.018 from 680
# on); larger chunks save the node's cost per chunk (feeding a worker, waking threads).
# benchmarks/bench_ros.py, batches of 10,000, alternating runs: 4,096 contacts 1.24x and
# 1.26x the core alone (node process 1.26-1.30 us of CPU per grasp), 8,192 1.30x and
# 1.37x, 16,384 1.38x, 1.41x, 1.38x and 1.40x (0.70-0.94 us), 32,768 1.36x and 1.41x.
CHUNK_CONTACTS = 16384


# Chunks of a batch with soft contacts hold CHUNK_CONTACTS / 64 = 256 contacts: their
# exact test (Clarabel path) measured 0.13-0.65 ms per grasp of 3-6 fingers against the
# fast stage's 0.004-0.04 (benchmarks/bench_soft.py), so a chunk stays near 10-30 ms.
SOFT_CHUNK_DIVISOR = 64


# A request of fewer chunks than workers is split into one chunk per worker, as equal as
# grasps allow, down to chunks of this many contacts (~170 6-finger grasps, where the
# core's cost per grasp is within ~15% of its best, per the figures above): a 1,000-grasp
# batch went as chunks of 682 and 318 grasps, leaving one worker idle a third of the time.
MIN_CHUNK_CONTACTS = 1024


def chunk_size(total_contacts: int, workers: int, chunk_contacts: int = CHUNK_CONTACTS) -> int:
    """Contacts per chunk for a request of ``total_contacts`` on ``workers`` processes.

    At most ``chunk_contacts``; the chunks as equal as possible, and at least one per
    worker while each keeps :data:`MIN_CHUNK_CONTACTS`.
    """
    n_chunks = max(-(-total_contacts // chunk_contacts),
                   min(workers, total_contacts // MIN_CHUNK_CONTACTS), 1)
    return max(1, -(-total_contacts // n_chunks))


# A chunk should take about this long to decide (s): chunks are made smaller when they
# take longer (slow machine, huge grasps), so that a stop without workers (decided in
# the calling thread, between chunks) is seen within about this time, and a stop with
# workers abandons little work. Never larger than the pool's own chunk size
# (:data:`CHUNK_CONTACTS`).
TARGET_CHUNK_S = 0.05


def chunk_end(ends: np.ndarray, first: int, max_contacts: int) -> int:
    """End (exclusive) of the chunk starting at grasp ``first``: at most ``max_contacts``
    contacts, and at least one grasp. ``ends`` is ``np.cumsum(counts)``."""
    base = int(ends[first - 1]) if first else 0
    last = int(np.searchsorted(ends, base + max_contacts, side="right"))
    return max(last, first + 1)


def adapted_chunk_contacts(chunk_contacts: int, compute_s: float, upper: int) -> int:
    """Contacts per chunk so that a chunk takes about :data:`TARGET_CHUNK_S`.

    ``compute_s`` is what the last chunk of ``chunk_contacts`` contacts took; the
    result lies in [:data:`MIN_CHUNK_CONTACTS`, ``upper``].
    """
    if not (compute_s > 0 and math.isfinite(compute_s)):
        return upper
    wanted = int(chunk_contacts * TARGET_CHUNK_S / compute_s)
    return int(np.clip(wanted, min(MIN_CHUNK_CONTACTS, upper), upper))
