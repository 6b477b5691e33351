import pytest

from fleetslam.errors import ConfigError, MiddlewareError
from fleetslam.middleware.names import (
    NameContext,
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


def test_name_context() -> None:
    context = NameContext(node_name="slam", namespace="c3po", remaps={"odom": "/c3po/wheel/odom"})
    assert context.namespace == "/c3po" and context.fq_node_name == "/c3po/slam"
    assert context.resolve("odom") == "/c3po/wheel/odom"
    assert context.resolve("~/graph") == "/c3po/slam/graph"
    assert NameContext(node_name="n").resolve("x") == "/x"
    with pytest.raises(MiddlewareError, match="node name '2d'"):
        NameContext(node_name="2d")


@pytest.mark.parametrize(
    ("namespace", "name", "expected"),
    [("/c3po", "{node}/debug", "/c3po/slam/debug"), ("/c3po", "/{ns}/x", "/c3po/x"), ("/", "{ns}/x", "/x"),
     ("/c3po", "{namespace}/{node}", "/c3po/slam")],
)  # fmt: skip
def test_substitutions(namespace: str, name: str, expected: str) -> None:
    assert expand_name(name, namespace=namespace, node_name="slam") == expected


@pytest.mark.parametrize(("bad", "reason"), [("{robot}/x", "unknown substitution"), ("a{/b", "unbalanced")])
def test_bad_substitutions(bad: str, reason: str) -> None:
    with pytest.raises(MiddlewareError, match=reason):
        expand_name(bad, namespace="/", node_name="n")


@pytest.mark.parametrize(
    ("bad", "reason"),
    [("a//b", "empty token"), ("/a/", "must not end"), ("9lives", "not start with a digit"), ("a b", "token 'a b'"),
     ("~x", "'~' must be followed by '/'"), ("", "empty name"), ("a/~/b", "token '~'")],
)  # fmt: skip
def test_error_messages_name_the_rule(bad: str, reason: str) -> None:
    with pytest.raises(MiddlewareError, match=reason):
        resolve_name(bad, namespace="/c3po", node_name="slam")


def test_node_specific_remaps_and_private_sources() -> None:
    remaps = {"teleop:cmd_vel": "/joy/cmd_vel", "~/out": "/debug/out"}
    assert resolve_name("cmd_vel", namespace="/", node_name="teleop", remaps=remaps) == "/joy/cmd_vel"
    assert resolve_name("cmd_vel", namespace="/", node_name="base", remaps=remaps) == "/cmd_vel"
    assert resolve_name("~/out", namespace="/a", node_name="n", remaps=remaps) == "/debug/out"
    # Node name/namespace rules never remap a topic.
    assert resolve_name("x", namespace="/", node_name="n", remaps={"__ns": "/y"}) == "/x"


def test_ros_args_validation_and_compatibility_flags() -> None:
    args = parse_ros_args(
        ["--ros-args", "--log-level", "debug", "--enable-rosout-logs", "-e", "/", "--remap", "n:a:=b"]
    )
    assert (args.log_level, args.enclave, args.remaps) == ("debug", "/", {"n:a": "b"})
    assert parse_ros_args(["-r", "a:=b"]).remaining == ["-r", "a:=b"]  # outside --ros-args: not ours
    for bad, reason in [
        (["--ros-args", "-r", "a:=b c"], "token 'b c'"),
        (["--ros-args", "-r", "__ns:=/9x"], "namespace"),
        (["--ros-args", "-r", "__node:=a/b"], "node name"),
        (["--ros-args", "--bogus"], "unknown argument '--bogus'"),
        (["--ros-args", "-r"], "needs a value"),
        (["--ros-args", "-r", "talker:__ns:=/x"], "node-specific '__ns'"),
    ]:
        with pytest.raises(ConfigError, match=reason):
            parse_ros_args(bad)


def test_environment_edge_cases() -> None:
    assert namespace_from_env({"FLEETSLAM_AGENT": "/r2d2"}) == "/r2d2"
    assert namespace_from_env({"FLEETSLAM_AGENT": "  "}) == "/"
    assert domain_id_from_env({}) == 0
    for bad in ("-1", "1.5", "\u0663"):  # the last one is an Arabic-Indic digit three
        with pytest.raises(ConfigError, match="ROS_DOMAIN_ID"):
            domain_id_from_env({"ROS_DOMAIN_ID": bad})
    assert agent_of("/c3po") == "" and agent_of("/c3po/camera/rgb") == "c3po"
