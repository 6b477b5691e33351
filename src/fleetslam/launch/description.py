"""Fleet descriptions: which hosts run which agents and nodes, as a validated YAML file.

A fleet file looks like::

    router:
      endpoint: tcp/10.1.2.2:7447      # every process connects here (FLEETSLAM_ROUTER)
      host: base                        # the host that runs `fleetslam router`
    domain_id: 0
    environment: {FLEETSLAM_LOG_LEVEL: info}   # for every process
    agents:
      - name: c3po                      # namespace /c3po (FLEETSLAM_AGENT)
        host: c3po
        listen: tcp/10.1.2.10:0         # FLEETSLAM_LISTEN on that host
        nodes:
          - name: slam
            command: [slam, node]       # a fleetslam subcommand, or `exec: [program, args...]`
            parameters: {odometry.max_features: 1000}
            remaps: {odom: /c3po/wheel_odom}
    hosts_nodes:                        # nodes not bound to an agent (station, fleet map)
      - {name: station, host: base, command: [station, --port, "8080"]}

Each node runs as its own process (CPU-heavy nodes must not share a GIL). The environment of a node is the
fleet's, then its agent's, then its own; FLEETSLAM_ROUTER / FLEETSLAM_AGENT / FLEETSLAM_LISTEN /
ROS_DOMAIN_ID are set from the description so that nothing else is needed to join.
"""

from __future__ import annotations

import shlex
import sys
from pathlib import Path
from typing import Literal

from pydantic import Field, field_validator, model_validator

from fleetslam.config import ConfigModel, load_config, read_yaml
from fleetslam.errors import ConfigError
from fleetslam.middleware.context import check_endpoint

_NAME_PATTERN = r"^[A-Za-z_][A-Za-z0-9_]*$"


class RouterSpec(ConfigModel):
    """Where the fleet's Zenoh router (the discovery service) runs."""

    endpoint: str = "tcp/localhost:7447"
    """Endpoint every process connects to (FLEETSLAM_ROUTER); comma-separate several."""
    host: str = "localhost"
    """Host that runs the router."""
    listen: list[str] = Field(default_factory=lambda: ["tcp/[::]:7447"])
    """Endpoints the router listens on."""
    embedded: bool = True
    """Start the router as one of the supervised processes when launching on its host."""

    @field_validator("endpoint")
    @classmethod
    def _endpoints(cls, endpoint: str) -> str:
        return ",".join(check_endpoint(e) for e in endpoint.split(","))

    @field_validator("listen")
    @classmethod
    def _listen(cls, listen: list[str]) -> list[str]:
        return [check_endpoint(e) for e in listen]


class RestartPolicy(ConfigModel):
    """How a crashed node is restarted."""

    mode: Literal["on-failure", "always", "never"] = "on-failure"
    """`on-failure` restarts after a non-zero exit, `always` after any exit, `never` leaves it stopped."""
    initial_backoff_s: float = Field(default=1.0, gt=0)
    """Delay before the first restart; doubled after each crash in a row."""
    max_backoff_s: float = Field(default=30.0, gt=0)
    """Upper bound of the restart delay."""
    stable_after_s: float = Field(default=30.0, gt=0)
    """A node that ran this long without crashing gets its back-off reset."""
    max_restarts: int = Field(default=-1, ge=-1)
    """Give up after this many restarts (-1: never give up)."""


class NodeSpec(ConfigModel):
    """One process of the fleet."""

    name: str = Field(pattern=_NAME_PATTERN)
    """Node name (also the log prefix, with the agent)."""
    command: list[str] | None = None
    """A fleetslam subcommand and its arguments, e.g. [slam, node]; run with this Python."""
    exec: list[str] | None = None
    """Any program and its arguments (instead of `command`)."""
    host: str | None = None
    """Host to run on; defaults to the agent's host."""
    parameters: dict[str, object] = Field(default_factory=dict)
    """Parameter overrides, passed as `--ros-args -p key:=value`."""
    remaps: dict[str, str] = Field(default_factory=dict)
    """Topic/service remaps, passed as `--ros-args -r from:=to`."""
    environment: dict[str, str] = Field(default_factory=dict)
    """Extra environment variables for this process."""
    restart: RestartPolicy = Field(default_factory=RestartPolicy)
    """Restart policy when the process exits."""

    @model_validator(mode="after")
    def _one_program(self) -> NodeSpec:
        if (self.command is None) == (self.exec is None):
            raise ValueError("give exactly one of 'command' (a fleetslam subcommand) or 'exec' (a program)")
        program = self.command if self.command is not None else self.exec
        if not program:
            raise ValueError("the command must not be empty")
        return self


class AgentSpec(ConfigModel):
    """A robot (or any agent) with its own namespace."""

    name: str = Field(pattern=_NAME_PATTERN)
    """Agent name, its namespace (FLEETSLAM_AGENT)."""
    host: str = "localhost"
    """Host that runs the agent's nodes."""
    listen: str | None = None
    """This host's listen endpoint (FLEETSLAM_LISTEN), e.g. tcp/10.1.2.10:0."""

    @field_validator("listen")
    @classmethod
    def _listen(cls, listen: str | None) -> str | None:
        return None if listen is None else check_endpoint(listen)

    environment: dict[str, str] = Field(default_factory=dict)
    """Environment variables for every node of the agent."""
    nodes: list[NodeSpec] = Field(default_factory=list)
    """The agent's processes."""


class FleetDescription(ConfigModel):
    """A whole fleet: router, agents and their nodes, and host-level nodes."""

    router: RouterSpec = Field(default_factory=RouterSpec)
    """The discovery service."""
    domain_id: int = Field(default=0, ge=0)
    """ROS_DOMAIN_ID of every process."""
    environment: dict[str, str] = Field(default_factory=dict)
    """Environment variables for every process."""
    agents: list[AgentSpec] = Field(default_factory=list)
    """The agents."""
    hosts_nodes: list[NodeSpec] = Field(default_factory=list)
    """Nodes outside any agent namespace (station, fleet map); each names its host."""
    security: str = ""
    """Keystore made by ``fleetslam security init``, at this path on every host (each host needs only its own
    folder of it): the router runs with ``--security``, every process gets ``FLEETSLAM_SECURITY``; agents' nodes
    act as their agent, host-level nodes as ``station``. ``router.endpoint`` must then be a ``tls/`` endpoint.
    Empty: an open fleet (docs/security.md)."""

    @model_validator(mode="after")
    def _secured_router_is_tls(self) -> FleetDescription:
        if self.security and not all(e.strip().startswith("tls/") for e in self.router.endpoint.split(",")):
            raise ValueError(f"with security, router.endpoint must be tls/..., got {self.router.endpoint!r}")
        return self

    @field_validator("agents")
    @classmethod
    def _unique_agents(cls, agents: list[AgentSpec]) -> list[AgentSpec]:
        names = [a.name for a in agents]
        duplicates = sorted({n for n in names if names.count(n) > 1})
        if duplicates:
            raise ValueError(f"agent names must be unique, repeated: {duplicates}")
        return agents


def load_fleet(path: str | Path, overrides: list[str] | None = None) -> FleetDescription:
    """Read and validate a fleet file; errors name the file, the key and the value. An empty file is an error (it
    would describe a lone router listening on every interface)."""
    if not read_yaml(path) and not overrides:
        raise ConfigError(f"{path}: empty fleet file; describe at least one agent (see examples/)")
    return load_config(FleetDescription, path, overrides=overrides)


class ProcessSpec(ConfigModel):
    """A resolved process: what to run, where, with which environment."""

    label: str
    """Log prefix, e.g. `c3po/slam`."""
    host: str
    """Host it runs on."""
    argv: list[str]
    """Full command line."""
    environment: dict[str, str]
    """Environment variables set for it (on top of the host's)."""
    restart: RestartPolicy
    """Restart policy."""
    niceness: int = Field(default=0, ge=0, le=19)
    """Added to the launcher's scheduling niceness (0: the same priority; higher yields the CPU to the others)."""


def _ros_args(node: NodeSpec) -> list[str]:
    extra: list[str] = []
    for key, value in node.parameters.items():
        extra += ["-p", f"{key}:={value}"]
    for source, target in node.remaps.items():
        extra += ["-r", f"{source}:={target}"]
    return ["--ros-args", *extra] if extra else []


def _argv(node: NodeSpec, python: str) -> list[str]:
    if node.command is not None:
        return [python, "-m", "fleetslam.cli.main", *node.command, *_ros_args(node)]
    assert node.exec is not None
    return [*node.exec, *_ros_args(node)]


def resolve_processes(fleet: FleetDescription, *, python: str | None = None) -> list[ProcessSpec]:
    """Every process of the fleet, router first, with its full environment and command line."""
    python = python or sys.executable
    base_env = {
        **fleet.environment,
        "FLEETSLAM_ROUTER": fleet.router.endpoint,
        "ROS_DOMAIN_ID": str(fleet.domain_id),
    }
    host_identity = {}
    if fleet.security:
        base_env["FLEETSLAM_SECURITY"] = fleet.security
        host_identity["FLEETSLAM_IDENTITY"] = "station"
    processes: list[ProcessSpec] = []
    if fleet.router.embedded:
        # A secured router listens where its keystore says, unless the file names listen endpoints itself.
        listen = fleet.router.listen if not fleet.security or "listen" in fleet.router.model_fields_set else []
        listen_args = [arg for endpoint in listen for arg in ("--listen", endpoint)]
        security_args = ["--security", fleet.security] if fleet.security else []
        processes.append(
            ProcessSpec(
                label="router",
                host=fleet.router.host,
                argv=[python, "-m", "fleetslam.cli.main", "router", *listen_args, *security_args],
                environment=dict(fleet.environment),
                restart=RestartPolicy(mode="always"),
            )
        )
    for agent in fleet.agents:
        agent_env = {**base_env, **agent.environment, "FLEETSLAM_AGENT": agent.name}
        if agent.listen:
            agent_env["FLEETSLAM_LISTEN"] = agent.listen
        for node in agent.nodes:
            processes.append(
                ProcessSpec(
                    label=f"{agent.name}/{node.name}",
                    host=node.host or agent.host,
                    argv=_argv(node, python),
                    environment={**agent_env, **node.environment},
                    restart=node.restart,
                )
            )
    for node in fleet.hosts_nodes:
        processes.append(
            ProcessSpec(
                label=node.name,
                host=node.host or fleet.router.host,
                argv=_argv(node, python),
                environment={**base_env, **host_identity, **node.environment},
                restart=node.restart,
            )
        )
    return processes


def format_host_instructions(fleet: FleetDescription) -> str:
    """Per host, the exact environment and command to run there (for deploying by hand)."""
    by_host: dict[str, list[ProcessSpec]] = {}
    for process in resolve_processes(fleet, python="python3"):
        by_host.setdefault(process.host, []).append(process)
    lines: list[str] = []
    for host, processes in by_host.items():
        lines.append(f"# host {host}")
        for process in processes:
            argv = list(process.argv)
            if argv[:3] == ["python3", "-m", "fleetslam.cli.main"]:
                argv = ["fleetslam", *argv[3:]]
            env = " ".join(f"{k}={shlex.quote(v)}" for k, v in sorted(process.environment.items()))
            lines.append(f"# {process.label}")
            lines.append(f"{env} {shlex.join(argv)}".strip())
        lines.append("")
    return "\n".join(lines)
