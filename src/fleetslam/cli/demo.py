"""`fleetslam demo`: run the whole fleet on this machine."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from fleetslam.launch.demo import run_demo


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robots", default="c3po,r2d2", help="comma-separated agent names")
    parser.add_argument("--headless", action="store_true", help="no operator console")
    parser.add_argument("--duration", type=float, default=None, help="stop after S seconds (default: Ctrl-C)")
    parser.add_argument("--out", type=Path, default=None, help="results folder (default: results/demo-<time>)")
    parser.add_argument("--port", type=int, default=8080, help="console port")
    parser.add_argument("--router-port", type=int, default=7447, help="router port on 127.0.0.1")
    parser.add_argument(
        "--mode", choices=["sim", "synthetic"], default="sim",
        help="sim: simulated robots with SLAM and maps; synthetic: agents exchanging graphs only",
    )  # fmt: skip
    parser.add_argument("--resolution", default="320x240", help="simulated camera resolution WxH")
    parser.add_argument("--camera-hz", type=float, default=10.0, help="simulated camera rate (simulated time)")
    parser.add_argument(
        "--route", default="loop", help="autopilot route every robot patrols, lap after lap (fleetslam robot routes)"
    )
    parser.add_argument(
        "--secure", action="store_true",
        help="make a keystore in the results folder; every process joins by mutual TLS under access control",
    )  # fmt: skip
    parser.add_argument(
        "--known-starts", action="store_true",
        help="robots start apart and the fleet map is given their start poses (default: they share a patrol and "
        "their maps are merged by inter-agent loop closures, no start poses given)",
    )  # fmt: skip
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    robots = [r.strip() for r in args.robots.split(",") if r.strip()]
    out = args.out or Path("results") / time.strftime("demo-%Y%m%d-%H%M%S")
    result = run_demo(
        robots=robots, duration_s=args.duration, out_dir=out, port=args.port, router_port=args.router_port,
        headless=args.headless, mode=args.mode, resolution=args.resolution, camera_hz=args.camera_hz,
        route=args.route, secure=args.secure, known_starts=args.known_starts,
    )  # fmt: skip
    for robot, value in sorted(result.ate.items()):
        live = f"; live poses {result.ate_live[robot]:.3f} m" if robot in result.ate_live else ""
        print(f"ATE {robot}: {value:.3f} m (final SLAM trajectory vs ground truth, aligned{live})")
    print(f"results in {result.out_dir}: report.md, report.html, statistics.json, maps/, trajectories/, plots")
    return 0
