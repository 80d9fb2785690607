"""Two hosts simulated on this machine, with DDS over UDP between them (no shared
memory), for benchmarks of the node and its clients on different hosts.

:class:`UdpHosts` is two hosts of ``test/net_hosts.py`` (network namespaces on one
switch; host 0 runs the ``node``, host 1 the ``client``) with a multicast route on each
for DDS discovery; :meth:`UdpHosts.command` runs a command in one of them with Fast DDS on
UDPv4 only. Making namespaces needs root and ``ip`` from iproute2: :func:`unavailable`
(net_hosts') says why not, for the benchmark to skip with that reason.
"""

from __future__ import annotations

import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "test"))
from net_hosts import BRIDGE, Hosts, ip, unavailable  # noqa: E402

__all__ = ["UDP_ENVIRONMENT", "UdpHosts", "in_namespace", "udp_drops", "unavailable"]

# DDS discovery (SPDP) uses multicast: it goes out of the host's link.
MULTICAST = "224.0.0.0/4"
# Fast DDS on UDP only, discovering the other host on its subnet (not only localhost,
# which the tests' environment may set).
UDP_ENVIRONMENT = {"FASTDDS_BUILTIN_TRANSPORTS": "UDPv4",
                   "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}
HOST_OF = {"node": 0, "client": 1}


class UdpHosts:
    """The ``node`` and ``client`` hosts (a context manager: made on entry, removed on
    exit, with every process still in them killed)."""

    def __init__(self) -> None:
        self._logs = tempfile.TemporaryDirectory(prefix="udp_hosts_")
        self._hosts = Hosts(len(HOST_OF), self._logs.name)
        self.namespaces = {host: self._hosts.namespaces[i] for host, i in HOST_OF.items()}

    def __enter__(self) -> UdpHosts:
        self._hosts.__enter__()
        try:
            # Discovery's multicast flooded to every port, not left to IGMP snooping.
            ip("-n", self._hosts.switch, "link", "set", BRIDGE, "type", "bridge",
                "mcast_snooping", "0")
            for namespace in self.namespaces.values():
                ip("-n", namespace, "route", "add", MULTICAST, "dev", "eth0")
        except BaseException:
            self.__exit__()
            raise
        return self

    def __exit__(self, *exc_info: object) -> None:
        self._hosts.close()
        self._logs.cleanup()

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
