"""`fleetslam map build | info | convert | compare | node`: occupancy octree maps in OctoMap's `.bt` / `.ot` files.

The work is :mod:`fleetslam.mapping.build` and :mod:`fleetslam.mapping.map_files`; this module parses and prints."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from fleetslam.errors import ConfigError


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", required=True)
    build = sub.add_parser(
        "build",
        help="integrate scans or RGB-D frames into an octree and write it (.bt or .ot)",
        description="Integrate laser scans, or the depth images of an RGB-D sequence at their camera poses, into "
        "an occupancy octree. RGB-D poses: --trajectory, a TUM file ('stamp tx ty tz qx qy qz qw' per line) of "
        "camera poses T_world_camera of the camera's optical frame (x right, y down, z forward), the convention "
        "of 'fleetslam slam run' trajectory.txt and of TUM and simulator groundtruth.txt; each frame takes the "
        "pose of the nearest stamp within --max-difference, frames without one are skipped. Without "
        "--trajectory: the sequence's ground truth, else the poses its frames carry (wheel odometry of a "
        "simulator export); in a recording these are ground_truth/odom and odom, each times the camera's mounting "
        "on tf_static. Free space is traced from the camera centre.",
    )
    build.add_argument(
        "input",
        type=Path,
        help="scans: OctoMap .graph, scan log (.log), x y z points (.xyz/.txt/.dat, .bz2); or an RGB-D sequence: "
        "a TUM folder, a simulator export, an .mcap file or a 'fleetslam record' folder",
    )
    build.add_argument("-o", "--output", type=Path, required=True, help="map file to write (.bt or .ot)")
    build.add_argument("--resolution", type=float, default=0.05, help="voxel edge in metres (default 0.05)")
    build.add_argument("--max-range", type=float, default=-1.0, help="cut longer rays here, metres (default: no limit)")
    build.add_argument(
        "--kind",
        default=None,
        help="input kind instead of guessing from the path: graph, log, xyz (scans) or tum, sim, mcap (RGB-D)",
    )
    rgbd = build.add_argument_group("RGB-D sequences")
    rgbd.add_argument(
        "--trajectory",
        type=Path,
        default=None,
        help="TUM file of camera poses T_world_camera (optical frame), e.g. slam run's trajectory.txt or a "
        "groundtruth.txt (default: the sequence's ground truth, else its frames' own poses)",
    )
    rgbd.add_argument(
        "--max-difference", type=float, default=0.02, help="largest frame-to-pose stamp difference, s (default 0.02)"
    )
    rgbd.add_argument("--every", type=int, default=1, help="use every N-th frame (default 1: all)")
    rgbd.add_argument("--pixel-step", type=int, default=4, help="use every K-th pixel of every K-th row (default 4)")
    rgbd.add_argument("--min-depth", type=float, default=0.3, help="ignore depth below this, m (default 0.3)")
    rgbd.add_argument("--max-depth", type=float, default=6.0, help="ignore depth beyond this, m (default 6)")
    build.add_argument("--origin", default=None, help="sensor position 'x,y,z' for point files (default 0,0,0)")
    build.add_argument("--no-progress", action="store_true", help="no progress bar")
    build.set_defaults(func=run_build)
    info = sub.add_parser("info", help="kind, resolution, node and leaf counts, bounds, memory of a map file")
    info.add_argument("file", type=Path)
    info.add_argument("--json", action="store_true", help="print JSON instead of text")
    info.set_defaults(func=run_info)
    convert = sub.add_parser("convert", help="convert between .bt and .ot (by the output suffix)")
    convert.add_argument("input", type=Path)
    convert.add_argument("output", type=Path)
    convert.set_defaults(func=run_convert)
    compare = sub.add_parser("compare", help="agreement of two maps' occupancy states, by volume")
    compare.add_argument("a", type=Path)
    compare.add_argument("b", type=Path)
    compare.add_argument("--json", action="store_true", help="print JSON instead of text")
    compare.set_defaults(func=run_compare)
    node = sub.add_parser("node", help="run the mapping node of an agent (keyframes + graph -> occupancy)")
    node.add_argument("--config", type=Path, default=None, help="YAML parameters of the node")
    node.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a parameter")
    node.set_defaults(func=run_node)


def _parse_origin(text: str | None) -> np.ndarray | None:
    if text is None:
        return None
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError as err:
        raise ConfigError(f"--origin: expected 'x,y,z', got {text!r}") from err
    if len(values) != 3:
        raise ConfigError(f"--origin: expected 3 numbers 'x,y,z', got {text!r}")
    return np.array(values)


def run_build(args: argparse.Namespace) -> int:
    from fleetslam.mapping.build import build_from_rgbd, build_from_scans
    from fleetslam.mapping.map_files import output_kind
    from fleetslam.mapping.scan_io import SEQUENCE_KINDS, input_kind

    output_kind(args.output)
    if not args.resolution > 0:
        raise ConfigError(f"--resolution must be > 0, got {args.resolution}")
    kind = input_kind(args.input, args.kind)
    if kind in SEQUENCE_KINDS:
        if args.origin is not None:
            raise ConfigError("--origin: RGB-D frames are seen from their camera poses; leave --origin out")
        built = build_from_rgbd(
            args.input, args.output, kind=kind, resolution=args.resolution, max_range=args.max_range,
            trajectory=args.trajectory, max_difference=args.max_difference, every=args.every,
            pixel_step=args.pixel_step, min_depth=args.min_depth, max_depth=args.max_depth,
            progress=not args.no_progress,
        )  # fmt: skip
        used = built.counts
        every = f" (--every {args.every})" if args.every > 1 else ""
        print(
            f"{args.output}: {used.used} of {used.frames} frames{every}, {used.points} points, {built.nodes} nodes "
            f"at {args.resolution} m"
        )
        if built.skipped is not None:
            print(built.skipped)
        return 0
    if args.trajectory is not None:
        raise ConfigError(
            f"--trajectory: {args.input} is a scan file ({kind}) with its own poses, not an RGB-D sequence"
        )
    scans = build_from_scans(
        args.input, args.output, kind=kind, resolution=args.resolution, max_range=args.max_range,
        origin=_parse_origin(args.origin), progress=not args.no_progress,
    )  # fmt: skip
    print(f"{args.output}: {scans.scans} scans, {scans.points} points, {scans.nodes} nodes at {args.resolution} m")
    return 0


def run_info(args: argparse.Namespace) -> int:
    from fleetslam.mapping.map_files import map_info

    info = map_info(args.file)
    if args.json:
        print(json.dumps(info))
        return 0
    width = max(len(k) for k in info)
    for key, value in info.items():
        print(f"{key.ljust(width)}  {value}")
    return 0


def run_convert(args: argparse.Namespace) -> int:
    from fleetslam.mapping.map_files import convert_map

    done = convert_map(args.input, args.output)
    print(f"{args.input} ({done.input_kind}) -> {args.output} ({done.output_kind}, {done.nodes} nodes)")
    return 0


def run_compare(args: argparse.Namespace) -> int:
    from fleetslam.mapping.map_files import map_compare

    result = map_compare(args.a, args.b)
    if args.json:
        print(json.dumps(result))
        return 0
    print(f"{result['a']} vs {result['b']} at {result['resolution']} m")
    for pair, volume in result["volume_m3"].items():
        print(f"  {pair:<20} {volume:.6g} m³")
    print(f"  agreement (known space)  {result['agreement']:.6f}")
    print(f"  occupied IoU             {result['occupied_iou']:.6f}")
    return 0


def run_node(args: argparse.Namespace) -> int:
    """The mapping node until Ctrl-C (namespace from FLEETSLAM_AGENT, or `--ros-args -r __ns:=/name`)."""
    from fleetslam.cli.common import run_adapter_node
    from fleetslam.mapping.node import MappingNode, MappingNodeConfig

    return run_adapter_node(args, "mapping", MappingNodeConfig, MappingNode)
