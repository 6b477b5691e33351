"""`fleetslam map build | info | convert | compare`: occupancy octree maps in OctoMap's `.bt` / `.ot` files."""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from fleetslam.errors import ConfigError, MapFileError

if TYPE_CHECKING:
    from fleetslam.mapping.octree import OccupancyOctree

log = logging.getLogger(__name__)


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


def _output_kind(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in (".bt", ".ot"):
        raise ConfigError(f"{path}: the output must end in .bt or .ot, not '{suffix}'")
    return suffix[1:]


def run_build(args: argparse.Namespace) -> int:
    from fleetslam.mapping.scan_io import SEQUENCE_KINDS, input_kind

    output_kind = _output_kind(args.output)
    if not args.resolution > 0:
        raise ConfigError(f"--resolution must be > 0, got {args.resolution}")
    kind = input_kind(args.input, args.kind)
    if kind in SEQUENCE_KINDS:
        if args.origin is not None:
            raise ConfigError("--origin: RGB-D frames are seen from their camera poses; leave --origin out")
        return _build_from_rgbd(args, kind, output_kind)
    if args.trajectory is not None:
        raise ConfigError(
            f"--trajectory: {args.input} is a scan file ({kind}) with its own poses, not an RGB-D sequence"
        )
    return _build_from_scans(args, kind, output_kind)


def _write_tree(tree: OccupancyOctree, path: Path, output_kind: str) -> int:
    """Write the map; the number of nodes in the file (a .bt's max-likelihood tree prunes further)."""
    return tree.write_binary(path) if output_kind == "bt" else tree.write(path)


def _build_from_scans(args: argparse.Namespace, kind: str, output_kind: str) -> int:
    from tqdm import tqdm

    from fleetslam.mapping.octree import OccupancyOctree
    from fleetslam.mapping.scan_io import load_scans

    scans = load_scans(args.input, kind=kind, origin=_parse_origin(args.origin))
    tree = OccupancyOctree(args.resolution)
    total = sum(len(scan.points) for scan in scans)
    with tqdm(total=total, unit="pt", unit_scale=True, disable=args.no_progress, desc="integrating") as bar:
        for scan in scans:
            tree.insert_point_cloud(scan.world_points(), scan.origin, max_range=args.max_range)
            bar.update(len(scan.points))
    written = _write_tree(tree, args.output, output_kind)
    print(f"{args.output}: {len(scans)} scans, {total} points, {written} nodes at {args.resolution} m")
    return 0


def _build_from_rgbd(args: argparse.Namespace, kind: str, output_kind: str) -> int:
    from tqdm import tqdm

    from fleetslam.mapping.octree import OccupancyOctree
    from fleetslam.mapping.rgbd_scans import open_rgbd_scans

    scans = open_rgbd_scans(
        args.input,
        kind=kind,
        trajectory=args.trajectory,
        max_difference=args.max_difference,
        every=args.every,
        pixel_step=args.pixel_step,
        min_depth=args.min_depth,
        max_depth=args.max_depth,
    )
    tree = OccupancyOctree(args.resolution)
    with tqdm(total=len(scans), unit="frame", disable=args.no_progress, desc="integrating") as bar:
        for scan in scans:
            tree.insert_point_cloud(scan.world_points(), scan.origin, max_range=args.max_range)
            bar.update(scans.counts.frames - bar.n)
        bar.update(scans.counts.frames - bar.n)
    written = _write_tree(tree, args.output, output_kind)
    used = scans.counts
    every = f" (--every {args.every})" if args.every > 1 else ""
    print(
        f"{args.output}: {used.used} of {used.frames} frames{every}, {used.points} points, {written} nodes "
        f"at {args.resolution} m"
    )
    skipped = scans.skipped_summary()
    if skipped is not None:
        print(skipped)
    return 0


def map_info(path: Path) -> dict[str, Any]:
    """What `fleetslam map info` prints, as a dict."""
    from fleetslam.mapping.keys import TREE_DEPTH, TREE_MAX_VAL
    from fleetslam.mapping.octomap_io import read_octree_file

    tree = read_octree_file(path)
    leaves = tree.leaves
    occupied = int(np.count_nonzero(leaves.log_odds >= 0.0))
    info: dict[str, Any] = {
        "file": str(path),
        "kind": tree.kind,
        "tree_type": tree.tree_id,
        "resolution": tree.resolution,
        "nodes": tree.num_nodes,
        "leaves": len(leaves),
        "occupied_leaves": occupied,
        "free_leaves": len(leaves) - occupied,
    }
    if len(leaves):
        size = np.power(2.0, TREE_DEPTH - leaves.depths.astype(np.float64))[:, None]
        lo = (leaves.keys.astype(np.float64) - TREE_MAX_VAL) * tree.resolution
        volume = size[:, 0] ** 3 * tree.resolution**3
        info["bbox_min"] = [round(float(v), 6) for v in lo.min(axis=0)]
        info["bbox_max"] = [round(float(v), 6) for v in (lo + size * tree.resolution).max(axis=0)]
        info["occupied_volume_m3"] = float(volume[leaves.log_odds >= 0.0].sum())
        info["free_volume_m3"] = float(volume[leaves.log_odds < 0.0].sum())
    inner = tree.num_nodes - len(leaves)
    # OctoMap's OcTree::memoryUsage(): the tree object, 16 bytes per node, 8 child pointers per inner node.
    info["octomap_memory_bytes"] = 320 + 16 * tree.num_nodes + 64 * inner
    info["file_bytes"] = path.stat().st_size
    return info


def run_info(args: argparse.Namespace) -> int:
    info = map_info(args.file)
    if args.json:
        print(json.dumps(info))
        return 0
    width = max(len(k) for k in info)
    for key, value in info.items():
        print(f"{key.ljust(width)}  {value}")
    return 0


def run_convert(args: argparse.Namespace) -> int:
    from fleetslam.mapping.octomap_io import read_octree_file, write_bt, write_ot

    output_kind = _output_kind(args.output)
    tree = read_octree_file(args.input)
    if output_kind == "bt":
        written = write_bt(args.output, tree.resolution, tree.leaves)
    else:
        if tree.kind == "bt":
            log.info("%s holds only max-likelihood states; the .ot file gets clamped log-odds", args.input)
        written = write_ot(args.output, tree.resolution, tree.leaves)
    print(f"{args.input} ({tree.kind}) -> {args.output} ({output_kind}, {written} nodes)")
    return 0


def map_compare(path_a: Path, path_b: Path) -> dict[str, Any]:
    """Volumes per state pair of two maps of the same resolution, and their agreement."""
    from fleetslam.mapping.octomap_io import read_octree_file
    from fleetslam.mapping.products import STATE_NAMES, state_confusion

    a, b = read_octree_file(path_a), read_octree_file(path_b)
    if abs(a.resolution - b.resolution) > 1e-12:
        raise MapFileError(f"{path_b}: resolution {b.resolution} differs from {path_a}'s {a.resolution}")
    confusion = state_confusion(a.leaves, b.leaves)
    voxel = a.resolution**3
    known = confusion.sum() - confusion[0, 0]
    agree = confusion[1, 1] + confusion[2, 2]
    return {
        "a": str(path_a),
        "b": str(path_b),
        "resolution": a.resolution,
        "volume_m3": {
            f"{STATE_NAMES[i]}/{STATE_NAMES[j]}": float(confusion[i, j] * voxel)
            for i in range(3)
            for j in range(3)
            if (i, j) != (0, 0)
        },
        "agreement": float(agree / known) if known else 1.0,
        "occupied_iou": float(
            confusion[2, 2] / max(confusion[2, :].sum() + confusion[:, 2].sum() - confusion[2, 2], 1)
        ),
    }


def run_compare(args: argparse.Namespace) -> int:
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
