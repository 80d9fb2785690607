"""Two hosts simulated on this machine: network namespaces joined by a veth pair, with
DDS over UDP between them (no shared memory), for benchmarks of the node and its clients
on different hosts.

:class:`UdpHosts` makes a ``node`` and a ``client`` namespace (addresses
:data:`NODE_ADDRESS` and :data:`CLIENT_ADDRESS`, a multicast route on the veth for DDS
discovery) and removes them on exit; :meth:`UdpHosts.command` runs a command in one of
them with Fast DDS on UDPv4 only. Making namespaces needs root (CAP_SYS_ADMIN and
CAP_NET_ADMIN) and ``ip`` from iproute2: :func:`unavailable` says why not, for the
benchmark to skip with that reason.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Sequence
from pathlib import Path

# The two hosts' addresses, in a /24 of 10.231.0.0/16 of their own (the namespaces keep
# them off every other interface of this machine).
NODE_ADDRESS = "10.231.250.1"
CLIENT_ADDRESS = "10.231.250.2"
PREFIX_LENGTH = 24
# DDS discovery (SPDP) uses multicast: it goes out of the veth.
MULTICAST = "224.0.0.0/4"
# Fast DDS on UDP only, discovering the other host on its subnet (not only localhost,
# which the tests' environment may set).
UDP_ENVIRONMENT = {"FASTDDS_BUILTIN_TRANSPORTS": "UDPv4",
                   "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}


def unavailable() -> str | None:
    """Why network namespaces cannot be made here (None if they can)."""
    if shutil.which("ip") is None:
        return "no `ip` command (iproute2)"
    if os.geteuid() != 0:
        return "not root: making network namespaces needs CAP_SYS_ADMIN and CAP_NET_ADMIN"
    probe = f"gfcprobe{os.getpid()}"
    made = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True)
    if made.returncode != 0:
        return f"`ip netns add` failed: {made.stderr.strip()}"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True)
    return None


class UdpHosts:
    """The ``node`` and ``client`` network namespaces, joined by a veth pair (a context
    manager: made on entry, removed on exit, with every process still in them killed).

    Parameters
    ----------
    tag : str
        Makes the names unique on this machine (at most 8 characters: interface names
        have 15).
    """

    def __init__(self, tag: str):
        self.namespaces = {"node": f"gfc{tag}n", "client": f"gfc{tag}c"}
        self._addresses = {"node": NODE_ADDRESS, "client": CLIENT_ADDRESS}

    def __enter__(self) -> UdpHosts:
        node, client = self.namespaces["node"], self.namespaces["client"]
        try:
            for namespace in (node, client):
                _ip("netns", "add", namespace)
            _ip("link", "add", f"{node}0", "type", "veth", "peer", "name", f"{client}0")
            for host, namespace in self.namespaces.items():
                device = f"{namespace}0"
                _ip("link", "set", device, "netns", namespace)
                _ip("-n", namespace, "addr", "add",
                    f"{self._addresses[host]}/{PREFIX_LENGTH}", "dev", device)
                _ip("-n", namespace, "link", "set", "lo", "up")
                _ip("-n", namespace, "link", "set", device, "up")
                _ip("-n", namespace, "route", "add", MULTICAST, "dev", device)
        except BaseException:
            self.__exit__()
            raise
        return self

    def __exit__(self, *exc_info: object) -> None:
        for namespace in self.namespaces.values():
            pids = subprocess.run(["ip", "netns", "pids", namespace], capture_output=True,
                                  text=True).stdout.split()
            for pid in pids:
                subprocess.run(["kill", "-KILL", pid], capture_output=True)
            subprocess.run(["ip", "netns", "del", namespace], capture_output=True)

    def command(self, host: str, command: Sequence[str]) -> list[str]:
        """``command`` run in ``host``'s namespace ("node" or "client"), Fast DDS on
        UDP only."""
        return in_namespace(self.namespaces[host], command)


def in_namespace(namespace: str, command: Sequence[str]) -> list[str]:
    """``command`` run in network namespace ``namespace``, Fast DDS on UDP only (``ip``
    and ``env`` exec it: its process id is the command's)."""
    return ["ip", "netns", "exec", namespace, "env",
            *(f"{name}={value}" for name, value in UDP_ENVIRONMENT.items()), *command]


def udp_drops(pid: int | str = "self") -> int:
    """UDP datagrams dropped so far in the network namespace of process ``pid`` because
    a socket's receive buffer was full (``RcvbufErrors`` of its /proc/net/snmp)."""
    lines = Path(f"/proc/{pid}/net/snmp").read_text().splitlines()
    names, values = (line.split()[1:] for line in lines if line.startswith("Udp:"))
    return int(dict(zip(names, values, strict=True))["RcvbufErrors"])


def _ip(*arguments: str) -> None:
    done = subprocess.run(["ip", *arguments], capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"ip {' '.join(arguments)}: {done.stderr.strip()}")
