"""Building a map file from a whole input: laser scans with their poses, or the depth images of an RGB-D sequence at
their camera poses, integrated into an occupancy octree and written as ``.bt`` or ``.ot`` (`fleetslam map build`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from numpy.typing import NDArray

from fleetslam.mapping.map_files import output_kind

if TYPE_CHECKING:
    from fleetslam.mapping.octree import OccupancyOctree
    from fleetslam.mapping.rgbd_scans import RgbdScanCounts


@dataclass(frozen=True)
class ScanBuild:
    """What :func:`build_from_scans` integrated and wrote."""

    scans: int
    points: int
    nodes: int
    """Nodes in the file (a .bt's max-likelihood tree prunes further than the tree in memory)."""


@dataclass(frozen=True)
class RgbdBuild:
    """What :func:`build_from_rgbd` integrated and wrote."""

    counts: RgbdScanCounts
    """Frames seen, used and skipped, points integrated."""
    nodes: int
    """Nodes in the file."""
    skipped: str | None
    """Why frames were skipped, one line (None: none was)."""


def write_tree(tree: OccupancyOctree, path: Path) -> int:
    """Write the map as ``.bt`` or ``.ot`` (by the suffix); the number of nodes in the file."""
    return tree.write_binary(path) if output_kind(path) == "bt" else tree.write(path)


def build_from_scans(
    source: Path,
    output: Path,
    *,
    kind: str,
    resolution: float,
    max_range: float = -1.0,
    origin: NDArray | None = None,
    progress: bool = True,
) -> ScanBuild:
    """Integrate the scans of a scan file (OctoMap .graph, scan log, point file of ``kind``) and write the map."""
    from tqdm import tqdm

    from fleetslam.mapping.octree import OccupancyOctree
    from fleetslam.mapping.scan_io import load_scans

    output_kind(output)  # a wrong suffix fails before the work
    scans = load_scans(source, kind=kind, origin=origin)
    tree = OccupancyOctree(resolution)
    total = sum(len(scan.points) for scan in scans)
    with tqdm(total=total, unit="pt", unit_scale=True, disable=not progress, desc="integrating") as bar:
        for scan in scans:
            tree.insert_point_cloud(scan.world_points(), scan.origin, max_range=max_range)
            bar.update(len(scan.points))
    return ScanBuild(len(scans), total, write_tree(tree, output))


def build_from_rgbd(
    source: Path,
    output: Path,
    *,
    kind: str,
    resolution: float,
    max_range: float = -1.0,
    trajectory: Path | None = None,
    max_difference: float = 0.02,
    every: int = 1,
    pixel_step: int = 4,
    min_depth: float = 0.3,
    max_depth: float = 6.0,
    progress: bool = True,
) -> RgbdBuild:
    """Integrate the depth images of an RGB-D sequence at their camera poses (see
    :func:`fleetslam.mapping.rgbd_scans.open_rgbd_scans`) and write the map."""
    from tqdm import tqdm

    from fleetslam.mapping.octree import OccupancyOctree
    from fleetslam.mapping.rgbd_scans import open_rgbd_scans

    output_kind(output)
    scans = open_rgbd_scans(
        source,
        kind=kind,
        trajectory=trajectory,
        max_difference=max_difference,
        every=every,
        pixel_step=pixel_step,
        min_depth=min_depth,
        max_depth=max_depth,
    )
    tree = OccupancyOctree(resolution)
    with tqdm(total=len(scans), unit="frame", disable=not progress, desc="integrating") as bar:
        for scan in scans:
            tree.insert_point_cloud(scan.world_points(), scan.origin, max_range=max_range)
            bar.update(scans.counts.frames - bar.n)
        bar.update(scans.counts.frames - bar.n)
    return RgbdBuild(scans.counts, write_tree(tree, output), scans.skipped_summary())
