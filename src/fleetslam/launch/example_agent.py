"""A synthetic agent for trying the fleet without a robot: publishes what a SLAM agent publishes, from a known path.

It is what the seed's experiments ran across machines: an agent under its own namespace (from
``FLEETSLAM_AGENT``) that publishes its keyframe graph on ``graph`` and subscribes to its peers' graphs. To give
the operator console something to draw, it also publishes ``odom`` (a robot driving a circle, exact kinematics)
and ``map/occupied`` (voxels of a corridor around the path, revealed as the robot passes). No sensor data is
involved: this is a network exercise, not a mapping result.

    FLEETSLAM_AGENT=c3po python -m fleetslam.launch.example_agent --peers r2d2
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import time
from typing import Any

import numpy as np

from fleetslam.middleware import Context, Node
from fleetslam.msg.conversions import odometry_msg, planar_pose_msg, pointcloud2_msg
from fleetslam.msg.typesys import header, message_from_dict
from fleetslam.topics import GRAPH, MAP_OCCUPIED, ODOM

log = logging.getLogger(__name__)


def circle_pose(t: float, *, radius: float, speed: float, center: tuple[float, float]) -> tuple[float, float, float]:
    """(x, y, yaw) of a robot driving a circle counter-clockwise at ``speed`` m/s."""
    angle = speed * t / radius
    return center[0] + radius * math.cos(angle), center[1] + radius * math.sin(angle), angle + math.pi / 2


def corridor_voxels(
    xs: np.ndarray, ys: np.ndarray, *, half_width: float, resolution: float, height: float = 1.0
) -> np.ndarray:
    """Voxel centres of two walls along a path (left and right, ``height`` tall)."""
    heading = np.arctan2(np.gradient(ys), np.gradient(xs))
    normal = np.stack([-np.sin(heading), np.cos(heading)], axis=1)
    walls = []
    for side in (-1.0, 1.0):
        wx = xs + side * half_width * normal[:, 0]
        wy = ys + side * half_width * normal[:, 1]
        for z in np.arange(resolution / 2, height, resolution):
            walls.append(np.stack([wx, wy, np.full_like(wx, z)], axis=1))
    points = np.concatenate(walls)
    keys = np.unique(np.floor(points / resolution).astype(np.int64), axis=0)
    return (keys + 0.5) * resolution


def run_agent(
    peers: list[str], *, rate_hz: float = 5.0, duration_s: float = 0.0, radius: float = 3.0,
    center: tuple[float, float] = (0.0, 0.0), speed: float = 0.4,
) -> dict[str, int]:  # fmt: skip
    """Run until ``duration_s`` passes (0: until Ctrl-C); returns the graphs received per peer."""
    with Context() as ctx, Node("slam", context=ctx) as node:
        agent = ctx.namespace.strip("/") or "agent"
        received = {peer: 0 for peer in peers}

        def on_peer_graph(msg: Any) -> None:
            received[msg.agent] = received.get(msg.agent, 0) + 1

        for peer in peers:
            node.create_subscription(GRAPH.type, GRAPH.of(peer), on_peer_graph, GRAPH.qos())
        graph_pub, odom_pub, map_pub = (
            node.create_publisher(topic.type, topic.name, topic.qos()) for topic in (GRAPH, ODOM, MAP_OCCUPIED)
        )
        start = time.monotonic()
        keyframes: list[tuple[float, float, float]] = []
        tick = 0
        while not duration_s or time.monotonic() - start < duration_s:
            t = time.monotonic() - start
            x, y, yaw = circle_pose(t, radius=radius, speed=speed, center=center)
            now = node.now_ns()
            odom = odometry_msg(
                planar_pose_msg(x, y, yaw), frame_id="odom", child_frame_id="base_link", stamp_ns=now,
                linear=(speed, 0.0, 0.0), angular=(0.0, 0.0, speed / radius),
            )  # fmt: skip
            odom_pub.publish(odom)
            if not keyframes or math.hypot(keyframes[-1][0] - x, keyframes[-1][1] - y) > 0.5:
                keyframes.append((x, y, yaw))
            graph = message_from_dict(
                "fleetslam_msgs/msg/KeyframeGraph",
                {"agent": agent, "keyframe_ids": list(range(len(keyframes))),
                 "poses": [{"position": {"x": kx, "y": ky, "z": 0.5},
                            "orientation": {"z": math.sin(kyaw / 2), "w": math.cos(kyaw / 2)}}
                           for kx, ky, kyaw in keyframes]},
            )  # fmt: skip
            graph.header = header("map", now)
            graph_pub.publish(graph)
            if tick % max(1, int(rate_hz)) == 0 and len(keyframes) > 1:
                path = np.array([(kx, ky) for kx, ky, _ in keyframes])
                map_pub.publish(
                    pointcloud2_msg(
                        corridor_voxels(path[:, 0], path[:, 1], half_width=1.0, resolution=0.1),
                        frame_id="map",
                        stamp_ns=now,
                    )
                )
                log.info("%s: %d keyframes, received %s", agent, len(keyframes), received)
            tick += 1
            time.sleep(1.0 / rate_hz)
        return received


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--peers", nargs="*", default=[], help="agents whose graph to subscribe to")
    parser.add_argument("--rate", type=float, default=5.0, help="publishing rate (Hz)")
    parser.add_argument("--duration", type=float, default=0.0, help="seconds to run (0: until Ctrl-C)")
    parser.add_argument("--radius", type=float, default=3.0, help="radius of the driven circle (m)")
    parser.add_argument("--center", type=float, nargs=2, default=(0.0, 0.0), help="centre of the circle")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s", datefmt="%H:%M:%S")
    with contextlib.suppress(KeyboardInterrupt):
        run_agent(args.peers, rate_hz=args.rate, duration_s=args.duration, radius=args.radius,
                  center=tuple(args.center))  # fmt: skip


if __name__ == "__main__":
    main()
