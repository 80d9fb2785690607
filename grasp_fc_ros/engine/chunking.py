"""How requests are cut into chunks for the worker processes: one policy (no ROS).

:func:`chunk_size` sizes the chunks of a request that :class:`.pool.EvaluationPool`
queues at once; :func:`adapted_chunk_contacts` the chunks that a long job
(:mod:`.long_jobs`) paces itself, from how long its last chunk took.
"""

from __future__ import annotations

import math

import numpy as np

# Contacts per chunk: the batch rate's best, since larger chunks save the node's cost
# per chunk (feeding a worker, waking threads) while the core's own cost per grasp has
# levelled off long before; and a chunk in progress still takes well under the ~50 ms
# that a request of more than INLINE_GRASPS grasps or a shutdown may wait for it
# (tuned: docs/performance.md#worker-chunks).
CHUNK_CONTACTS = 16384


# Chunks of a batch with soft contacts hold CHUNK_CONTACTS / 64 = 256 contacts: their
# exact test takes the Clarabel path, tens of times a hard grasp's cost, so that a soft
# chunk takes about as long as a hard one (tuned: docs/performance.md#worker-chunks).
SOFT_CHUNK_DIVISOR = 64


# An assess_robustness request (settings with a robustness query) is sized in samples:
# each grasp costs its samples (one exact test each) plus RADII_SAMPLES for its radii and
# holds answer, about their cost in exact tests (tuned: docs/performance.md#robustness-service).
# A chunk holds ASSESSMENT_CHUNK_SAMPLES of that, about as long as a batch chunk; a
# request of at most INLINE_ASSESSMENT_SAMPLES (one grasp with 1,000 samples) is decided
# in the calling thread, as small check requests are.
RADII_SAMPLES = 500
ASSESSMENT_CHUNK_SAMPLES = 16_384
INLINE_ASSESSMENT_SAMPLES = 2_048


def assessment_samples(n_grasps: int, samples: int) -> int:
    """What an assess_robustness request of ``n_grasps`` grasps costs, in samples."""
    return n_grasps * (samples + RADII_SAMPLES)


def assessment_chunk_contacts(n_grasps: int, max_contacts: int, samples: int,
                              workers: int) -> int:
    """Contacts per chunk of an assess_robustness request: whole grasps of up to
    ``max_contacts`` contacts, ASSESSMENT_CHUNK_SAMPLES' worth at most, and spread over
    ``workers`` (each grasp costs many exact tests, so even a few are worth sharing)."""
    grasps = max(1, ASSESSMENT_CHUNK_SAMPLES // (samples + RADII_SAMPLES))
    if workers > 1:
        grasps = min(grasps, -(-n_grasps // workers))
    return grasps * max_contacts


# A request of fewer chunks than workers is split into one chunk per worker, as equal as
# grasps allow, so that no worker idles while another decides a large chunk; down to
# chunks of this many contacts, where the core's cost per grasp is still near its best
# (tuned: docs/performance.md#worker-chunks).
MIN_CHUNK_CONTACTS = 1024


def chunk_size(total_contacts: int, workers: int, chunk_contacts: int = CHUNK_CONTACTS) -> int:
    """Contacts per chunk for a request of ``total_contacts`` on ``workers`` processes.

    At most ``chunk_contacts``; the chunks as equal as possible, and at least one per
    worker while each keeps :data:`MIN_CHUNK_CONTACTS` (``workers`` 0 or 1: the bound
    alone).
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


def adapted_chunk_contacts(chunk_contacts: int, compute_s: float, upper: int) -> int:
    """Contacts per chunk so that a chunk takes about :data:`TARGET_CHUNK_S`.

    ``compute_s`` is what the last chunk of ``chunk_contacts`` contacts took; the
    result lies in [:data:`MIN_CHUNK_CONTACTS`, ``upper``].
    """
    if not (compute_s > 0 and math.isfinite(compute_s)):
        return upper
    wanted = int(chunk_contacts * TARGET_CHUNK_S / compute_s)
    return int(np.clip(wanted, min(MIN_CHUNK_CONTACTS, upper), upper))
