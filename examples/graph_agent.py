"""A stand-in SLAM agent for the multi-host example: publishes its keyframe graph, listens to its peers'.

Configured only by the environment (FLEETSLAM_ROUTER, FLEETSLAM_AGENT, FLEETSLAM_LISTEN), as the seed's
agents were by ROS_MASTER_URI / ROS_IP / LSD_SLAM_NODE. Usage: python examples/graph_agent.py --peers r2d2
"""

from __future__ import annotations

import argparse
import math
import time

from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.middleware.typesys import header, message_from_dict


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--peers", nargs="*", default=[], help="agents whose graph to subscribe to")
    parser.add_argument("--rate", type=float, default=5.0, help="graph publishing rate (Hz)")
    parser.add_argument("--duration", type=float, default=0.0, help="seconds to run (0: until Ctrl-C)")
    args = parser.parse_args()

    with Context() as ctx, Node("slam", context=ctx) as node:
        agent = ctx.namespace.strip("/")
        received = {peer: 0 for peer in args.peers}

        def on_peer_graph(msg: object) -> None:
            received[msg.agent] = received.get(msg.agent, 0) + 1  # type: ignore[attr-defined]

        for peer in args.peers:
            node.create_subscription("fleetslam_msgs/msg/KeyframeGraph", f"/{peer}/graph", on_peer_graph)
        publisher = node.create_publisher("fleetslam_msgs/msg/KeyframeGraph", "graph", QoSProfile(depth=5))
        start = time.monotonic()
        count = 0
        while not args.duration or time.monotonic() - start < args.duration:
            count += 1
            first = max(0, count - 50)
            graph = message_from_dict(
                "fleetslam_msgs/msg/KeyframeGraph",
                {
                    "agent": agent,
                    "keyframe_ids": list(range(first, count)),
                    "poses": [{"position": {"x": math.cos(i / 5), "y": math.sin(i / 5)}} for i in range(first, count)],
                },
            )
            graph.header = header("map", node.now_ns())
            publisher.publish(graph)
            if count % int(args.rate) == 0:
                print(f"{agent}: published {count} graphs, received {received}", flush=True)
            time.sleep(1.0 / args.rate)


if __name__ == "__main__":
    main()
