"""Results of ended label_grasps goals, kept for late result requests.

rclpy's action server keeps an ended goal (its request, the whole batch, and its result)
for ``result_timeout``, and lists every kept goal in each status message, which every
action client converts in Python: with 15 minutes, a job of a few hundred goals slowed
down with the list (docs/performance.md#big-label-jobs). The node therefore lets the
server forget an ended goal after a few seconds and keeps only its result response
here, outside the status list, for as long as rclpy would keep it, but bounded by count
and bytes: a client that asks for a result minutes after its goal ended still gets it
(status and verdicts), the oldest results going first when the bounds are reached.
"""

from __future__ import annotations

import time
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

# How long an ended goal's result is kept (s): rclpy's own default result_timeout.
KEEP_S = 900.0
# Results kept at most: a GraspClient job of 100,000 six-finger grasps is ~200 goals.
KEEP_COUNT = 10_000
# Bytes of verdicts kept at most (estimated from their fields, see result_bytes).
KEEP_BYTES = 64 * 1024 * 1024
# Estimated bytes of a Python list's slot, of a bool list's element included.
_SLOT_BYTES = 8


class KeptResults:
    """Result responses by goal id, oldest first, within an age, a count and bytes.

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
        # goal id -> (the result response, its size in bytes, when it was kept)
        self._kept: OrderedDict[bytes, tuple[Any, int, float]] = OrderedDict()
        self.bytes = 0

    def __len__(self) -> int:
        return len(self._kept)

    def keep(self, goal_id: bytes, response: Any, size: int) -> None:
        """Keep ``response`` (of ``size`` bytes) for ``goal_id``; drop the oldest beyond
        the bounds (a result larger than ``max_bytes`` alone is not kept)."""
        self._drop_expired()
        self._kept[goal_id] = (response, size, self._clock())
        self.bytes += size
        while self._kept and (len(self._kept) > self._max_count
                              or self.bytes > self._max_bytes):
            self._drop_oldest()

    def get(self, goal_id: bytes) -> Any | None:
        """The kept response of ``goal_id``, or None (never kept, or dropped)."""
        self._drop_expired()
        entry = self._kept.get(goal_id)
        return None if entry is None else entry[0]

    def _drop_expired(self) -> None:
        oldest = self._clock() - self._keep_s
        while self._kept and next(iter(self._kept.values()))[2] < oldest:
            self._drop_oldest()

    def _drop_oldest(self) -> None:
        _, (_, size, _) = self._kept.popitem(last=False)
        self.bytes -= size


def result_bytes(result: Any) -> int:
    """About the memory a LabelGrasps result holds: its verdict arrays' bytes, a slot
    per list element, and each distinct message text once (a refusal repeats one text
    object for every grasp)."""
    verdicts = result.verdicts
    size = 0
    for name in ("ids", "status", "margin", "contact_forces", "contact_torques",
                 "separating_wrenches", "min_friction", "epsilon_lower", "epsilon_upper"):
        values = getattr(verdicts, name)
        size += len(values) * getattr(values, "itemsize", _SLOT_BYTES)
    messages = verdicts.messages
    distinct = {id(text): text for text in messages}
    size += _SLOT_BYTES * (len(verdicts.force_closure) + len(messages))
    return size + sum(len(text) for text in distinct.values())
