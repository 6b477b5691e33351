"""The operator's path through docs/security.md, by the command line: `fleetslam security init`, `fleetslam router
--security DIR` in its own process, and hosts that were given only their own folder (copied elsewhere)."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from fleetslam.cli.main import main
from fleetslam.middleware import Context, Node
from fleetslam.msg.typesys import get_type

from ..support import free_port, wait_until

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None, reason="the openssl command makes the certificates")


def test_init_router_and_hosts_with_their_own_folders(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    keys, port = tmp_path / "fleet-keys", free_port()
    assert main(["security", "init", str(keys), "--agents", "c3po,r2d2", "--port", str(port)]) == 0
    assert f"fleetslam router --security {keys}" in capsys.readouterr().out
    on_c3po = shutil.copytree(keys / "c3po", tmp_path / "c3po-host" / "keys")  # scp -r keys/c3po c3po:...
    on_station = shutil.copytree(keys / "station", tmp_path / "station-host" / "keys")
    router = subprocess.Popen(
        [sys.executable, "-m", "fleetslam.cli.main", "router", "--security", str(keys)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )  # fmt: skip
    contexts: list[Context] = []
    try:
        assert router.stdout is not None
        banner = router.stdout.readline()
        assert f"listening on tls/localhost:{port}" in banner, banner
        contexts += [
            Context(environ={"FLEETSLAM_SECURITY": str(folder)}, namespace="/") for folder in (on_c3po, on_station)
        ]
        c3po, station = Node("status", context=contexts[0]), Node("console", context=contexts[1])
        heard: list[Any] = []
        station.create_subscription("std_msgs/msg/String", "/c3po/status", heard.append)
        status = c3po.create_publisher("std_msgs/msg/String", "/c3po/status")
        assert wait_until(lambda: status.matched_subscriptions > 0, 10.0)
        status.publish(get_type("std_msgs/msg/String")(data="ok"))
        assert wait_until(lambda: len(heard) == 1, 10.0)
    finally:
        for ctx in contexts:
            ctx.close()
        router.send_signal(signal.SIGINT)
        out, _ = router.communicate(timeout=20)
    assert router.returncode == 0 and "router stopped" in out, out


@pytest.mark.parametrize(
    ("args", "says"),
    [(["--agents", ","], "name at least one agent"), (["--agents", "c3po,Bad-Name"], "'Bad-Name'")],
)
def test_init_refuses_bad_names_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], says: str
) -> None:
    assert main(["security", "init", str(tmp_path / "keys"), *args]) != 0
    err = capsys.readouterr().err
    assert says in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "keys").exists()
