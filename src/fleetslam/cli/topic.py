"""`fleetslam topic list | info | echo | pub | hz | bw`, as ros2 topic does."""

from __future__ import annotations

import argparse
import contextlib
import threading
import time
from typing import Any

import yaml

from fleetslam.cli.common import cli_node, settle, to_yaml, wait_for_graph
from fleetslam.errors import ConfigError, MiddlewareError
from fleetslam.middleware import MessageInfo
from fleetslam.middleware.meters import BandwidthMeter, RateMeter, human_bytes
from fleetslam.middleware.names import expand_name
from fleetslam.msg.typesys import message_from_dict, message_to_dict


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", required=True)
    listing = sub.add_parser("list", help="list topics")
    listing.add_argument("-t", "--show-types", action="store_true", help="show types")
    listing.add_argument("--wait", type=float, default=1.0, help="seconds to wait for discovery")
    listing.set_defaults(func=run_list)

    info = sub.add_parser("info", help="type, publishers and subscribers of a topic")
    info.add_argument("topic")
    info.add_argument("-v", "--verbose", action="store_true", help="endpoints with GID and QoS")
    info.add_argument("--wait", type=float, default=1.0)
    info.set_defaults(func=run_info)

    echo = sub.add_parser("echo", help="print messages as YAML")
    echo.add_argument("topic")
    echo.add_argument("type", nargs="?", help="message type (default: from the graph or the samples)")
    echo.add_argument("--count", type=int, default=0, help="stop after N messages")
    echo.add_argument("--timeout", type=float, default=0.0, help="stop after S seconds (0: never)")
    echo.add_argument("--no-arr", action="store_true", help="do not print array contents")
    echo.set_defaults(func=run_echo)

    pub = sub.add_parser("pub", help="publish a message given as YAML")
    pub.add_argument("topic")
    pub.add_argument("type", help="message type, e.g. geometry_msgs/msg/Twist")
    pub.add_argument("values", nargs="?", default="{}", help="YAML, e.g. '{linear: {x: 0.2}}'")
    pub.add_argument("--rate", type=float, default=1.0, help="publishing rate (Hz)")
    pub.add_argument("--count", type=int, default=0, help="publish N times then exit (0: until Ctrl-C)")
    pub.add_argument("--once", action="store_true", help="same as --count 1")
    pub.set_defaults(func=run_pub)

    hz = sub.add_parser("hz", help="message rate")
    hz.add_argument("topic")
    hz.add_argument("--window", type=int, default=100)
    hz.add_argument("--duration", type=float, default=0.0, help="stop after S seconds (0: never)")
    hz.set_defaults(func=run_hz)

    bw = sub.add_parser("bw", help="bandwidth")
    bw.add_argument("topic")
    bw.add_argument("--window", type=int, default=100)
    bw.add_argument("--duration", type=float, default=0.0, help="stop after S seconds (0: never)")
    bw.set_defaults(func=run_bw)


def _fq(topic: str) -> str:
    return expand_name(topic, namespace="/", node_name="_")


def run_list(args: argparse.Namespace) -> int:
    with cli_node("topic") as node:
        wait_for_graph(node, lambda: False, args.wait)
        for name, types in node.context.graph.topic_names_and_types().items():
            print(f"{name} [{', '.join(types)}]" if args.show_types else name)
    return 0


def run_info(args: argparse.Namespace) -> int:
    topic = _fq(args.topic)
    with cli_node("topic") as node:
        graph = node.context.graph
        wait_for_graph(node, lambda: topic in graph.topic_names_and_types(), args.wait)
        types = graph.topic_names_and_types().get(topic)
        if not types:
            raise MiddlewareError(f"topic '{topic}' not found; see `fleetslam topic list`")
        pubs, subs = graph.publishers_info(topic), graph.subscriptions_info(topic)
        print(f"Type: {', '.join(types)}")
        print(f"Publisher count: {len(pubs)}")
        print(f"Subscription count: {len(subs)}")
        if args.verbose:
            for title, infos in (("Publishers", pubs), ("Subscriptions", subs)):
                print(f"\n{title}:")
                for info in infos:
                    print(f"  Node: {info.node_fq_name}")
                    print(f"  Type: {info.topic_type}  Hash: {info.type_hash}")
                    print(f"  GID: {info.gid.hex('.')}")
                    print(f"  QoS: {info.qos}\n")
    return 0


def _strip_arrays(data: Any) -> Any:
    if isinstance(data, dict):
        return {k: _strip_arrays(v) for k, v in data.items()}
    if isinstance(data, list):
        return f"<array of {len(data)}>" if len(data) > 16 else [_strip_arrays(v) for v in data]
    return data


def _topic_type(node: Any, topic: str, given: str | None) -> str | None:
    if given:
        return given
    graph = node.context.graph
    wait_for_graph(node, lambda: bool(graph.topic_names_and_types().get(topic)), 1.0)
    types = graph.topic_names_and_types().get(topic)
    return types[0] if types else None


def run_echo(args: argparse.Namespace) -> int:
    topic = _fq(args.topic)
    done = threading.Event()
    count = 0
    with cli_node("echo") as node:
        type_name = _topic_type(node, topic, args.type)

        def on_message(msg: Any, info: MessageInfo) -> None:
            nonlocal count
            if done.is_set():
                return
            data = message_to_dict(msg)
            print(to_yaml(_strip_arrays(data) if args.no_arr else data), end="---\n", flush=True)
            count += 1
            if args.count and count >= args.count:
                done.set()

        node.create_subscription(type_name, topic, on_message)
        with contextlib.suppress(KeyboardInterrupt):
            done.wait(args.timeout if args.timeout > 0 else None)
    if args.count and count < args.count:
        print(f"fleetslam topic echo: received {count} of {args.count} messages on {topic}", flush=True)
        return 1
    return 0


def run_pub(args: argparse.Namespace) -> int:
    topic = _fq(args.topic)
    try:
        values = yaml.safe_load(args.values)
    except yaml.YAMLError as err:
        raise ConfigError(f"message values {args.values!r} are not valid YAML: {err}") from err
    if values is not None and not isinstance(values, dict):
        raise ConfigError(f"message values {args.values!r} must be a YAML mapping")
    msg = message_from_dict(args.type, values)
    count = 1 if args.once else args.count
    with cli_node("pub") as node:
        publisher = node.create_publisher(args.type, topic)
        graph = node.context.graph
        wait_for_graph(node, lambda: bool(graph.subscriptions_info(topic)), 1.0)
        settle(0.2)
        sent = 0
        period = 1.0 / args.rate if args.rate > 0 else 1.0
        next_time = time.monotonic()
        try:
            while not count or sent < count:
                publisher.publish(msg)
                sent += 1
                print(f"publishing #{sent}: {message_to_dict(msg)}", flush=True)
                next_time += period
                if not count or sent < count:
                    time.sleep(max(0.0, next_time - time.monotonic()))
        except KeyboardInterrupt:
            pass
        settle(0.2)
    return 0


def _measure(args: argparse.Namespace, report: Any) -> int:
    topic = _fq(args.topic)
    with cli_node("meter") as node:
        node.create_subscription(None, topic, report.add_sample, raw=True)
        start = time.monotonic()
        try:
            while not args.duration or time.monotonic() - start < args.duration:
                time.sleep(min(1.0, args.duration) if args.duration else 1.0)
                report.print()
        except KeyboardInterrupt:
            pass
    return 0


class _Hz:
    def __init__(self, window: int) -> None:
        self.meter = RateMeter(window)

    def add_sample(self, data: bytes, info: MessageInfo) -> None:
        self.meter.add(info.received_timestamp_ns / 1e9)

    def print(self) -> None:
        r = self.meter.report()
        if r is None:
            print("no new messages", flush=True)
            return
        print(
            f"average rate: {r.rate_hz:.3f}\n\tmin: {r.min_period_s:.3f}s max: {r.max_period_s:.3f}s "
            f"std dev: {r.std_period_s:.5f}s window: {r.window}",
            flush=True,
        )


class _Bw:
    def __init__(self, window: int) -> None:
        self.meter = BandwidthMeter(window)

    def add_sample(self, data: bytes, info: MessageInfo) -> None:
        self.meter.add(info.received_timestamp_ns / 1e9, info.size)

    def print(self) -> None:
        r = self.meter.report(time.time())
        if r is None:
            print("no new messages", flush=True)
            return
        print(
            f"{human_bytes(r.bytes_per_s)}/s from {r.window} messages\n\tMessage size mean: {human_bytes(r.mean_size)} "
            f"min: {human_bytes(r.min_size)} max: {human_bytes(r.max_size)}",
            flush=True,
        )


def run_hz(args: argparse.Namespace) -> int:
    return _measure(args, _Hz(args.window))


def run_bw(args: argparse.Namespace) -> int:
    return _measure(args, _Bw(args.window))
