"""First calls after install: what numba's compile costs, and what is left of it for a
user's first call once ``make setup`` has run the core's ``warm_up``.

Every measurement is a fresh process (wall seconds; numba compiles on one core). The
full form gives each scenario an empty numba cache of its own (``NUMBA_CACHE_DIR``, a
temporary folder), so nothing was compiled before it and the installed cache is left
alone:

* install: ``grasp_fc_ros.core.warm_up()``, what ``make setup`` runs;
* after it, each in a fresh process: the first ``epsilon_quality``,
  ``minimum_friction``, ``optimal_contact_forces`` and ``check_force_closure`` call on
  the README's square grasp;
* without any warm-up: the first ``epsilon_quality`` call (it compiles the exact stage
  it starts with too).

``--quick`` measures only the first calls, from the installed cache as ``make setup``
left it (seconds).

    python benchmarks/bench_first_call.py            # ~2-3 min on 2 cores
    python benchmarks/bench_first_call.py --quick
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from collections.abc import Sequence

# What each child times, after its imports: one first call.
CALLS = {
    "warm_up": "core.warm_up()",
    "epsilon_quality": "core.epsilon_quality(P, -P, mu=0.5)",
    "minimum_friction": "core.minimum_friction(P, -P)",
    "optimal_contact_forces": "core.optimal_contact_forces(P, -P, 0.5, [0, 0, -9.81, 0, 0, 0])",
    "check_force_closure": "core.check_force_closure(P, -P, 0.5)",
}
FIRST_CALLS = ("epsilon_quality", "minimum_friction", "optimal_contact_forces",
               "check_force_closure")
CHILD = """
import time
import numpy as np
import grasp_fc_ros.core as core
P = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]])
start = time.perf_counter()
{call}
print(time.perf_counter() - start)
"""
CHILD_TIMEOUT_S = 900


def first_call(name: str, cache_dir: str | None) -> float:
    """Seconds of ``name``'s first call in a fresh process (numba's cache in
    ``cache_dir``, or the installed one)."""
    env = dict(os.environ)
    if cache_dir is not None:
        env["NUMBA_CACHE_DIR"] = cache_dir
    done = subprocess.run([sys.executable, "-c", CHILD.format(call=CALLS[name])], env=env,
                          capture_output=True, text=True, timeout=CHILD_TIMEOUT_S, check=True)
    return float(done.stdout.split()[-1])


def first_calls(cache_dir: str | None) -> str:
    return ", ".join(f"{name} {first_call(name, cache_dir):.2f} s" for name in FIRST_CALLS)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true",
                        help="first calls from the installed cache only")
    args = parser.parse_args(argv)
    if args.quick:
        print(f"first calls, fresh processes, installed cache: {first_calls(None)}")
        return 0
    with tempfile.TemporaryDirectory() as installed, tempfile.TemporaryDirectory() as empty:
        print(f"install: warm_up into an empty cache {first_call('warm_up', installed):.1f} s",
              flush=True)
        print(f"first calls, fresh processes, after it: {first_calls(installed)}", flush=True)
        print("first epsilon_quality call without a warm-up (empty cache): "
              f"{first_call('epsilon_quality', empty):.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
