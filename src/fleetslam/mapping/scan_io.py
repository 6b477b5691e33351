"""Laser scan inputs in OctoMap's formats: ScanGraph `.graph` (binary), scan logs and plain `x y z` text, and
MapCollection files.

Binary ScanGraph (ScanGraph::writeBinary, little-endian): ``uint32`` node count; per node a point cloud
(``uint32`` count, then per point ``int32`` 3 and three float64), a Pose6D (``int32`` 3 + three float64
translation, ``int32`` 4 + four float64 quaternion w, x, y, z) and a ``uint32`` id; then ``uint32`` edge count and
per edge ``uint32`` first id, ``uint32`` second id, a Pose6D constraint and a float64 weight. OctoMap keeps points
and poses as float32, so we do too. A node's pose maps its sensor frame to the world.

Scan logs (ScanGraph::readPlainASCII, the input of log2graph) hold ``NODE x y z roll pitch yaw`` lines each
followed by the node's ``x y z`` points; a plain point file has only point lines. ``.bz2`` and ``.gz`` files are
read transparently.

RGB-D sequences (TUM folders, simulator exports, MCAP recordings) are input kinds too (:data:`SEQUENCE_KINDS`,
guessed from a folder or an ``.mcap`` name); :mod:`fleetslam.mapping.rgbd_scans` turns their frames into scans.
"""

from __future__ import annotations

import bz2
import gzip
import logging
import math
import struct
import zlib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fleetslam.datasets.base import LOADERS as DATASET_LOADERS
from fleetslam.datasets.base import guess_kind
from fleetslam.errors import DatasetError

log = logging.getLogger(__name__)

_POINT = np.dtype([("tag", "<i4"), ("xyz", "<f8", (3,))])
_POSE = struct.Struct("<i3di4d")
_U32 = struct.Struct("<I")
_EDGE_IDS = struct.Struct("<II")
_F64 = struct.Struct("<d")


@dataclass(frozen=True)
class ScanNode:
    """One scan: points in the sensor frame and the pose world ← sensor."""

    id: int
    pose: NDArray[np.float64]
    """(4, 4) world ← sensor."""
    points: NDArray[np.float32]
    """(N, 3) in the sensor frame."""
    quaternion_wxyz: NDArray[np.float32] | None = None
    """The pose's float32 quaternion as stored by OctoMap, if read from a file; then :meth:`world_points` and
    :attr:`origin` reproduce OctoMap's float arithmetic bit for bit."""

    def world_points(self) -> NDArray[np.float32]:
        """The points in the world frame (float32, as OctoMap's Pointcloud::transform computes them)."""
        if self.quaternion_wxyz is not None:
            return _octomap_transform(self.quaternion_wxyz, self.pose[:3, 3].astype(np.float32), self.points)
        rotation = self.pose[:3, :3].astype(np.float32)
        return (self.points @ rotation.T + self.pose[:3, 3].astype(np.float32)).astype(np.float32)

    @property
    def origin(self) -> NDArray[np.float64]:
        """Sensor origin in the world frame (for a file's node, as OctoMap's insertPointCloud(ScanNode) gets it:
        the pose's inverse applied to its translation, then the pose, in float32)."""
        if self.quaternion_wxyz is None:
            return self.pose[:3, 3].copy()
        q = self.quaternion_wxyz.astype(np.float32)
        t = self.pose[:3, 3].astype(np.float32).reshape(1, 3)
        # Pose6D::inv(): rotation = normalized conjugate, translation = rotation.rotate(-t).
        inverse = np.array([q[0], -q[1], -q[2], -q[3]], np.float32)
        norm = np.float32(math.sqrt(sum(float(c * c) for c in inverse)))
        if norm > 0:
            inverse = (inverse / norm).astype(np.float32)
        inverse_t = _octomap_rotate(inverse, -t)
        in_sensor = _octomap_rotate(inverse, t) + inverse_t
        return _octomap_transform(q, t[0], in_sensor.astype(np.float32))[0].astype(np.float64)


def _octomap_rotate(q: NDArray[np.float32], v: NDArray[np.float32]) -> NDArray[np.float32]:
    """Quaternion::rotate in float32, operation for operation: q · (0, v) · q⁻¹."""
    u, x, y, z = (np.float32(c) for c in q)
    vx, vy, vz = (v[:, i].astype(np.float32) for i in range(3))
    zero = np.float32(0.0)
    # t is the product q · (0, v)
    tu = u * zero - x * vx - y * vy - z * vz
    tx = y * vz - vy * z + u * vx + zero * x
    ty = z * vx - vz * x + u * vy + zero * y
    tz = x * vy - vx * y + u * vz + zero * z
    # r is the product t · (u, -x, -y, -z): t times the conjugate of q
    ix, iy, iz = -x, -y, -z
    rx = ty * iz - iy * tz + tu * ix + u * tx
    ry = tz * ix - iz * tx + tu * iy + u * ty
    rz = tx * iy - ix * ty + tu * iz + u * tz
    return np.stack([rx, ry, rz], axis=1).astype(np.float32)


def _octomap_transform(q: NDArray[np.float32], t: NDArray[np.float32], v: NDArray[np.float32]) -> NDArray[np.float32]:
    """Pose6D::transform in float32: rotate, then add the translation."""
    return (_octomap_rotate(q, v.reshape(-1, 3)) + t.astype(np.float32).reshape(1, 3)).astype(np.float32)


@dataclass(frozen=True)
class ScanEdge:
    """A constraint between two scan nodes."""

    first: int
    second: int
    constraint: NDArray[np.float64]
    """(4, 4) relative pose."""
    weight: float
    constraint_wxyz: NDArray[np.float32] | None = None
    """The constraint's float32 quaternion as stored in the file, if read from one."""


@dataclass(frozen=True)
class ScanGraph:
    """Nodes and edges of a ScanGraph file."""

    nodes: list[ScanNode]
    edges: list[ScanEdge] = field(default_factory=list)


@dataclass(frozen=True)
class MapCollectionEntry:
    """One map of an OctoMap MapCollection file."""

    id: str
    path: Path
    """The map file, resolved against the collection file's folder."""
    pose: NDArray[np.float64]
    """(4, 4) world ← map."""


# -- poses -------------------------------------------------------------------------------------------------------
def pose_from_wxyz(translation: ArrayLike, quaternion_wxyz: ArrayLike) -> NDArray[np.float64]:
    """4×4 pose from OctoMap's Pose6D parts (Quaternion::toRotMatrix; a zero quaternion is the identity)."""
    w, x, y, z = (float(v) for v in np.asarray(quaternion_wxyz, dtype=np.float64))
    norm2 = w * w + x * x + y * y + z * z
    s = 2.0 / norm2 if norm2 > 0 else 0.0
    pose = np.eye(4)
    pose[:3, :3] = [
        [1 - s * (y * y + z * z), s * (x * y - w * z), s * (x * z + w * y)],
        [s * (x * y + w * z), 1 - s * (x * x + z * z), s * (y * z - w * x)],
        [s * (x * z - w * y), s * (y * z + w * x), 1 - s * (x * x + y * y)],
    ]
    pose[:3, 3] = np.asarray(translation, dtype=np.float64)
    return pose


def wxyz_from_pose(pose: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(translation, quaternion w, x, y, z) of a 4×4 pose, w ≥ 0."""
    from fleetslam.geometry import pose_to_quat

    translation, quat_xyzw = pose_to_quat(pose)
    wxyz = np.array([quat_xyzw[3], quat_xyzw[0], quat_xyzw[1], quat_xyzw[2]], dtype=np.float64)
    return np.asarray(translation, dtype=np.float64), wxyz if wxyz[0] >= 0 else -wxyz


def pose_from_xyz_rpy(x: float, y: float, z: float, roll: float, pitch: float, yaw: float) -> NDArray[np.float64]:
    """OctoMap's pose6d(x, y, z, roll, pitch, yaw): float32 translation, rotation Rz(yaw)·Ry(pitch)·Rx(roll)."""
    from fleetslam.geometry import pose_from_xyz_rpy as geometry_pose

    pose = geometry_pose(0.0, 0.0, 0.0, roll, pitch, yaw)
    pose[:3, 3] = np.array([x, y, z], dtype=np.float32)
    return pose


# -- binary ScanGraph --------------------------------------------------------------------------------------------
class _Reader:
    def __init__(self, data: bytes, name: str) -> None:
        self.data, self.name, self.pos = data, name, 0

    def take(self, size: int, what: str) -> int:
        start = self.pos
        if start + size > len(self.data):
            raise DatasetError(
                f"{self.name}: byte {start}: file truncated reading {what} (needs {size} bytes, "
                f"{len(self.data) - start} left)"
            )
        self.pos += size
        return start

    def u32(self, what: str) -> int:
        return int(_U32.unpack_from(self.data, self.take(4, what))[0])

    def pose(self, what: str) -> tuple[NDArray[np.float64], NDArray[np.float32]]:
        start = self.take(_POSE.size, what)
        tag_t, tx, ty, tz, tag_q, qw, qx, qy, qz = _POSE.unpack_from(self.data, start)
        if (tag_t, tag_q) != (3, 4):
            raise DatasetError(
                f"{self.name}: byte {start}: {what} is not a Pose6D (tags {tag_t}, {tag_q}, expected 3, 4)"
            )
        # OctoMap stores both as float32.
        translation = np.array([tx, ty, tz], dtype=np.float32)
        quaternion = np.array([qw, qx, qy, qz], dtype=np.float32)
        return pose_from_wxyz(translation, quaternion), quaternion


def load_scan_graph(path: str | Path) -> ScanGraph:
    """Read a binary OctoMap ScanGraph (`.graph`) file, nodes and edges."""
    name = str(path)
    try:
        data = Path(path).read_bytes()
    except OSError as err:
        raise DatasetError(f"{name}: cannot read: {err.strerror}") from err
    reader = _Reader(data, name)
    node_count = reader.u32("the node count")
    nodes: list[ScanNode] = []
    for index in range(node_count):
        point_count = reader.u32(f"node {index}'s point count")
        start = reader.take(point_count * _POINT.itemsize, f"node {index}'s {point_count} points")
        raw = np.frombuffer(data, dtype=_POINT, count=point_count, offset=start)
        if point_count and not np.all(raw["tag"] == 3):
            bad = int(np.flatnonzero(raw["tag"] != 3)[0])
            raise DatasetError(
                f"{name}: byte {start + bad * _POINT.itemsize}: point {bad} of node {index} is not a 3-vector"
            )
        points = raw["xyz"].astype(np.float32)
        pose, quaternion = reader.pose(f"node {index}'s pose")
        node_id = reader.u32(f"node {index}'s id")
        nodes.append(ScanNode(node_id, pose, points, quaternion))
    edges: list[ScanEdge] = []
    if reader.pos < len(data):  # old files may end after the nodes
        edge_count = reader.u32("the edge count")
        known = {node.id for node in nodes}
        for index in range(edge_count):
            first, second = _EDGE_IDS.unpack_from(data, reader.take(8, f"edge {index}'s node ids"))
            if first not in known or second not in known:
                raise DatasetError(f"{name}: edge {index} joins unknown nodes {first} and {second}")
            constraint, quaternion = reader.pose(f"edge {index}'s constraint")
            weight = _F64.unpack_from(data, reader.take(8, f"edge {index}'s weight"))[0]
            edges.append(ScanEdge(int(first), int(second), constraint, float(weight), quaternion))
    if reader.pos != len(data):
        raise DatasetError(f"{name}: byte {reader.pos}: {len(data) - reader.pos} unexpected bytes after the graph")
    return ScanGraph(nodes, edges)


def read_scan_graph(path: str | Path) -> list[ScanNode]:
    """The scan nodes of a binary OctoMap ScanGraph (`.graph`) file."""
    return load_scan_graph(path).nodes


def _pose_bytes(pose: ArrayLike, quaternion_wxyz: NDArray[np.float32] | None = None) -> bytes:
    translation, wxyz = wxyz_from_pose(pose)
    if quaternion_wxyz is not None:  # keep a file's quaternion bit for bit
        wxyz = quaternion_wxyz.astype(np.float64)
    # OctoMap holds poses as float32 and widens them to float64 in the file.
    values = np.concatenate([translation, wxyz]).astype(np.float32).astype(np.float64).tolist()
    return _POSE.pack(3, *values[:3], 4, *values[3:])


def write_scan_graph(path: str | Path, nodes: Sequence[ScanNode], edges: Iterable[ScanEdge] = ()) -> None:
    """Write a binary ScanGraph as OctoMap does (float32 points and poses widened to float64)."""
    parts = [_U32.pack(len(nodes))]
    for node in nodes:
        points = np.asarray(node.points, dtype=np.float32).reshape(-1, 3)
        raw = np.empty(len(points), dtype=_POINT)
        raw["tag"] = 3
        raw["xyz"] = points.astype(np.float64)
        parts += [
            _U32.pack(len(points)),
            raw.tobytes(),
            _pose_bytes(node.pose, node.quaternion_wxyz),
            _U32.pack(node.id),
        ]
    edge_list = list(edges)
    parts.append(_U32.pack(len(edge_list)))
    for edge in edge_list:
        parts += [
            _EDGE_IDS.pack(edge.first, edge.second),
            _pose_bytes(edge.constraint, edge.constraint_wxyz),
            _F64.pack(edge.weight),
        ]
    try:
        Path(path).write_bytes(b"".join(parts))
    except OSError as err:
        raise DatasetError(f"{path}: cannot write: {err.strerror}") from err


# -- text scans --------------------------------------------------------------------------------------------------
def _read_text(path: str | Path) -> str:
    p = Path(path)
    try:
        if p.suffix == ".bz2":
            raw = bz2.decompress(p.read_bytes())
        elif p.suffix == ".gz":
            raw = gzip.decompress(p.read_bytes())
        else:
            raw = p.read_bytes()
    except OSError as err:  # also gzip's BadGzipFile
        raise DatasetError(f"{path}: cannot read: {err}") from err
    except (EOFError, ValueError, zlib.error) as err:  # a truncated or corrupt .bz2/.gz
        raise DatasetError(f"{path}: corrupt or truncated {p.suffix} file: {err}") from err
    return raw.decode("utf-8", errors="replace")


def _parse_points(lines: list[tuple[int, str]], name: str) -> NDArray[np.float32]:
    """Points from numbered ``x y z`` lines (extra columns ignored, as OctoMap's stream reads ignore them)."""
    if not lines:
        return np.zeros((0, 3), np.float32)
    try:
        rows = [line.split(maxsplit=3)[:3] for _, line in lines]
        return np.array(rows, dtype=np.float64).reshape(-1, 3).astype(np.float32)
    except ValueError:
        for number, line in lines:
            fields = line.split()
            try:
                if len(fields) < 3:
                    raise ValueError(line)
                [float(v) for v in fields[:3]]
            except ValueError as err:
                raise DatasetError(f"{name}:{number}: expected 'x y z', found {line.strip()[:60]!r}") from err
        raise


def _content_lines(text: str) -> list[tuple[int, str]]:
    """(1-based line number, line) without blank and comment lines (OctoMap also skips lines starting with ' ')."""
    return [
        (number, line)
        for number, line in enumerate(text.splitlines(), start=1)
        if line.strip() and not line.startswith("#")
    ]


def read_xyz(path: str | Path) -> NDArray[np.float32]:
    """Points ``(N, 3)`` float32 of a text file with one ``x y z`` per line (``.bz2``/``.gz`` transparently)."""
    name = str(path)
    lines = _content_lines(_read_text(path))
    if lines and lines[0][1].startswith("NODE"):
        raise DatasetError(f"{name}:{lines[0][0]}: a scan log with NODE lines; use read_scan_log")
    points = _parse_points(lines, name)
    if len(points) == 0:
        raise DatasetError(f"{name}: no points (an empty point file maps nothing)")
    finite = np.isfinite(points).all(axis=1)
    if not finite.any():
        raise DatasetError(f"{name}: all {len(points)} points are NaN or infinite")
    if not finite.all():
        log.warning("%s: %d of %d points are NaN or infinite; left out", name, int((~finite).sum()), len(points))
        points = points[finite]
    return points


def read_scan_log(path: str | Path) -> list[ScanNode]:
    """Scan nodes of a log file (``NODE x y z roll pitch yaw`` then that scan's points, as log2graph reads)."""
    name = str(path)
    nodes: list[ScanNode] = []
    pose: NDArray[np.float64] | None = None
    block: list[tuple[int, str]] = []

    def finish() -> None:
        if pose is not None:
            nodes.append(ScanNode(len(nodes), pose, _parse_points(block, name)))

    for number, line in _content_lines(_read_text(path)):
        if line.startswith(" "):
            continue
        if line.startswith("NODE"):
            finish()
            fields = line.split()
            try:
                x, y, z, roll, pitch, yaw = (float(v) for v in fields[1:7])
            except ValueError as err:
                raise DatasetError(
                    f"{name}:{number}: expected 'NODE x y z roll pitch yaw', found {line.strip()[:60]!r}"
                ) from err
            pose, block = pose_from_xyz_rpy(x, y, z, roll, pitch, yaw), []
        elif pose is None:
            raise DatasetError(f"{name}:{number}: a point before the first NODE line")
        else:
            block.append((number, line))
    finish()
    return nodes


def read_map_collection(path: str | Path) -> list[MapCollectionEntry]:
    """Entries of an OctoMap MapCollection file (MAPNODEID, MAPNODEFILENAME, MAPNODEPOSE x y z roll pitch yaw)."""
    name = str(path)
    folder = Path(path).parent
    entries: list[MapCollectionEntry] = []
    expected = ("MAPNODEID", "MAPNODEFILENAME", "MAPNODEPOSE")
    values: list[str] = []
    for number, line in _content_lines(_read_text(path)):
        tag, _, value = line.strip().partition(" ")
        want = expected[len(values)]
        if tag != want:
            raise DatasetError(f"{name}:{number}: expected {want}, found {line.strip()[:60]!r}")
        values.append(value.strip())
        if len(values) == 3:
            try:
                x, y, z, roll, pitch, yaw = (float(v) for v in values[2].split()[:6])
            except ValueError as err:
                raise DatasetError(f"{name}:{number}: expected 'MAPNODEPOSE x y z roll pitch yaw'") from err
            if not all(math.isfinite(v) for v in (x, y, z, roll, pitch, yaw)):
                raise DatasetError(f"{name}:{number}: MAPNODEPOSE has a non-finite value")
            pose = pose_from_xyz_rpy(x, y, z, roll, pitch, yaw)
            entries.append(MapCollectionEntry(values[0], folder / values[1], pose))
            values = []
    if values:
        raise DatasetError(f"{name}: the last map entry is incomplete (has only {', '.join(expected[: len(values)])})")
    return entries


# -- scan sources by file name -----------------------------------------------------------------------------------
class ScanLoader(Protocol):
    """Loads the scans of one input file; ``origin`` is the sensor position for plain point files."""

    def __call__(self, path: Path, *, origin: NDArray[np.float64] | None) -> list[ScanNode]: ...


def _load_graph(path: Path, *, origin: NDArray[np.float64] | None) -> list[ScanNode]:
    return read_scan_graph(path)


def _load_log(path: Path, *, origin: NDArray[np.float64] | None) -> list[ScanNode]:
    return read_scan_log(path)


def _load_xyz(path: Path, *, origin: NDArray[np.float64] | None) -> list[ScanNode]:
    """A plain point file in the world frame, seen from ``origin`` (default the world origin)."""
    sensor = np.zeros(3) if origin is None else np.asarray(origin, dtype=np.float64).reshape(3)
    pose = np.eye(4)
    pose[:3, 3] = sensor.astype(np.float32)
    points = read_xyz(path)
    return [ScanNode(0, pose, (points - pose[:3, 3].astype(np.float32)).astype(np.float32))]


#: input kind → loader. Kinds are chosen from the file name by :func:`scan_kind`.
SCAN_LOADERS: Mapping[str, ScanLoader] = {"graph": _load_graph, "log": _load_log, "xyz": _load_xyz}
#: RGB-D sequence kinds (the loaders of :mod:`fleetslam.datasets`), read as scans by
#: :func:`fleetslam.mapping.rgbd_scans.open_rgbd_scans` because they need camera poses and are read lazily.
SEQUENCE_KINDS: tuple[str, ...] = tuple(sorted(DATASET_LOADERS))
_SUFFIX_KINDS = {".graph": "graph", ".log": "log", ".xyz": "xyz", ".txt": "xyz", ".dat": "xyz", ".pts": "xyz"}


def _known_kinds() -> str:
    return ", ".join([*sorted(SCAN_LOADERS), *SEQUENCE_KINDS])


def scan_kind(path: str | Path) -> str:
    """Input kind of a scan input from its name (compression suffixes ignored); a folder or an ``.mcap`` file is
    an RGB-D sequence whose kind :func:`fleetslam.datasets.guess_kind` tells."""
    p = Path(path)
    if p.is_dir() or p.suffix.lower() == ".mcap":
        return guess_kind(p)
    suffixes = [s for s in p.suffixes if s not in (".bz2", ".gz")]
    if not suffixes and not p.exists():
        raise DatasetError(f"{path}: not found (expected a scan file or an RGB-D sequence folder)")
    kind = _SUFFIX_KINDS.get(suffixes[-1].lower()) if suffixes else None
    if kind is None:
        raise DatasetError(
            f"{path}: unknown scan input kind '{''.join(p.suffixes)}'; known: {', '.join(sorted(_SUFFIX_KINDS))}, "
            "a dataset folder or .mcap"
        )
    return kind


def input_kind(path: str | Path, kind: str | None = None) -> str:
    """``kind`` when it is a known input kind (a scan kind or a sequence kind), else the kind guessed from ``path``.

    Raises:
        DatasetError: ``kind`` is unknown or the path's kind cannot be told.
    """
    if kind is None:
        return scan_kind(path)
    if kind not in SCAN_LOADERS and kind not in SEQUENCE_KINDS:
        raise DatasetError(f"{path}: unknown scan input kind '{kind}'; known: {_known_kinds()}")
    return kind


def load_scans(path: str | Path, *, kind: str | None = None, origin: ArrayLike | None = None) -> list[ScanNode]:
    """Scans of an input file, by ``kind`` (a key of :data:`SCAN_LOADERS`) or by its file name."""
    chosen = input_kind(path, kind)
    loader = SCAN_LOADERS.get(chosen)
    if loader is None:
        raise DatasetError(
            f"{path}: '{chosen}' is an RGB-D sequence, not a scan file; read it with "
            "fleetslam.mapping.rgbd_scans.open_rgbd_scans (it needs camera poses)"
        )
    sensor = None if origin is None else np.asarray(origin, dtype=np.float64).reshape(3)
    return loader(Path(path), origin=sensor)
