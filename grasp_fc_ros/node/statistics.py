"""What the node counts for /diagnostics, and throttled logging (thread-safe)."""

from __future__ import annotations

import math
import threading
import time
from collections import deque

import numpy as np
from diagnostic_msgs.msg import KeyValue

from grasp_fc_ros.core import Status

WARN_THROTTLE_S = 2.0
# Processing times kept for the diagnostics' mean and p99.
TIMING_WINDOW = 2000


class Statistics:
    """Counters and processing times reported on /diagnostics (thread-safe)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.counts = {s: 0 for s in Status}
        self.received = 0
        self.answered = 0
        self.callback_errors = 0
        self.overloaded = 0
        # Messages the middleware reports lost before the node's subscriptions took them
        # (rclpy's message_lost QoS event; a publisher's KEEP_LAST history overwrote them).
        self.messages_lost = 0
        self.seconds = {"conversion_s": 0.0, "validation_s": 0.0, "filter_s": 0.0,
                        "exact_s": 0.0}
        self.processing_s: deque[float] = deque(maxlen=TIMING_WINDOW)
        # label_grasps goals: received, and how they ended; grasps of canceled or
        # aborted goals that were never decided.
        self.goals = {"received": 0, "succeeded": 0, "canceled": 0, "aborted": 0}
        self.goal_grasps_undecided = 0

    def count_goal(self, event: str) -> None:
        """Count a label_grasps goal ``event``: a key of :attr:`goals`."""
        with self._lock:
            self.goals[event] += 1

    def count_undecided(self, n_grasps: int) -> None:
        with self._lock:
            self.goal_grasps_undecided += n_grasps

    def count_received(self, n_queries: int) -> None:
        with self._lock:
            self.received += n_queries

    def record(self, status: np.ndarray, seconds: dict[str, float],
               processing_s: float | None) -> None:
        """Count answered queries: their verdict codes and where their time went.

        ``processing_s`` is None for answers that did no real work (failures), which
        must not pull the mean and p99 processing time down.
        """
        # bincount over the few codes: a fraction of np.unique's cost on a 1-query answer.
        per_code = np.bincount(status, minlength=len(Status)).tolist()
        with self._lock:
            self.answered += len(status)
            # One count per code (bincount's minlength); never fewer.
            for status_code, count in zip(Status, per_code, strict=False):
                self.counts[status_code] += count
            for key in self.seconds:
                self.seconds[key] += seconds.get(key, 0.0)
            if processing_s is not None:
                self.processing_s.append(processing_s)

    def record_failures(self, n_queries: int) -> None:
        """Count ``n_queries`` answered with SOLVER_FAILURE without being decided."""
        self.record_refused(Status.SOLVER_FAILURE, n_queries)

    def record_refused(self, status: Status, n_queries: int) -> None:
        """Count ``n_queries`` answered with ``status`` without being decided (no
        processing time, no array of their statuses)."""
        with self._lock:
            self.answered += n_queries
            self.counts[status] += n_queries

    def count_error(self) -> None:
        with self._lock:
            self.callback_errors += 1

    def count_lost(self, n_messages: int) -> None:
        with self._lock:
            self.messages_lost += n_messages

    def count_overloaded(self, n_queries: int) -> None:
        with self._lock:
            self.overloaded += n_queries

    def failures(self) -> int:
        with self._lock:
            return self.counts[Status.SOLVER_FAILURE] + self.callback_errors

    def key_values(self, pending: dict[str, int]) -> list[KeyValue]:
        with self._lock:
            times_ms = np.array(self.processing_s) * 1e3
            counts = dict(self.counts)
            values = {
                "received": self.received,
                "answered": self.answered,
                "queries": self.answered,
                "force_closure": counts[Status.FORCE_CLOSURE],
                "rejected_by_filter": counts[Status.FILTERED_OUT],
                "decided_by_exact_test": (counts[Status.FORCE_CLOSURE]
                                          + counts[Status.NOT_FORCE_CLOSURE]),
                "invalid_input": counts[Status.INVALID_INPUT],
                "solver_failures": counts[Status.SOLVER_FAILURE],
                "callback_errors": self.callback_errors,
                "overloaded": self.overloaded,
                "messages_lost": self.messages_lost,
                **pending,
                **{f"action_goals_{key}": value for key, value in self.goals.items()},
                "action_grasps_undecided": self.goal_grasps_undecided,
                # Microseconds: a one-grasp exact test takes a fraction of a ms, so a few
                # queries' worth would not show in milliseconds.
                **{f"{key[:-2]}_time_total_s": f"{value:.6f}"
                   for key, value in self.seconds.items()},
            }
        mean_ms = float(times_ms.mean()) if len(times_ms) else 0.0
        p99_ms = float(np.percentile(times_ms, 99)) if len(times_ms) else 0.0
        values["processing_time_mean_ms"] = f"{mean_ms:.3f}"
        values["processing_time_p99_ms"] = f"{p99_ms:.3f}"
        return [KeyValue(key=k, value=str(v)) for k, v in values.items()]


class Throttle:
    """At most one log line per ``period_s`` and key, decided before calling the logger.

    rclpy's own ``throttle_duration_sec`` inspects the caller's stack on every call,
    even a suppressed one, which costs more than a whole verdict on the hot path.
    """

    def __init__(self, period_s: float) -> None:
        self._period_s = period_s
        self._last: dict[str, float] = {}
        self._lock = threading.Lock()

    def __call__(self, key: str) -> bool:
        now = time.monotonic()
        with self._lock:
            if now - self._last.get(key, -math.inf) < self._period_s:
                return False
            self._last[key] = now
            return True
