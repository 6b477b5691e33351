"""ROS 2 names: validation, expansion of relative and private names, remapping, and the environment.

Rules (as rcl): a name is absolute (`/a/b`), relative (`a/b`, expanded in the node's namespace) or private
(`~/a` or `~`, expanded under the node's fully qualified name); the substitutions `{node}`, `{ns}` and
`{namespace}` are replaced first. Tokens contain only `[A-Za-z0-9_]`, do not start with a digit, and are
separated by single slashes; no trailing slash. Remaps are applied after expansion, both sides expanded with
the node's context, the first matching rule wins; a rule `node:from` applies only to the node called `node`.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from fleetslam.errors import ConfigError, MiddlewareError

_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def validate_fq_name(name: str, what: str = "name") -> str:
    """Check a fully qualified name; returns it unchanged or raises MiddlewareError saying what is wrong."""
    if not name.startswith("/"):
        raise MiddlewareError(f"{what} '{name}' must be absolute (start with '/')")
    if name == "/":
        return name
    if name.endswith("/"):
        raise MiddlewareError(f"{what} '{name}' must not end with '/'")
    for token in name[1:].split("/"):
        if not token:
            raise MiddlewareError(f"{what} '{name}' has an empty token (repeated '/')")
        if not _TOKEN.match(token):
            raise MiddlewareError(
                f"{what} '{name}': token '{token}' must be letters, digits and '_' and not start with a digit"
            )
    return name


def validate_node_name(name: str) -> str:
    """A node's base name is one token."""
    if not _TOKEN.match(name):
        raise MiddlewareError(f"node name '{name}' must be letters, digits and '_' and not start with a digit")
    return name


def normalize_namespace(namespace: str) -> str:
    """`c3po` → `/c3po`, `` → `/`; validated."""
    if not namespace or namespace == "/":
        return "/"
    namespace = namespace if namespace.startswith("/") else f"/{namespace}"
    return validate_fq_name(namespace.rstrip("/") or "/", "namespace")


_SUBSTITUTION = re.compile(r"\{([^{}]*)\}")


def _substitute(name: str, namespace: str, node_name: str) -> str:
    values = {"node": node_name, "ns": namespace, "namespace": namespace}

    def replace(match: re.Match[str]) -> str:
        try:
            return values[match.group(1)]
        except KeyError:
            raise MiddlewareError(
                f"name '{name}': unknown substitution {match.group(0)} (known: {{node}}, {{ns}}, {{namespace}})"
            ) from None

    substituted = _SUBSTITUTION.sub(replace, name)
    if "{" in substituted or "}" in substituted:
        raise MiddlewareError(f"name '{name}': unbalanced '{{' or '}}'")
    # `{ns}/x` with the root namespace gives `//x`; rcl collapses that to `/x`.
    return "/" + substituted.lstrip("/") if substituted.startswith("//") else substituted


def expand_name(name: str, *, namespace: str, node_name: str) -> str:
    """Expand a relative or private name to a fully qualified one (no remapping)."""
    namespace = normalize_namespace(namespace)
    base = namespace.rstrip("/")
    if not name:
        raise MiddlewareError("empty name")
    if "{" in name or "}" in name:
        name = _substitute(name, namespace, node_name)
    if name == "~":
        expanded = f"{base}/{node_name}"
    elif name.startswith("~/"):
        expanded = f"{base}/{node_name}/{name[2:]}"
    elif name.startswith("~"):
        raise MiddlewareError(f"name '{name}': '~' must be followed by '/'")
    elif name.startswith("/"):
        expanded = name
    else:
        expanded = f"{base}/{name}"
    return validate_fq_name(expanded)


def resolve_name(name: str, *, namespace: str, node_name: str, remaps: Mapping[str, str] | None = None) -> str:
    """Expand ``name`` and apply the first matching remap rule (both sides expanded)."""
    expanded = expand_name(name, namespace=namespace, node_name=node_name)
    for rule, target in (remaps or {}).items():
        node, sep, source = rule.rpartition(":")
        if (sep and node != node_name) or source.startswith("__"):
            continue
        if expand_name(source, namespace=namespace, node_name=node_name) == expanded:
            return expand_name(target, namespace=namespace, node_name=node_name)
    return expanded


@dataclass(frozen=True)
class NameContext:
    """Where a node resolves names: its namespace, its base name and its remap rules."""

    node_name: str
    namespace: str = "/"
    remaps: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        validate_node_name(self.node_name)
        object.__setattr__(self, "namespace", normalize_namespace(self.namespace))

    @property
    def fq_node_name(self) -> str:
        """The node's fully qualified name, e.g. ``/c3po/slam``."""
        return f"{self.namespace.rstrip('/')}/{self.node_name}"

    def resolve(self, name: str) -> str:
        """Fully qualified, remapped name of a topic or service name."""
        return resolve_name(name, namespace=self.namespace, node_name=self.node_name, remaps=self.remaps)


@dataclass(frozen=True)
class RosArgs:
    """What `--ros-args` arguments say: remaps, node name/namespace overrides, parameters."""

    remaps: dict[str, str] = field(default_factory=dict)
    namespace: str | None = None
    node_name: str | None = None
    parameters: dict[str, str] = field(default_factory=dict)
    """`-p key:=value` overrides, values as text (YAML)."""
    params_files: list[str] = field(default_factory=list)
    remaining: list[str] = field(default_factory=list)
    """Arguments outside any `--ros-args` section."""
    log_level: str | None = None
    """`--log-level LEVEL` (accepted for compatibility with ROS 2 launch files)."""
    enclave: str | None = None
    """`-e/--enclave NAME` (accepted; fleetslam uses the enclave `/`)."""


#: ROS 2 flags without a value that fleetslam accepts and ignores (logging destinations).
_IGNORED_FLAGS = frozenset(
    {
        "--enable-rosout-logs",
        "--disable-rosout-logs",
        "--enable-stdout-logs",
        "--disable-stdout-logs",
        "--enable-external-lib-logs",
        "--disable-external-lib-logs",
    }
)


def _check_remap(rule: str, target: str) -> None:
    """Check that both sides of a remap rule are valid names (a rule may name its node as `node:from`)."""
    node, sep, source = rule.rpartition(":")
    if sep:
        validate_node_name(node)
        if source in ("__ns", "__node", "__name"):
            raise MiddlewareError(f"node-specific '{source}' rules are not supported; write '{source}:={target}'")
    for name in (source, target):
        expand_name(name, namespace="/", node_name="node")


def parse_ros_args(argv: Sequence[str]) -> RosArgs:
    """Parse ``--ros-args -r a:=b -r __ns:=/x -p k:=v --params-file f [--]`` sections of a command line.

    Outside a `--ros-args` section, ``-r``/``--remap`` are not consumed. Bad rules raise ConfigError.
    """
    remaps: dict[str, str] = {}
    parameters: dict[str, str] = {}
    params_files: list[str] = []
    namespace = node_name = log_level = enclave = None
    remaining: list[str] = []
    in_ros = False
    i = 0
    args = list(argv)
    while i < len(args):
        arg = args[i]
        if arg == "--ros-args":
            in_ros = True
        elif in_ros and arg == "--":
            in_ros = False
        elif in_ros and arg in _IGNORED_FLAGS:
            pass
        elif in_ros and arg in ("-r", "--remap", "-p", "--param", "--params-file", "--log-level", "-e", "--enclave"):
            if i + 1 >= len(args):
                raise ConfigError(f"--ros-args: '{arg}' needs a value")
            value = args[i + 1]
            i += 1
            if arg == "--params-file":
                params_files.append(value)
            elif arg == "--log-level":
                log_level = value
            elif arg in ("-e", "--enclave"):
                enclave = value
            else:
                key, sep, target = value.partition(":=")
                if not sep or not key:
                    raise ConfigError(f"--ros-args {arg} {value!r}: expected FROM:=TO")
                try:
                    if arg in ("-p", "--param"):
                        parameters[key] = target
                    elif key == "__ns":
                        namespace = normalize_namespace(target)
                    elif key in ("__node", "__name"):
                        node_name = validate_node_name(target)
                    else:
                        _check_remap(key, target)
                        remaps[key] = target
                except MiddlewareError as err:
                    raise ConfigError(f"--ros-args {arg} {value!r}: {err}") from err
        elif in_ros:
            raise ConfigError(f"--ros-args: unknown argument {arg!r}")
        else:
            remaining.append(arg)
        i += 1
    return RosArgs(remaps, namespace, node_name, parameters, params_files, remaining, log_level, enclave)


def namespace_from_env(environ: Mapping[str, str] | None = None) -> str:
    """The default namespace: ``FLEETSLAM_AGENT=c3po`` → ``/c3po``; unset → ``/``."""
    environ = os.environ if environ is None else environ
    agent = environ.get("FLEETSLAM_AGENT", "").strip()
    try:
        return normalize_namespace(agent)
    except MiddlewareError as err:
        raise ConfigError(f"environment variable FLEETSLAM_AGENT={agent!r}: {err}") from err


def domain_id_from_env(environ: Mapping[str, str] | None = None) -> int:
    """``ROS_DOMAIN_ID`` (default 0)."""
    environ = os.environ if environ is None else environ
    text = environ.get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return 0
    if not (text.isascii() and text.isdigit()):
        raise ConfigError(f"environment variable ROS_DOMAIN_ID={text!r}: expected a non-negative integer")
    return int(text)


def agent_of(fq_name: str) -> str:
    """The agent (first namespace token) of a fully qualified name; '' for root-level names like /statistics."""
    tokens = fq_name.strip("/").split("/")
    return tokens[0] if len(tokens) > 1 else ""
