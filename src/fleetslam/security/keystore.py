"""A fleet's keystore on disk: a CA, a key, certificate and password per host, and each host's Zenoh config.

Layout of ``DIR`` (made by ``fleetslam security init``)::

    ca.pem, ca.key          the fleet's certificate authority (keep ca.key offline once the fleet is set up)
    router/                 key.pem, cert.pem, ca.pem, zenoh.json5: the router's, and passwords: every host's
                            password (Zenoh's user-password dictionary, ``user:password`` per line)
    <host>/                 key.pem, cert.pem, ca.pem, zenoh.json5 (with the host's user name and password) for
                            each agent and station: copy only this folder to the host

Certificates are made with the ``openssl`` command (EC P-256, 10 years, common name = host name, every certificate
valid for both ends of a TLS link). Passwords are 256 random bits from :mod:`secrets` (43 URL-safe characters).
Keys, passwords and configs are readable by their owner only (0600, folders 0700). Each host folder is
self-contained; its ``zenoh.json5`` is a standard Zenoh config (usable as rmw_zenoh's
``ZENOH_SESSION_CONFIG_URI``/``ZENOH_ROUTER_CONFIG_URI`` as long as the folder stays where it was made); fleetslam
itself points the TLS paths and the password dictionary at the folder wherever it is.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import secrets
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from fleetslam.errors import ConfigError
from fleetslam.security.policy import Identity, host_config, password_dictionary, router_config

ROUTER = "router"
CONFIG_FILE = "zenoh.json5"
PASSWORDS_FILE = "passwords"
_NAME = re.compile(r"[a-z][a-z0-9_]{0,62}")


def _openssl(*args: str) -> None:
    if shutil.which("openssl") is None:
        raise ConfigError("the 'openssl' command is needed to make certificates; install it (apt install openssl)")
    result = subprocess.run(["openssl", *args], capture_output=True, text=True, check=False)
    if result.returncode != 0:
        raise ConfigError(f"openssl {args[0]} failed: {result.stderr.strip()}")


def _identity(folder: Path, name: str) -> Identity:
    return Identity(name, folder / "key.pem", folder / "cert.pem")


def _issue(root: Path, name: str, alt_names: Sequence[str]) -> Identity:
    folder = root / name
    folder.mkdir(mode=0o700)
    identity = _identity(folder, name)
    _openssl("ecparam", "-name", "prime256v1", "-genkey", "-noout", "-out", str(identity.key))
    os.chmod(identity.key, 0o600)
    with tempfile.TemporaryDirectory() as scratch:
        request, extensions = Path(scratch) / "req.csr", Path(scratch) / "ext.cnf"
        sans = ",".join(f"IP:{n}" if re.fullmatch(r"[0-9.]+|[0-9a-fA-F:]+:[0-9a-fA-F:]*", n) else f"DNS:{n}"
                        for n in dict.fromkeys([name, *alt_names]))  # fmt: skip
        extensions.write_text(
            "basicConstraints=critical,CA:FALSE\nkeyUsage=critical,digitalSignature\n"
            f"extendedKeyUsage=serverAuth,clientAuth\nsubjectAltName={sans}\n"
        )
        _openssl("req", "-new", "-key", str(identity.key), "-subj", f"/CN={name}", "-out", str(request))
        _openssl("x509", "-req", "-in", str(request), "-CA", str(root / "ca.pem"), "-CAkey", str(root / "ca.key"),
                 "-CAcreateserial", "-days", "3650", "-sha256", "-extfile", str(extensions),
                 "-out", str(identity.certificate))  # fmt: skip
    shutil.copy(root / "ca.pem", folder / "ca.pem")
    return identity


def _write_private(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` readable by its owner only, from the first byte on, replacing the file at once."""
    scratch = path.with_name(f".{path.name}.new")
    fd = os.open(scratch, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as out:
        os.fchmod(out.fileno(), 0o600)
        out.write(text)
    os.replace(scratch, path)


def _write_json5(path: Path, config: dict[str, Any]) -> None:
    _write_private(path, json.dumps(config, indent=2) + "\n")


def new_password() -> str:
    """A fresh host password: 256 random bits, 43 URL-safe characters (no ':' that the dictionary could trip on)."""
    return secrets.token_urlsafe(32)


def init_keystore(
    directory: Path,
    *,
    agents: Sequence[str],
    stations: Sequence[str] = ("station",),
    router_hosts: Sequence[str] = ("localhost", "127.0.0.1"),
    router_port: int = 7447,
    max_message_bytes: int,
) -> list[str]:
    """Make the keystore (see the module docstring) in ``directory``, which must not exist or be empty; returns the
    identities made. Router endpoints are ``tls/<first router host>:<port>``; the router's certificate is valid for
    every name in ``router_hosts``."""
    names = [*agents, *stations]
    for name in names:
        if not _NAME.fullmatch(name) or name == ROUTER:
            raise ConfigError(f"host name {name!r}: use lower-case letters, digits and '_' (not {ROUTER!r})")
    if len(set(names)) != len(names):
        raise ConfigError(f"host names must differ: {names}")
    if not agents:
        raise ConfigError("name at least one agent (--agents c3po,r2d2)")
    if directory.exists() and any(directory.iterdir()):
        raise ConfigError(f"{directory}: not empty; a keystore is made once (remove it to start again)")
    directory.mkdir(parents=True, exist_ok=True, mode=0o700)
    _openssl("ecparam", "-name", "prime256v1", "-genkey", "-noout", "-out", str(directory / "ca.key"))
    os.chmod(directory / "ca.key", 0o600)
    _openssl("req", "-new", "-x509", "-key", str(directory / "ca.key"), "-subj", "/CN=fleetslam fleet CA",
             "-days", "3650", "-sha256", "-addext", "basicConstraints=critical,CA:TRUE",
             "-addext", "keyUsage=critical,keyCertSign,cRLSign", "-out", str(directory / "ca.pem"))  # fmt: skip
    router = _issue(directory, ROUTER, router_hosts)
    endpoint = f"tls/{router_hosts[0]}:{router_port}"
    listen = f"tls/{'[::]' if router_hosts[0] not in ('localhost', '127.0.0.1') else router_hosts[0]}:{router_port}"
    passwords = {name: new_password() for name in names}
    dictionary = router.key.parent / PASSWORDS_FILE
    _write_private(dictionary, password_dictionary(passwords))
    config = router_config(
        router.key.parent / "ca.pem", router, [listen], agents, stations, dictionary=dictionary,
        max_message_bytes=max_message_bytes,
    )  # fmt: skip
    _write_json5(router.key.parent / CONFIG_FILE, config)
    for name in names:
        identity = dataclasses.replace(_issue(directory, name, ()), password=passwords[name])
        config = host_config(identity.key.parent / "ca.pem", identity, [endpoint], max_message_bytes=max_message_bytes)
        _write_json5(identity.key.parent / CONFIG_FILE, config)
    return [ROUTER, *names]


def _read_dictionary(path: Path) -> dict[str, str]:
    passwords: dict[str, str] = {}
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(f"{path}: cannot read the router's password dictionary: {err}") from err
    for number, line in enumerate(lines, 1):
        user, colon, password = line.partition(":")
        if not colon or not user or not password:
            raise ConfigError(f"{path}:{number}: not a 'user:password' line")
        passwords[user] = password
    return passwords


def rotate_password(directory: Path, host: str) -> Path:
    """Give ``host`` a new password in the keystore ``directory`` (the operator's whole copy): its ``zenoh.json5``
    and the router's dictionary are rewritten; returns the host's folder, to copy to the host again. The router
    reads its dictionary when it starts: restart it, then the host's nodes (links made before keep working until
    they close; the old password opens none after the restart)."""
    dictionary = directory / ROUTER / PASSWORDS_FILE
    config_path = directory / host / CONFIG_FILE
    if host == ROUTER or not _NAME.fullmatch(host):
        raise ConfigError(f"host name {host!r}: give an agent's or a station's name")
    if not dictionary.is_file():
        raise ConfigError(
            f"{dictionary}: missing; rotate passwords in the whole keystore made by 'fleetslam security init' "
            "(keystores made before passwords existed have none: make a new one)"
        )
    passwords = _read_dictionary(dictionary)
    if host not in passwords or not config_path.is_file():
        raise ConfigError(f"{directory}: no host {host!r} (hosts: {', '.join(passwords)})")
    try:
        config = json.loads(config_path.read_text())
        usrpwd = config["transport"]["auth"]["usrpwd"]
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError) as err:
        raise ConfigError(f"{config_path}: not a host config made by 'fleetslam security init': {err}") from err
    passwords[host] = usrpwd["password"] = new_password()
    usrpwd["user"] = host
    _write_json5(config_path, config)
    _write_private(dictionary, password_dictionary(passwords))
    return config_path.parent


def host_folder(directory: Path, identity: str | None) -> Path:
    """The folder of one identity: ``directory`` itself when it holds a config (a host's copy), else its
    ``identity`` subfolder. Raises ConfigError saying what is missing."""
    if (directory / CONFIG_FILE).is_file():
        return directory
    if identity and (directory / identity / CONFIG_FILE).is_file():
        return directory / identity
    raise ConfigError(
        f"{directory}: no {CONFIG_FILE} here or in {str(directory / (identity or '<identity>'))!r}; make the keystore "
        "with 'fleetslam security init' and point FLEETSLAM_SECURITY / --security at it or at a host's folder"
    )


def load_zenoh_config(folder: Path) -> Any:
    """The folder's Zenoh config, its TLS files taken from the folder wherever it now is."""
    import zenoh

    try:
        config = zenoh.Config.from_file(str(folder / CONFIG_FILE))
    except Exception as err:
        raise ConfigError(f"{folder / CONFIG_FILE}: invalid Zenoh config: {err}") from err
    for key, file in (("root_ca_certificate", "ca.pem"), ("connect_private_key", "key.pem"),
                      ("connect_certificate", "cert.pem")):  # fmt: skip
        config.insert_json5(f"transport/link/tls/{key}", json.dumps(str(folder / file)))
    if json.loads(config.get_json("mode")) == "router":
        config.insert_json5("transport/link/tls/listen_private_key", json.dumps(str(folder / "key.pem")))
        config.insert_json5("transport/link/tls/listen_certificate", json.dumps(str(folder / "cert.pem")))
        if json.loads(config.get_json("transport/auth/usrpwd/dictionary_file")) is not None:
            config.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(folder / PASSWORDS_FILE)))
    return config
