"""Separate hosts on one machine: Linux network namespaces joined by a bridge.

Used by the multi-host labelling test and by ``benchmarks/bench_label_cluster.py``.
Each host is a network namespace with its own loopback and one veth link to a bridge
that lives in a namespace of its own (the switch), so the hosts reach each other over a
real IP network and nothing else: no route to or from the root namespace, and their
addresses (10.231.0.1, .2, ...) exist only inside this run's namespaces, so concurrent
runs never collide. Processes started on a host see the same filesystem as everyone (a
shared filesystem, as clusters have) but only that host's network.

:meth:`Hosts.cut` pulls a host's cable (its switch port goes down) and then kills every
process on it: the others get no FIN or RST, exactly as when a machine loses power.
:meth:`Hosts.freeze` stops its processes instead, link up: a hung machine, whose kernel
still acknowledges TCP.

Namespaces are named ``gfcnet-<pid>-<token>-...`` and deleted on exit, also when the test
fails; those left by a killed run (whose pid no longer exists) are swept on the next start.

Needs root (CAP_SYS_ADMIN and CAP_NET_ADMIN) and iproute2's ``ip``;
:func:`unavailable` says why not where the machine does not allow it.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import secrets
import shutil
import signal
import subprocess
import time
from collections.abc import Sequence
from pathlib import Path
from typing import IO

PREFIX = "gfcnet-"
# The hosts' network; /24 inside the isolated namespaces (10.231.0.0/16 is the range
# reserved for these tests: 10.231.0.x-10.231.10.x).
SUBNET = "10.231.0"
BRIDGE = "br0"
# How long `ip` may take for one step before the machine is deemed unable to do it.
IP_TIMEOUT_S = 20


def ip(*args: str, check: bool = True) -> subprocess.CompletedProcess[str]:
    """Run iproute2's ``ip`` with ``args`` (output captured; ``check``: raise on failure)."""
    return subprocess.run(["ip", *args], capture_output=True, text=True, check=check,
                          timeout=IP_TIMEOUT_S)


def unavailable() -> str | None:
    """Why network namespaces cannot be made here, or None if they can (probed)."""
    if shutil.which("ip") is None:
        return "no `ip` command (iproute2) on PATH"
    if os.geteuid() != 0:
        return "not root: network namespaces need CAP_SYS_ADMIN and CAP_NET_ADMIN"
    probe = f"{PREFIX}{os.getpid()}-probe-{secrets.token_hex(3)}"
    made = ip("netns", "add", probe, check=False)
    if made.returncode:
        return f"`ip netns add` failed: {made.stderr.strip() or made.returncode}"
    ip("netns", "del", probe, check=False)
    return None


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def sweep_stale() -> list[str]:
    """Delete the namespaces of runs whose process is gone; return their names."""
    listing = ip("netns", "list", check=False).stdout
    names = [line.split()[0] for line in listing.splitlines() if line.startswith(PREFIX)]
    swept = []
    for name in names:
        match = re.match(rf"{PREFIX}(\d+)-", name)
        if match and not _alive(int(match.group(1))):
            _kill_namespace_processes(name)
            ip("netns", "del", name, check=False)
            swept.append(name)
    return swept


def _kill_namespace_processes(namespace: str) -> None:
    """SIGKILL every process inside ``namespace`` (all of them this run's)."""
    pids = ip("netns", "pids", namespace, check=False).stdout.split()
    for pid in pids:
        with contextlib.suppress(ProcessLookupError):
            os.kill(int(pid), signal.SIGKILL)


class Hosts:
    """``n`` hosts (network namespaces) on one switch (a bridge in its own namespace).

    Host ``i`` has address ``10.231.0.(i+1)``. Use as a context manager: everything it
    made, processes and namespaces, is removed on exit.

    Parameters
    ----------
    n : int
        Number of hosts (at most 200).
    log_dir : path-like
        Where the processes' output goes, one ``host<i>-<k>.log`` per process.
    """

    def __init__(self, n: int, log_dir: str | os.PathLike[str]) -> None:
        if not 1 <= n <= 200:
            raise ValueError(f"n must be in 1..200, got {n}")
        self.n = n
        self.log_dir = Path(log_dir)
        self.tag = f"{PREFIX}{os.getpid()}-{secrets.token_hex(3)}"
        self.switch = f"{self.tag}-sw"
        self.namespaces = [f"{self.tag}-h{i}" for i in range(n)]
        self.processes: list[tuple[int, subprocess.Popen[bytes]]] = []
        self._logs: dict[int, IO[bytes]] = {}

    def address(self, host: int) -> str:
        return f"{SUBNET}.{host + 1}"

    def __enter__(self) -> Hosts:
        sweep_stale()
        self.log_dir.mkdir(parents=True, exist_ok=True)
        try:
            self._build()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def _build(self) -> None:
        ip("netns", "add", self.switch)
        ip("-n", self.switch, "link", "add", BRIDGE, "type", "bridge")
        ip("-n", self.switch, "link", "set", BRIDGE, "up")
        for i, namespace in enumerate(self.namespaces):
            ip("netns", "add", namespace)
            ip("-n", namespace, "link", "set", "lo", "up")
            # Made with both ends already in their namespaces: no name in the root one.
            ip("link", "add", "eth0", "netns", namespace, "type", "veth", "peer", "name",
                f"port{i}", "netns", self.switch)
            ip("-n", self.switch, "link", "set", f"port{i}", "master", BRIDGE, "up")
            ip("-n", namespace, "addr", "add", f"{self.address(i)}/24", "dev", "eth0")
            ip("-n", namespace, "link", "set", "eth0", "up")

    def popen(self, host: int, argv: Sequence[str], env: dict[str, str] | None = None,
              **kwargs: object) -> subprocess.Popen[bytes]:
        """Start ``argv`` on ``host`` (its own session); its output goes to a log file
        unless ``stdout``/``stderr`` are given."""
        log = open(self.log_dir / f"host{host}-{len(self.processes)}.log", "wb")  # noqa: SIM115
        options: dict[str, object] = {"stdout": log, "stderr": subprocess.STDOUT, **kwargs}
        proc = subprocess.Popen(["ip", "netns", "exec", self.namespaces[host], *argv],
                                env=env, start_new_session=True, **options)  # type: ignore[call-overload]
        self.processes.append((host, proc))
        self._logs[proc.pid] = log
        return proc

    def log(self, proc: subprocess.Popen[bytes]) -> str:
        """What ``proc`` has written so far to its log file."""
        return Path(self._logs[proc.pid].name).read_text(errors="replace")

    def cut(self, host: int) -> float:
        """Pull ``host``'s cable, then kill every process on it; return the time
        (``time.monotonic()``) at which the link went down."""
        ip("-n", self.switch, "link", "set", f"port{host}", "down")
        down = time.monotonic()
        _kill_namespace_processes(self.namespaces[host])
        for owner, proc in self.processes:
            if owner == host:
                proc.wait()
        return down

    def freeze(self, host: int, resume: bool = False) -> float:
        """Stop (SIGSTOP) every process on ``host``, its link up: a hung machine that
        still answers TCP in its kernel; ``resume`` continues them (SIGCONT). Returns the
        time (``time.monotonic()``) of the signal."""
        signum = signal.SIGCONT if resume else signal.SIGSTOP
        for pid in ip("netns", "pids", self.namespaces[host], check=False).stdout.split():
            with contextlib.suppress(ProcessLookupError):
                os.kill(int(pid), signum)
        return time.monotonic()

    def close(self) -> None:
        """Kill every process on every host and delete the namespaces."""
        for namespace in self.namespaces:
            _kill_namespace_processes(namespace)
        for _, proc in self.processes:
            if proc.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        for log in self._logs.values():
            log.close()
        for namespace in [*self.namespaces, self.switch]:
            ip("netns", "del", namespace, check=False)


# --- a Dask cluster over the hosts ----------------------------------------------------

SCHEDULER_PORT = 8786
#: Dask settings under which a lost host costs seconds (docs/labelling.md measures them):
#: the scheduler restarts a worker that missed heartbeats for 5 s (its floor for <= 10
#: workers) through its nanny, and removes it when a hung nanny has not answered in 30 s
#: (fixed in Dask), TCP keepalive declares a silent peer dead after 11 s (Dask's floor),
#: and an unreachable nanny is given up after 3 s.
FAST_LOSS_CONFIG = {
    "distributed.scheduler.worker-ttl": "5s",
    "distributed.comm.timeouts.tcp": "11s",
    "distributed.comm.timeouts.connect": "3s",
}


def dask_environment(config: dict[str, str]) -> dict[str, str]:
    """This process's environment plus Dask settings as ``DASK_*`` variables."""
    env = dict(os.environ)
    for key, value in config.items():
        env["DASK_" + key.upper().replace(".", "__").replace("-", "_")] = value
    return env


def start_dask(hosts: Hosts, dask: str | os.PathLike[str], worker_hosts: Sequence[int],
               env: dict[str, str], workers_per_host: int = 1, timeout: float = 60.0) -> str:
    """A ``dask scheduler`` on host 0 and ``dask worker`` processes (with their nannies,
    one thread each) on ``worker_hosts``; returns the scheduler's address once every
    worker has registered."""
    address = f"tcp://{hosts.address(0)}:{SCHEDULER_PORT}"
    scheduler = hosts.popen(0, [str(dask), "scheduler", "--host", hosts.address(0), "--port",
                                str(SCHEDULER_PORT), "--no-dashboard"], env=env)
    for host in worker_hosts:
        hosts.popen(host, [str(dask), "worker", address, "--nthreads", "1", "--nworkers",
                           str(workers_per_host), "--host", hosts.address(host),
                           "--no-dashboard", "--local-directory",
                           str(hosts.log_dir / f"worker{host}")], env=env)
    wanted = workers_per_host * len(worker_hosts)
    deadline = time.monotonic() + timeout
    while hosts.log(scheduler).count("Register worker") < wanted:
        if scheduler.poll() is not None or time.monotonic() > deadline:
            raise RuntimeError(f"the Dask cluster did not come up:\n{hosts.log(scheduler)}")
        time.sleep(0.1)
    return address


_WATCHER = """
import json, sys
from distributed import Client
with Client(sys.argv[1], timeout="30s") as client:
    print("ready", flush=True)
    for _ in sys.stdin:
        print(json.dumps({w: len(t) for w, t in client.processing().items()}), flush=True)
"""


class Watcher:
    """A Dask client on host 0 that says, on request, how many tasks each worker holds
    (the test process is outside the hosts' network). Kept connected, so a question
    takes milliseconds, not an interpreter start."""

    def __init__(self, hosts: Hosts, python: str | os.PathLike[str], address: str) -> None:
        self.proc = hosts.popen(0, [str(python), "-c", _WATCHER, address],
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        assert self.proc.stdout is not None
        if self.proc.stdout.readline().strip() != b"ready":
            raise RuntimeError(f"the watcher did not connect:\n{hosts.log(self.proc)}")

    def processing(self) -> dict[str, int]:
        """Tasks assigned to each worker, by worker address."""
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(b"?\n")
        self.proc.stdin.flush()
        return dict(json.loads(self.proc.stdout.readline()))
