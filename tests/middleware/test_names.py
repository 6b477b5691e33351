import pytest

from fleetslam.errors import ConfigError, MiddlewareError
from fleetslam.middleware.names import (
    agent_of,
    domain_id_from_env,
    expand_name,
    namespace_from_env,
    parse_ros_args,
    resolve_name,
)


@pytest.mark.parametrize(
    ("name", "expected"),
    [("odom", "/c3po/odom"), ("/statistics", "/statistics"), ("~/debug", "/c3po/slam/debug"), ("~", "/c3po/slam"),
     ("camera/rgb/image_raw", "/c3po/camera/rgb/image_raw")],
)  # fmt: skip
def test_expansion(name: str, expected: str) -> None:
    assert expand_name(name, namespace="/c3po", node_name="slam") == expected


def test_root_namespace() -> None:
    assert expand_name("odom", namespace="/", node_name="n") == "/odom"


@pytest.mark.parametrize("bad", ["a//b", "a/", "1abc", "a-b", "~x", ""])
def test_invalid_names(bad: str) -> None:
    with pytest.raises(MiddlewareError):
        expand_name(bad, namespace="/c3po", node_name="slam")


def test_remaps_are_expanded_on_both_sides() -> None:
    remaps = {"odom": "wheel_odom", "/c3po/cmd_vel": "/teleop/cmd_vel"}
    assert resolve_name("odom", namespace="/c3po", node_name="n", remaps=remaps) == "/c3po/wheel_odom"
    assert resolve_name("cmd_vel", namespace="/c3po", node_name="n", remaps=remaps) == "/teleop/cmd_vel"
    assert resolve_name("tf", namespace="/c3po", node_name="n", remaps=remaps) == "/c3po/tf"


def test_parse_ros_args() -> None:
    args = parse_ros_args(
        ["--rate", "5", "--ros-args", "-r", "odom:=/x", "-r", "__ns:=/r2d2", "-r", "__node:=base", "-p", "a.b:=3",
         "--params-file", "p.yaml", "--", "tail"]
    )  # fmt: skip
    assert args.remaps == {"odom": "/x"}
    assert args.namespace == "/r2d2" and args.node_name == "base"
    assert args.parameters == {"a.b": "3"} and args.params_files == ["p.yaml"]
    assert args.remaining == ["--rate", "5", "tail"]
    with pytest.raises(ConfigError, match="expected FROM:=TO"):
        parse_ros_args(["--ros-args", "-r", "odom"])


def test_environment() -> None:
    assert namespace_from_env({"FLEETSLAM_AGENT": "c3po"}) == "/c3po"
    assert namespace_from_env({}) == "/"
    assert domain_id_from_env({"ROS_DOMAIN_ID": "7"}) == 7
    with pytest.raises(ConfigError, match="ROS_DOMAIN_ID='x'"):
        domain_id_from_env({"ROS_DOMAIN_ID": "x"})
    with pytest.raises(ConfigError, match="FLEETSLAM_AGENT='9bad'"):
        namespace_from_env({"FLEETSLAM_AGENT": "9bad"})


def test_agent_of() -> None:
    assert agent_of("/c3po/graph") == "c3po"
    assert agent_of("/statistics") == ""
