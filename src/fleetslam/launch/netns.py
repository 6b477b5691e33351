"""A multi-host fleet on one machine: Linux network namespaces joined by a bridge (needs root and iproute2).

Like the seed's virtual machines on a host-only network: a "host" namespace holds the bridge and runs the
router; each agent gets its own namespace, a veth link to the bridge and its own address. Nothing touches the
machine's real interfaces: the bridge lives inside the host namespace, and every address is inside namespaces
this class creates and deletes.
"""

from __future__ import annotations

import ipaddress
import logging
import os
import shutil
import subprocess
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from fleetslam.errors import FleetslamError

log = logging.getLogger(__name__)


class NetnsUnavailableError(FleetslamError):
    """Network namespaces cannot be created here (not root, no iproute2, or forbidden)."""


def _ip(*args: str) -> None:
    result = subprocess.run(["ip", *args], capture_output=True, text=True, check=False)
    if result.returncode != 0:
        raise NetnsUnavailableError(f"`ip {' '.join(args)}` failed: {result.stderr.strip()}")


def netns_available() -> tuple[bool, str]:
    """Whether namespaces can be created here, and why not."""
    if shutil.which("ip") is None:
        return False, "iproute2's `ip` is not installed"
    if os.geteuid() != 0:
        return False, "creating network namespaces needs root"
    probe = f"fsprobe{os.getpid()}"
    result = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True, check=False)
    if result.returncode != 0:
        return False, f"`ip netns add` is not allowed here: {result.stderr.strip()}"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True, check=False)
    return True, ""


@dataclass(frozen=True)
class Host:
    """One namespace of the virtual network."""

    name: str
    namespace: str
    address: str
    veth: str
    """The interface inside this namespace (the bridge for the host)."""


class VirtualNetwork:
    """Namespaces ``<prefix>-host`` (bridge, first address) and one per agent, on ``subnet``.

    Use as a context manager; everything is deleted on exit, also after errors.
    """

    def __init__(self, agents: Sequence[str], *, prefix: str = "fs", subnet: str = "10.77.0.0/24") -> None:
        self.prefix = prefix
        self.network = ipaddress.ip_network(subnet)
        hosts = list(self.network.hosts())
        self.host = Host("host", f"{prefix}-host", str(hosts[0]), "br0")
        self.agents: dict[str, Host] = {
            name: Host(name, f"{prefix}-{name}", str(hosts[9 + i]), f"eth-{name}"[:15]) for i, name in enumerate(agents)
        }
        self._created: list[str] = []

    def __enter__(self) -> VirtualNetwork:
        ok, why = netns_available()
        if not ok:
            raise NetnsUnavailableError(why)
        try:
            self._create()
        except Exception:
            self.delete()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.delete()

    def _create(self) -> None:
        prefix_len = self.network.prefixlen
        for ns in [self.host.namespace, *(h.namespace for h in self.agents.values())]:
            _ip("netns", "add", ns)
            self._created.append(ns)
            _ip("-n", ns, "link", "set", "lo", "up")
        _ip("-n", self.host.namespace, "link", "add", "br0", "type", "bridge")
        _ip("-n", self.host.namespace, "addr", "add", f"{self.host.address}/{prefix_len}", "dev", "br0")
        _ip("-n", self.host.namespace, "link", "set", "br0", "up")
        for i, agent in enumerate(self.agents.values()):
            peer = f"br-{self.prefix}{i}"[:15]
            # Created inside the agent's namespace, the bridge end then moved to the host: nothing in ours.
            _ip("-n", agent.namespace, "link", "add", agent.veth, "type", "veth", "peer", "name", peer)
            _ip("-n", agent.namespace, "link", "set", peer, "netns", self.host.namespace)
            _ip("-n", self.host.namespace, "link", "set", peer, "master", "br0")
            _ip("-n", self.host.namespace, "link", "set", peer, "up")
            _ip("-n", agent.namespace, "addr", "add", f"{agent.address}/{prefix_len}", "dev", agent.veth)
            _ip("-n", agent.namespace, "link", "set", agent.veth, "up")

    def delete(self) -> None:
        """Delete every namespace created (their interfaces go with them)."""
        for ns in reversed(self._created):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, check=False)
        self._created.clear()

    # -- running things ----------------------------------------------------------------------------------------
    def command(self, host: str, argv: Sequence[str]) -> list[str]:
        """The command line running ``argv`` inside a host's namespace ('host' or an agent name)."""
        namespace = self.host.namespace if host == "host" else self.agents[host].namespace
        return ["ip", "netns", "exec", namespace, *argv]

    def environment(self, host: str, router_port: int = 7447) -> dict[str, str]:
        """The fleetslam environment of a host: the router endpoint, its agent name and listen address."""
        env = {"FLEETSLAM_ROUTER": f"tcp/{self.host.address}:{router_port}"}
        if host == "host":
            env["FLEETSLAM_LISTEN"] = f"tcp/{self.host.address}:0"
        else:
            env["FLEETSLAM_AGENT"] = host
            env["FLEETSLAM_LISTEN"] = f"tcp/{self.agents[host].address}:0"
        return env

    def popen(
        self, host: str, argv: Sequence[str], *, env: Mapping[str, str] | None = None, **kwargs: object
    ) -> subprocess.Popen[str]:
        """Start a process inside a host's namespace with the fleetslam environment of that host."""
        full_env = {**os.environ, **self.environment(host), **(env or {}), "PYTHONUNBUFFERED": "1"}
        return subprocess.Popen(self.command(host, argv), env=full_env, text=True, **kwargs)  # type: ignore[call-overload]

    def run(self, host: str, argv: Sequence[str], *, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
        full_env = {**os.environ, **self.environment(host), "PYTHONUNBUFFERED": "1"}
        return subprocess.run(
            self.command(host, argv), env=full_env, text=True, capture_output=True, timeout=timeout, check=False
        )

    def set_link(self, agent: str, up: bool) -> None:
        """Take an agent's link down (cable pulled) or up again."""
        host = self.agents[agent]
        _ip("-n", host.namespace, "link", "set", host.veth, "up" if up else "down")
