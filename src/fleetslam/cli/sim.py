"""`fleetslam sim`: export TUM RGB-D datasets from the simulated plant, or run the sim node."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import TYPE_CHECKING

from fleetslam.errors import ConfigError

if TYPE_CHECKING:
    from fleetslam.sim.config import SimConfig

log = logging.getLogger(__name__)


def parse_resolution(text: str) -> tuple[int, int]:
    """``"640x480"`` → (640, 480)."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError as err:
        raise ConfigError(f"--resolution: expected WIDTHxHEIGHT such as 640x480, got {text!r}") from err
    if w <= 0 or h <= 0:
        raise ConfigError(f"--resolution: width and height must be > 0, got {text!r}")
    return w, h


def _load_sim_config(args: argparse.Namespace) -> SimConfig:
    from fleetslam.config import load_config
    from fleetslam.sim.config import SimConfig

    return load_config(SimConfig, args.config, overrides=args.set or [])


def _add_common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", default=None, help="simulator YAML configuration (SimConfig)")
    parser.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a configuration key")
    parser.add_argument("--resolution", default=None, help="camera resolution WIDTHxHEIGHT (default: config)")


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="sim_command", required=True)
    export = sub.add_parser("export-tum", help="drive a route and write a TUM RGB-D folder")
    export.add_argument("out", help="output folder")
    export.add_argument("--route", default="loop", help="autopilot route (loop, survey, square, line, ...)")
    export.add_argument("--frames", type=int, default=None, help="number of frames (default: until route done)")
    export.add_argument("--robot", default="c3po", help="robot to drive (its start pose comes from the config)")
    export.add_argument("--camera-hz", type=float, default=30.0, help="camera rate in simulated time")
    export.add_argument("--max-speed", type=float, default=0.6, help="autopilot cruise speed, m/s")
    export.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    _add_common(export)
    export.set_defaults(func=run_export)
    try:
        from fleetslam.sim import node as _node  # noqa: F401 - only offer `run` where the node exists
    except ImportError:
        return
    run_parser = sub.add_parser("run", help="run the plant as a node publishing cameras, ground truth, /clock")
    run_parser.add_argument("--robots", default=None, help="comma-separated robots (default: all configured)")
    run_parser.add_argument("--camera-hz", type=float, default=10.0, help="camera rate in simulated time")
    run_parser.add_argument(
        "--rate", type=float, default=1.0, help="simulated seconds per wall second (0: as fast as possible)"
    )
    run_parser.add_argument("--autopilot", default=None, help="drive every robot along this route")
    run_parser.add_argument(
        "--laps", action="store_true", help="drive a closed autopilot route lap after lap instead of once"
    )
    run_parser.add_argument("--duration", type=float, default=None, help="stop after this much simulated time")
    run_parser.add_argument(
        "--ground-truth", default=None, metavar="DIR",
        help="also write each robot's ground truth (base_link in world, TUM) to DIR/<robot>.txt",
    )  # fmt: skip
    _add_common(run_parser)
    run_parser.set_defaults(func=run_node)


def run_export(args: argparse.Namespace) -> int:
    from fleetslam.sim.export import export_tum

    config = _load_sim_config(args)
    width, height = parse_resolution(args.resolution) if args.resolution else (None, None)
    result = export_tum(
        args.out,
        config=config,
        robot=args.robot,
        route=args.route,
        frames=args.frames,
        width=width,
        height=height,
        camera_hz=args.camera_hz,
        max_speed=args.max_speed,
        progress=not args.no_progress,
    )
    done = "completed" if result.route_completed else "not completed"
    print(f"{result.path}: {result.frames} frames, {result.duration:.1f} s simulated, route {args.route} {done}")
    return 0


def run_node(args: argparse.Namespace) -> int:
    from fleetslam.sim.node import run_sim_node

    config = _load_sim_config(args)
    width, height = parse_resolution(args.resolution) if args.resolution else (None, None)
    robots = [r.strip() for r in args.robots.split(",") if r.strip()] if args.robots else None
    return run_sim_node(
        config,
        robots=robots,
        camera_hz=args.camera_hz,
        width=width,
        height=height,
        rate=args.rate,
        autopilot=args.autopilot,
        laps=args.laps,
        duration=args.duration,
        ground_truth_dir=Path(args.ground_truth) if args.ground_truth else None,
    )
