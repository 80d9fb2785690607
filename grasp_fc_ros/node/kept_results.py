"""Results of ended label_grasps goals, kept for late result requests.

rclpy's action server keeps an ended goal (its request, the whole batch, and its result)
for ``result_timeout``, and lists every kept goal in each status message, which every
action client converts in Python: with 15 minutes, a job of a few hundred goals slowed
down with the list (docs/performance.md#big-label-jobs). The node therefore lets the
server forget an ended goal after a few seconds and keeps only its result response
here, outside the status list, for as long as rclpy would keep it, but bounded by count
and bytes: a client that asks for a result minutes after its goal ended still gets it
(status and verdicts), the oldest results going first when the bounds are reached.

A result is kept serialized: as messages, the bool and string lists of thousands of
kept results made every full collection of the node's garbage collector walk millions
of references (47 ms for 3,136 results of 512 grasps, against 0.2 ms as bytes), holding
up its service calls; bytes are also their exact size.
"""

from __future__ import annotations

import time
from collections import OrderedDict
from collections.abc import Callable

# How long an ended goal's result is kept (s): rclpy's own default result_timeout.
KEEP_S = 900.0
# Results kept at most: a GraspClient job of 100,000 six-finger grasps is ~200 goals.
KEEP_COUNT = 10_000
# Bytes of serialized results kept at most (a 512-grasp goal's: ~13 kB).
KEEP_BYTES = 64 * 1024 * 1024


class KeptResults:
    """Serialized result responses by goal id, oldest first, within an age, a count and
    bytes.

    Not thread-safe: used from the action server's executor thread only.

    Parameters
    ----------
    keep_s, max_count, max_bytes : float, int, int
        The bounds; beyond any of them the oldest results are dropped.
    clock : callable
        Monotonic seconds (for tests).
    """

    def __init__(self, keep_s: float = KEEP_S, max_count: int = KEEP_COUNT,
                 max_bytes: int = KEEP_BYTES, clock: Callable[[], float] = time.monotonic):
        self._keep_s, self._max_count, self._max_bytes = keep_s, max_count, max_bytes
        self._clock = clock
        # goal id -> the serialized result response; goal id -> when it was kept, oldest
        # first (no tuple per result: nothing for the garbage collector to track)
        self._responses: dict[bytes, bytes] = {}
        self._kept_at: OrderedDict[bytes, float] = OrderedDict()
        self.bytes = 0

    def __len__(self) -> int:
        return len(self._responses)

    def keep(self, goal_id: bytes, response: bytes) -> None:
        """Keep the serialized ``response`` for ``goal_id``; drop the oldest beyond the
        bounds (a result larger than ``max_bytes`` alone is not kept)."""
        self._drop_expired()
        if goal_id in self._responses:  # (goal ids are unique: never, in the node)
            self._drop(goal_id)
        self._responses[goal_id] = response
        self._kept_at[goal_id] = self._clock()
        self.bytes += len(response)
        while self._responses and (len(self._responses) > self._max_count
                                   or self.bytes > self._max_bytes):
            self._drop_oldest()

    def get(self, goal_id: bytes) -> bytes | None:
        """The kept serialized response of ``goal_id``, or None (never kept, or
        dropped)."""
        self._drop_expired()
        return self._responses.get(goal_id)

    def _drop_expired(self) -> None:
        oldest = self._clock() - self._keep_s
        while self._kept_at and next(iter(self._kept_at.values())) < oldest:
            self._drop_oldest()

    def _drop_oldest(self) -> None:
        self._drop(next(iter(self._kept_at)))

    def _drop(self, goal_id: bytes) -> None:
        del self._kept_at[goal_id]
        self.bytes -= len(self._responses.pop(goal_id))

