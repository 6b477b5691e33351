"""A secured fleet over a real router on loopback: mutual TLS keeps strangers out, the access control keeps each
agent in its own namespace, and the station drives everyone (issue 18, item 1)."""

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

from fleetslam.errors import ConfigError, RouterUnreachableError, ServiceError
from fleetslam.middleware import Context, Node, QoSProfile, Router
from fleetslam.middleware.context import MAX_MESSAGE_BYTES
from fleetslam.middleware.wire import encode_attachment
from fleetslam.msg.typesys import get_type, message_from_dict, serialize
from fleetslam.security.keystore import init_keystore

from ..middleware.test_wire import STRING_HASH
from ..support import free_port, wait_until

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None, reason="the openssl command makes the certificates")


def twist(v: float) -> Any:
    return message_from_dict("geometry_msgs/msg/Twist", {"linear": {"x": v}})


@pytest.fixture(scope="module")
def keystore(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, int]:
    port = free_port()
    directory = tmp_path_factory.mktemp("fleet") / "keys"
    made = init_keystore(directory, agents=["c3po", "r2d2"], router_port=port, max_message_bytes=MAX_MESSAGE_BYTES)
    assert made == ["router", "c3po", "r2d2", "station"]
    return directory, port


@pytest.fixture
def secured_router(keystore: tuple[Path, int]) -> Iterator[tuple[Path, int]]:
    directory, port = keystore
    with Router(None, security=directory, environ={}) as router:
        assert router.listen == [f"tls/localhost:{port}"]
        yield keystore


def _host(directory: Path, identity: str) -> Context:
    return Context(environ={"FLEETSLAM_SECURITY": str(directory), "FLEETSLAM_IDENTITY": identity}, namespace="/")


def test_keystore_files_and_refusals(keystore: tuple[Path, int], tmp_path: Path) -> None:
    directory, port = keystore
    for host in ("router", "c3po", "r2d2", "station"):
        folder = directory / host
        files = {"ca.pem", "cert.pem", "key.pem", "zenoh.json5"} | ({"passwords"} if host == "router" else set())
        assert {p.name for p in folder.iterdir()} == files
        assert stat.S_IMODE((folder / "key.pem").stat().st_mode) == 0o600
    c3po = json.loads((directory / "c3po" / "zenoh.json5").read_text())
    assert c3po["mode"] == "client" and c3po["connect"]["endpoints"] == [f"tls/localhost:{port}"]
    assert c3po["transport"]["link"]["tls"]["enable_mtls"] is True
    router = json.loads((directory / "router" / "zenoh.json5").read_text())
    assert router["access_control"]["default_permission"] == "deny"
    with pytest.raises(ConfigError, match="not empty"):
        init_keystore(directory, agents=["c3po"], max_message_bytes=MAX_MESSAGE_BYTES)
    with pytest.raises(ConfigError, match="'R2-D2'"):
        init_keystore(tmp_path / "k", agents=["R2-D2"], max_message_bytes=MAX_MESSAGE_BYTES)
    with pytest.raises(ConfigError, match=r"no zenoh\.json5"):
        _host(tmp_path, "c3po")


def test_strangers_cannot_connect(secured_router: tuple[Path, int]) -> None:
    directory, port = secured_router
    stranger = zenoh.Config()  # trusts the fleet's CA, but has no certificate of its own
    stranger.insert_json5("mode", '"client"')
    stranger.insert_json5("connect/endpoints", json.dumps([f"tls/localhost:{port}"]))
    stranger.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(str(directory / "ca.pem")))
    with pytest.raises(zenoh.ZError):
        zenoh.open(stranger)
    with pytest.raises(RouterUnreachableError):  # plain TCP: nothing listens for it
        Context(router=f"tcp/127.0.0.1:{port}", listen="tcp/127.0.0.1:0", environ={}, router_timeout_s=1.0)


def test_agents_stay_in_their_namespace_and_the_station_drives_everyone(secured_router: tuple[Path, int]) -> None:
    directory, _ = secured_router
    contexts = [_host(directory, name) for name in ("c3po", "r2d2", "station")]
    try:
        c3po, r2d2, station = (Node("n", context=ctx) for ctx in contexts)
        commands: list[float] = []
        r2d2.create_subscription("geometry_msgs/msg/Twist", "/r2d2/cmd_vel", lambda m: commands.append(m.linear.x))
        seen: dict[str, list[Any]] = {"odom": [], "stats": []}
        station.create_subscription("std_msgs/msg/String", "/c3po/status", seen["odom"].append)
        station.create_subscription("std_msgs/msg/String", "/statistics", seen["stats"].append)
        stops: list[bool] = []

        def e_stop(request: Any) -> Any:
            stops.append(bool(request.data))
            return get_type("std_srvs/srv/SetBool_Response")(success=True, message="stopped")

        r2d2.create_service("std_srvs/srv/SetBool", "/r2d2/e_stop", e_stop)
        hijack = c3po.create_publisher("geometry_msgs/msg/Twist", "/r2d2/cmd_vel", QoSProfile(depth=10))
        drive = station.create_publisher("geometry_msgs/msg/Twist", "/r2d2/cmd_vel", QoSProfile(depth=10))
        own = c3po.create_publisher("std_msgs/msg/String", "/c3po/status")
        stats = c3po.create_publisher("std_msgs/msg/String", "/statistics")
        assert wait_until(lambda: drive.matched_subscriptions > 0, 10.0)
        for _ in range(10):
            hijack.publish(twist(1.0))
            own.publish(get_type("std_msgs/msg/String")(data="c3po is fine"))
            stats.publish(get_type("std_msgs/msg/String")(data="counts"))
        assert wait_until(lambda: len(seen["odom"]) == 10 and len(seen["stats"]) == 10, 10.0), seen
        drive.publish(twist(0.3))
        assert wait_until(lambda: commands == [0.3], 5.0), commands  # the station's, never c3po's 1.0
        request = get_type("std_srvs/srv/SetBool_Request")
        with pytest.raises(ServiceError):  # c3po may not call r2d2's services
            c3po.create_client("std_srvs/srv/SetBool", "/r2d2/e_stop").call(request(data=False), timeout=2.0)
        response = station.create_client("std_srvs/srv/SetBool", "/r2d2/e_stop").call(request(data=True), timeout=10)
        assert response.success and stops == [True]
    finally:
        for ctx in contexts:
            ctx.close()


def test_a_ros2_peer_with_the_same_files_interoperates(secured_router: tuple[Path, int]) -> None:
    """rmw_zenoh opens its session from a host's ``zenoh.json5`` as it is (``ZENOH_SESSION_CONFIG_URI``). ROS 2 is not
    installable here, so a plain Zenoh session opened from that file stands in for it, speaking rmw_zenoh's keys,
    liveliness tokens and attachments (checked byte for byte in tests/middleware): it joins the secured router with
    c3po's certificate, fleetslam sees it in the graph and hears it, it hears the station, and the access control
    holds for it as for fleetslam's own nodes."""
    directory, _ = secured_router
    ros2 = zenoh.open(zenoh.Config.from_file(str(directory / "c3po" / "zenoh.json5")))
    station_context = _host(directory, "station")
    token: zenoh.LivelinessToken | None = None
    try:
        station = Node("viewer", context=station_context)
        heard: dict[str, list[str]] = {"/c3po/chatter": [], "/r2d2/chatter": []}
        for topic, messages in heard.items():
            station.create_subscription("std_msgs/msg/String", topic, lambda m, out=messages: out.append(m.data))
        zid = str(ros2.zid())
        token = ros2.liveliness().declare_token(
            f"@ros2_lv/0/{zid}/0/1/MP/%/%/ros2_talker/%c3po%chatter/std_msgs::msg::dds_::String_/{STRING_HASH}/"
            "::,7:,:,:,,"
        )

        def talkers() -> list[str]:  # what `ros2 topic info -v` lists
            return [p.node_fq_name for p in station.context.graph.publishers_info("/c3po/chatter")]

        assert wait_until(lambda: talkers() == ["/ros2_talker"], 10.0), talkers()
        to_ros2: list[bytes] = []
        ros2.declare_subscriber(f"0/c3po/note/std_msgs::msg::dds_::String_/{STRING_HASH}",
                                lambda s: to_ros2.append(s.payload.to_bytes()))  # fmt: skip
        note = station.create_publisher("std_msgs/msg/String", "/c3po/note")
        gid = bytes(range(16))
        for seq in range(1, 51):
            for ns in ("c3po", "r2d2"):  # its own namespace, and one it may not publish in
                ros2.put(f"0/{ns}/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}",
                         serialize(get_type("std_msgs/msg/String")(data=f"ros2 {seq}"), "std_msgs/msg/String"),
                         attachment=encode_attachment(seq, time.time_ns(), gid))  # fmt: skip
            note.publish(get_type("std_msgs/msg/String")(data="from the station"))
            if heard["/c3po/chatter"] and to_ros2:
                break
            time.sleep(0.1)
        assert wait_until(lambda: bool(heard["/c3po/chatter"]) and bool(to_ros2), 5.0), (heard, len(to_ros2))
        assert heard["/c3po/chatter"][0].startswith("ros2 ")
        assert to_ros2[0] == serialize(get_type("std_msgs/msg/String")(data="from the station"), "std_msgs/msg/String")
        time.sleep(0.5)
        assert heard["/r2d2/chatter"] == []  # c3po's certificate does not publish in r2d2's namespace
    finally:
        station_context.close()
        if token is not None:
            token.undeclare()
        ros2.close()
