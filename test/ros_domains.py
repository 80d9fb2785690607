"""ROS_DOMAIN_IDs that no other test run on this machine uses at the same time.

Test runs (CI, several work trees) may run side by side on one machine; with a shared
domain id their nodes of the same name answer each other's queries and publish into each
other's /diagnostics. :func:`claim_domain_id` takes an id by locking a file for it in the
temporary directory (``flock``: released when this process ends, even if it is killed),
so concurrent runs never share one.
"""

from __future__ import annotations

import fcntl
import os
import tempfile
from pathlib import Path
from typing import IO

# Domain ids FastDDS maps to valid UDP ports with its default port parameters: 0-232.
# 0 is the default domain of everything else on the machine.
DOMAIN_IDS = range(1, 233)
_held: list[IO[bytes]] = []  # open, locked files: the claims of this process


def claim_domain_id() -> int:
    """A domain id no other process holds, held by this process until it ends.

    Starts at an offset derived from the process id, so that concurrent runs rarely
    contend for the same lock.

    Raises
    ------
    RuntimeError
        If every id of :data:`DOMAIN_IDS` is held.
    """
    folder = Path(tempfile.gettempdir()) / "grasp_fc_ros_domains"
    folder.mkdir(exist_ok=True)
    start = os.getpid() % len(DOMAIN_IDS)
    for k in range(len(DOMAIN_IDS)):
        domain = DOMAIN_IDS[(start + k) % len(DOMAIN_IDS)]
        lock = open(folder / f"{domain}.lock", "wb")  # noqa: SIM115 - held until exit
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            lock.close()
            continue
        _held.append(lock)
        return domain
    raise RuntimeError(f"every ROS domain id in {DOMAIN_IDS} is held by another process")
