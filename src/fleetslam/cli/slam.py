"""``fleetslam slam run DATASET --out DIR``: the offline RGB-D graph SLAM."""

from __future__ import annotations

import argparse


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="slam_command", required=True)
    run = sub.add_parser("run", help="run the SLAM over a dataset (TUM folder, simulator export, MCAP)")
    run.add_argument("dataset", help="dataset path")
    run.add_argument("--out", required=True, help="results folder")
    run.add_argument("--kind", choices=["tum", "sim", "mcap"], help="dataset kind (guessed from the path)")
    run.add_argument("--config", help="YAML configuration file")
    run.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a config key")
    run.add_argument("--max-frames", type=int, help="stop after N frames")
    run.add_argument("--no-progress", action="store_true", help="no progress bar")
    run.set_defaults(func=_run)
    node = sub.add_parser("node", help="run the SLAM node of an agent on its camera topics")
    node.add_argument("--config", help="YAML parameters (SlamNodeConfig)")
    node.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a parameter")
    node.set_defaults(func=_node)


def _run(args: argparse.Namespace) -> int:
    from fleetslam.config import load_config
    from fleetslam.datasets import open_source
    from fleetslam.slam.config import SlamConfig
    from fleetslam.slam.pipeline import run_offline

    config = load_config(SlamConfig, args.config, overrides=args.set, env_prefix="slam")
    source = open_source(args.dataset, args.kind)
    result = run_offline(source, config, args.out, max_frames=args.max_frames, show_progress=not args.no_progress)
    summary = result.stats["summary"]
    print(
        f"{summary['frames']} frames, {summary['keyframes']} keyframes, loops {summary['loops_accepted']} "
        f"accepted / {summary['loops_rejected']} rejected, odometry median {summary['odometry_ms_median']:.1f} ms"
        f" -> {args.out}"
    )
    return 0


def _node(args: argparse.Namespace) -> int:
    """The SLAM node until Ctrl-C (namespace from FLEETSLAM_AGENT, or `--ros-args -r __ns:=/name`)."""
    from fleetslam.cli.common import run_adapter_node
    from fleetslam.slam.node import SlamNode, SlamNodeConfig

    return run_adapter_node(args, "slam", SlamNodeConfig, SlamNode)
