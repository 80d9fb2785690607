"""Polling for a condition in tests that drive other processes (Dask schedulers and
workers, hosts in network namespaces)."""

import time
from collections.abc import Callable

# How often a condition is polled: well under the seconds the waits last.
POLL_S = 0.05


def wait_for(condition: Callable[[], object], timeout: float, what: str) -> None:
    """Return once ``condition()`` is true; AssertionError naming ``what`` after
    ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(POLL_S)
