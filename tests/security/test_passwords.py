"""Passwords as a second factor (issue 18, item 1): every host gives the router its own user name and password
(Zenoh's ``transport/auth/usrpwd``) besides its certificate. Over a real router on loopback: a valid certificate
with a wrong, missing or another host's password opens no session or gets no rights, the right one does, and a
rotated password replaces the old one."""

from __future__ import annotations

import json
import shutil
import stat
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh

from fleetslam.cli.main import main
from fleetslam.errors import ConfigError
from fleetslam.middleware import Router
from fleetslam.middleware.context import MAX_MESSAGE_BYTES
from fleetslam.security.keystore import init_keystore, load_zenoh_config, rotate_password

from ..support import free_port

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None, reason="the openssl command makes the certificates")

HOSTS = ("c3po", "r2d2", "station")


@pytest.fixture
def keystore(tmp_path: Path) -> Path:
    directory = tmp_path / "keys"
    init_keystore(directory, agents=["c3po", "r2d2"], router_port=free_port(), max_message_bytes=MAX_MESSAGE_BYTES)
    return directory


@pytest.fixture
def router(keystore: Path) -> Iterator[Path]:
    with Router(None, security=keystore, environ={}):
        yield keystore


def _usrpwd(folder: Path) -> dict[str, Any]:
    usrpwd: dict[str, Any] = json.loads((folder / "zenoh.json5").read_text())["transport"]["auth"]["usrpwd"]
    return usrpwd


def _dictionary(directory: Path) -> dict[str, str]:
    lines = (directory / "router" / "passwords").read_text().splitlines()
    return dict(line.split(":", 1) for line in lines)


def _open(folder: Path, *, user: str | None, password: str | None) -> zenoh.Session:
    """A session from the host's own config, its certificate included, giving ``user``/``password`` instead."""
    config = load_zenoh_config(folder)
    config.insert_json5("transport/auth/usrpwd/user", json.dumps(user))
    config.insert_json5("transport/auth/usrpwd/password", json.dumps(password))
    return zenoh.open(config)


def _delivers(sender: zenoh.Session, receiver: zenoh.Session, key: str) -> bool:
    """Whether ``sender``'s puts on ``key`` reach ``receiver`` through the router within 3 s."""
    heard: list[bytes] = []
    subscriber = receiver.declare_subscriber(key, lambda sample: heard.append(sample.payload.to_bytes()))
    try:
        deadline = time.monotonic() + 3.0
        while not heard and time.monotonic() < deadline:
            sender.put(key, b"hello")
            time.sleep(0.1)
        return bool(heard)
    finally:
        subscriber.undeclare()


def test_init_gives_each_host_its_own_password_readable_by_its_owner_only(keystore: Path) -> None:
    dictionary = _dictionary(keystore)
    assert set(dictionary) == set(HOSTS)
    for host in HOSTS:
        usrpwd = _usrpwd(keystore / host)
        assert usrpwd["user"] == host and usrpwd["password"] == dictionary[host]
        assert len(usrpwd["password"]) >= 43  # 256 random bits
        assert stat.S_IMODE((keystore / host).stat().st_mode) == 0o700
        for name in ("zenoh.json5", "key.pem"):
            assert stat.S_IMODE((keystore / host / name).stat().st_mode) == 0o600, (host, name)
    assert len(set(dictionary.values())) == len(HOSTS)
    assert stat.S_IMODE((keystore / "router" / "passwords").stat().st_mode) == 0o600
    router = json.loads((keystore / "router" / "zenoh.json5").read_text())
    assert router["transport"]["auth"]["usrpwd"] == {"dictionary_file": str(keystore / "router" / "passwords")}
    router_text = (keystore / "router" / "zenoh.json5").read_text()
    assert not any(password in router_text for password in dictionary.values())
    assert {s["id"]: (s["cert_common_names"], s["usernames"]) for s in router["access_control"]["subjects"]} == {
        host: ([host], [host]) for host in HOSTS
    }


def test_a_valid_certificate_needs_its_own_password(router: Path) -> None:
    c3po, station_folder = router / "c3po", router / "station"
    station = _open(station_folder, **_usrpwd(station_folder))
    try:
        for user, password in [("c3po", "not-the-password"), ("c3po", _usrpwd(station_folder)["password"]),
                               (None, None), ("eve", "guess")]:  # fmt: skip
            with pytest.raises(zenoh.ZError):
                _open(c3po, user=user, password=password).close()
        # Another host's name and password with c3po's certificate: a session, but no subject (certificate common
        # name and user name must agree), so no rights, not even c3po's.
        borrowed = _open(c3po, **_usrpwd(station_folder))
        try:
            assert not _delivers(borrowed, station, "0/c3po/status")
        finally:
            borrowed.close()
        right = _open(c3po, **_usrpwd(c3po))
        try:
            assert _delivers(right, station, "0/c3po/status")
        finally:
            right.close()
    finally:
        station.close()


def test_rotated_password_replaces_the_old_one(keystore: Path, capsys: pytest.CaptureFixture[str]) -> None:
    before = {host: (keystore / host / "zenoh.json5").read_bytes() for host in HOSTS}
    old = _usrpwd(keystore / "c3po")
    assert main(["security", "rotate", str(keystore), "c3po"]) == 0
    assert "restart the router" in capsys.readouterr().out
    new = _usrpwd(keystore / "c3po")
    assert new["user"] == "c3po" and new["password"] != old["password"] and len(new["password"]) >= 43
    assert _dictionary(keystore)["c3po"] == new["password"]
    for host in ("r2d2", "station"):
        assert (keystore / host / "zenoh.json5").read_bytes() == before[host]
        assert _dictionary(keystore)[host] == _usrpwd(keystore / host)["password"]
    for path in (keystore / "c3po" / "zenoh.json5", keystore / "router" / "passwords"):
        assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert sorted(p.name for p in (keystore / "c3po").iterdir()) == ["ca.pem", "cert.pem", "key.pem", "zenoh.json5"]
    with Router(None, security=keystore, environ={}):  # a restarted router reads the new dictionary
        with pytest.raises(zenoh.ZError):
            _open(keystore / "c3po", **old).close()
        station = _open(keystore / "station", **_usrpwd(keystore / "station"))
        c3po = _open(keystore / "c3po", **new)
        try:
            assert _delivers(c3po, station, "0/c3po/status")
        finally:
            c3po.close()
            station.close()


def test_rotate_refuses_in_one_line(keystore: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ConfigError, match="no host 'bb8'"):
        rotate_password(keystore, "bb8")
    with pytest.raises(ConfigError, match="'router'"):
        rotate_password(keystore, "router")
    host_copy = shutil.copytree(keystore / "c3po", tmp_path / "on-c3po")
    assert main(["security", "rotate", str(host_copy), "c3po"]) != 0  # a host's folder holds no dictionary
    err = capsys.readouterr().err
    assert "passwords: missing" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    (keystore / "router" / "passwords").write_text("c3po\n")
    with pytest.raises(ConfigError, match=r"passwords:1: not a 'user:password' line"):
        rotate_password(keystore, "c3po")
