"""Zenoh configs of a secured fleet (pure): mutual TLS and a password to one router, and the router's access control.

Every host (each robot, the station) connects as a Zenoh *client* to the router over ``tls/`` with a certificate
whose common name is its identity, signed by the fleet's CA, and with its own password (Zenoh's user-password
authentication, ``transport/auth/usrpwd``: user = identity); the router accepts no link without both (mutual TLS,
then the password checked against its dictionary file; the password never crosses the link, the router sends a
nonce and the host answers with an HMAC of its password keyed by it). Clients cannot link to each other, so the
router sees, and filters, everything. Its access control (``access_control``, default deny; a subject is a
certificate common name *and* the same user name, so one host's password does not lend another's certificate its
rights) lets:

- everyone subscribe to and query any topic's data, declare and watch liveliness tokens (the ROS graph), and
  publish ``/statistics``;
- an agent publish, serve services and answer queries only under its own namespace ``/<agent>`` (its own teleop
  and controller run on its host, so its own ``cmd_vel`` and services are its own);
- the station publish anything (``cmd_vel`` of every agent, the fleet map) and call every service (``e_stop``,
  resets, saves).

Calling a service is a Zenoh query, so queries to an agent's namespace are the station's and the agent's own;
other agents may query only the history caches of transient-local topics (``@adv`` keys). Known limit (Zenoh
#1562): liveliness tokens are not filtered by key, so a host may announce tokens in another's name; data and
services are filtered.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fleetslam.errors import ConfigError

#: Every kind of message the access control filters (Zenoh 1.x names).
_READ = ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query", "liveliness_token"]
_SERVE = ["put", "delete", "declare_queryable", "reply"]


@dataclass(frozen=True)
class Identity:
    """One host's credentials: its name (the certificate's common name and its user name), its files, and its
    password (the router's identity has none: it only accepts links)."""

    name: str
    key: Path
    certificate: Path
    password: str | None = None


def _tls(ca: Path, identity: Identity, *, listen: bool) -> dict[str, Any]:
    tls: dict[str, Any] = {
        "root_ca_certificate": str(ca),
        "enable_mtls": True,
        "connect_private_key": str(identity.key),
        "connect_certificate": str(identity.certificate),
        "verify_name_on_connect": True,
    }
    if listen:
        tls["listen_private_key"] = str(identity.key)
        tls["listen_certificate"] = str(identity.certificate)
    return tls


def host_config(
    ca: Path, identity: Identity, router_endpoints: Sequence[str], *, max_message_bytes: int
) -> dict[str, Any]:
    """A robot's or the station's session config: a TLS client of the router that gives its user name and password
    (rmw_zenoh session defaults otherwise)."""
    if not identity.password:
        raise ConfigError(f"host {identity.name!r}: a host's config needs its password")
    return {
        "mode": "client",
        "connect": {"endpoints": list(router_endpoints)},
        "listen": {"endpoints": []},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}, "delay": 0},
        "timestamping": {"enabled": {"router": True, "peer": True, "client": True}},
        "queries_default_timeout": 600000,
        "transport": {
            "link": {"tls": _tls(ca, identity, listen=False), "rx": {"max_message_size": max_message_bytes}},
            "auth": {"usrpwd": {"user": identity.name, "password": identity.password}},
        },
    }


def _keys(domain_id: int, *names: str) -> list[str]:
    """Key expressions of a namespace's data and of its transient-local caches (``@adv`` chunks are verbatim: ``**``
    does not reach them)."""
    keys = []
    for name in names:
        keys += [f"{domain_id}/{name}/**", f"{domain_id}/{name}/**/@adv/**"]
    return keys


def access_control(agents: Sequence[str], stations: Sequence[str], domain_id: int = 0) -> dict[str, Any]:
    """The router's ``access_control`` block (see the module docstring)."""
    everyone = [*agents, *stations]
    both = ["ingress", "egress"]
    rules: list[dict[str, Any]] = [
        {"id": "read", "permission": "allow", "flows": both, "messages": _READ,
         "key_exprs": [f"{domain_id}/**", "@ros2_lv/**", f"{domain_id}/**/@adv/**"]},
        # What the router forwards to a host: anything it let in.
        {"id": "deliver", "permission": "allow", "flows": ["egress"], "messages": [*_SERVE, "query"],
         "key_exprs": [f"{domain_id}/**", f"{domain_id}/**/@adv/**"]},
        {"id": "statistics", "permission": "allow", "flows": ["ingress"], "messages": ["put"],
         "key_exprs": _keys(domain_id, "statistics")},
        {"id": "history", "permission": "allow", "flows": ["ingress"], "messages": ["query"],
         "key_exprs": [f"{domain_id}/**/@adv/**"]},
        {"id": "station", "permission": "allow", "flows": ["ingress"], "messages": [*_SERVE, "query"],
         "key_exprs": [f"{domain_id}/**", f"{domain_id}/**/@adv/**"]},
    ]  # fmt: skip
    for agent in agents:
        rules.append({"id": f"own:{agent}", "permission": "allow", "flows": ["ingress"],
                      "messages": [*_SERVE, "query"], "key_exprs": _keys(domain_id, agent)})  # fmt: skip
    subjects = [{"id": name, "cert_common_names": [name], "usernames": [name]} for name in everyone]
    policies = [{"id": "everyone", "rules": ["read", "deliver", "statistics", "history"], "subjects": everyone}]
    policies += [{"id": f"agent:{a}", "rules": [f"own:{a}"], "subjects": [a]} for a in agents]
    if stations:
        policies.append({"id": "stations", "rules": ["station"], "subjects": list(stations)})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def password_dictionary(passwords: Mapping[str, str]) -> str:
    """The router's ``dictionary_file``: one ``user:password`` line per host (Zenoh's format)."""
    for user, password in passwords.items():
        if not user or not password or any(c in user + password for c in ":\n\r"):
            raise ConfigError(f"user {user!r}: user names and passwords must be non-empty, without ':' or newlines")
    return "".join(f"{user}:{password}\n" for user, password in passwords.items())


def router_config(
    ca: Path, identity: Identity, listen: Sequence[str], agents: Sequence[str], stations: Sequence[str], *,
    dictionary: Path, max_message_bytes: int, domain_id: int = 0,
) -> dict[str, Any]:  # fmt: skip
    """The router's config: listens on ``tls/`` endpoints only, mutual TLS, each host's password checked against
    ``dictionary`` (see :func:`password_dictionary`), the fleet's access control."""
    return {
        "mode": "router",
        "listen": {"endpoints": list(listen)},
        "connect": {"endpoints": []},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": True}, "delay": 0},
        "timestamping": {"enabled": True},
        "transport": {
            "link": {"tls": _tls(ca, identity, listen=True), "rx": {"max_message_size": max_message_bytes}},
            "auth": {"usrpwd": {"dictionary_file": str(dictionary)}},
        },
        "access_control": access_control(agents, stations, domain_id),
    }
