"""OctoMap's files, byte for byte: `.bt` (binary, max-likelihood), `.ot` (full), and octomap_msgs payloads.

Both formats are a pre-order walk of the tree. `.bt` writes, for each inner node, two bytes with a 2-bit code per
child (0 unknown, 1 free leaf, 2 occupied leaf, 3 inner node; children 0–3 in the first byte). `.ot` writes every
node's float32 log-odds followed by one byte of child-existence bits. Headers are OctoMap's, `res` formatted as
C++ streams print a double. Writing works on arrays and never changes the leaves it was given; the walks run in
numba kernels (:mod:`fleetslam.mapping._io_kernels`).
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np
from numpy.typing import NDArray

from fleetslam.errors import MapFileError
from fleetslam.mapping import _io_kernels as kernels
from fleetslam.mapping._prune_kernels import unmorton_keys
from fleetslam.mapping.keys import morton
from fleetslam.mapping.leaves import LeafArrays

BT_HEADER = b"# Octomap OcTree binary file"
OT_HEADER = b"# Octomap OcTree file"
COMMENT = b"# (feel free to add / change comments, but leave the first line as it is!)\n#\n"
DEFAULT_CLAMP_MIN = float(np.float32(math.log(0.1192 / (1 - 0.1192))))
DEFAULT_CLAMP_MAX = float(np.float32(math.log(0.971 / (1 - 0.971))))

_ERRORS = {
    kernels.TRUNCATED: "data truncated inside a node (expected more node bytes)",
    kernels.TOO_DEEP: "an inner node below the finest level (depth 16); corrupt data",
}


@dataclass(frozen=True)
class OctreeFile:
    """A tree read from a file."""

    kind: str
    """'bt' or 'ot'."""
    tree_id: str
    """OctoMap tree type ('OcTree')."""
    resolution: float
    """Edge length of a finest voxel in metres."""
    leaves: LeafArrays
    """Leaves in pre-order; `.bt` leaves carry the reading tree's clamp values."""
    num_nodes: int
    """Node count stored in the header (and found in the data)."""


def format_resolution(resolution: float) -> str:
    """A double as C++ ``ostream << double`` prints it (6 significant digits, %g style)."""
    return f"{resolution:g}"


def _header(first: bytes, num_nodes: int, resolution: float) -> bytes:
    return (
        first + b"\n" + COMMENT + b"id OcTree\n" + f"size {num_nodes}\n".encode()
        + f"res {format_resolution(resolution)}\n".encode() + b"data\n"
    )  # fmt: skip


# -- payloads (no header) ----------------------------------------------------------------------------------------
def _encode(leaves: LeafArrays, threshold: float, full: bool) -> tuple[bytes, int]:
    if len(leaves) == 0:
        return b"", 0
    codes = morton(leaves.keys)
    out, count, status, index = kernels.encode(
        codes, np.ascontiguousarray(leaves.depths, np.uint8), np.ascontiguousarray(leaves.log_odds, np.float32),
        np.float32(threshold), full,
    )  # fmt: skip
    if status != kernels.OK:
        raise ValueError(
            f"leaf {index} (key {leaves.keys[index].tolist()}, depth {int(leaves.depths[index])}) overlaps or "
            "precedes the previous leaf; LeafArrays must be non-overlapping and in pre-order"
        )
    return out.tobytes(), int(count)


def encode_binary_payload(leaves: LeafArrays, occupancy_threshold_log_odds: float = 0.0) -> bytes:
    """octomap_msgs binary data: writeBinaryData of the tree as it is (leaves classified, no pruning, no header)."""
    return _encode(leaves, occupancy_threshold_log_odds, full=False)[0]


def encode_full_payload(leaves: LeafArrays) -> bytes:
    """octomap_msgs full data: writeData (every node's float32 log-odds and child bits, pre-order, no header)."""
    return _encode(leaves, 0.0, full=True)[0]


def _leaves_from(codes: NDArray[np.uint64], depths: NDArray[np.uint8], values: NDArray[np.float32]) -> LeafArrays:
    return LeafArrays(unmorton_keys(np.ascontiguousarray(codes, dtype=np.uint64)), depths.copy(), values.copy())


def _decode(
    data: bytes, start: int, name: str, *, full: bool, clamp_min: float, clamp_max: float
) -> tuple[LeafArrays, int, int]:
    buffer = np.frombuffer(data, dtype=np.uint8)
    if full:
        result = kernels.decode_ot(buffer, start)
    else:
        result = kernels.decode_bt(buffer, start, np.float32(clamp_min), np.float32(clamp_max))
    codes, depths, values, count, end, status, offset = result
    if status != kernels.OK:
        raise MapFileError(f"{name}: byte {offset}: {_ERRORS[status]}")
    return _leaves_from(codes, depths, values), int(count), int(end)


def decode_binary_payload(
    data: bytes,
    *,
    clamp_min_log_odds: float = DEFAULT_CLAMP_MIN,
    clamp_max_log_odds: float = DEFAULT_CLAMP_MAX,
    name: str = "<binary payload>",
) -> LeafArrays:
    """Leaves of octomap_msgs binary data (readBinaryData): free leaves get clamp min, occupied clamp max."""
    if len(data) == 0:
        return LeafArrays.empty()
    leaves, _, end = _decode(data, 0, name, full=False, clamp_min=clamp_min_log_odds, clamp_max=clamp_max_log_odds)
    if end != len(data):
        raise MapFileError(f"{name}: byte {end}: {len(data) - end} bytes after the end of the tree")
    return leaves


def decode_full_payload(data: bytes, *, name: str = "<full payload>") -> LeafArrays:
    """Leaves of octomap_msgs full data (readData)."""
    if len(data) == 0:
        return LeafArrays.empty()
    leaves, _, end = _decode(data, 0, name, full=True, clamp_min=0.0, clamp_max=0.0)
    if end != len(data):
        raise MapFileError(f"{name}: byte {end}: {len(data) - end} bytes after the end of the tree")
    return leaves


# -- max likelihood + prune, as writeBinary() does to the live tree ---------------------------------------------
def max_likelihood_pruned(
    leaves: LeafArrays, clamp_min_log_odds: float, clamp_max_log_odds: float, occupancy_threshold_log_odds: float = 0.0
) -> LeafArrays:
    """The leaves after C++ ``toMaxLikelihood(); prune();`` (computed on copies).

    OctoMap's prune() makes passes at depth 15, 14, … 1 and stops after the first pass that collapses nothing, and
    never collapses the root; this reproduces exactly that, not a maximal pruning.
    """
    if len(leaves) == 0:
        return leaves
    values = np.where(
        leaves.log_odds >= np.float32(occupancy_threshold_log_odds),
        np.float32(clamp_max_log_odds),
        np.float32(clamp_min_log_odds),
    ).astype(np.float32)
    codes, depths, values = kernels.prune_levels(morton(leaves.keys), np.ascontiguousarray(leaves.depths), values)
    return _leaves_from(codes, depths, values)


# -- files -------------------------------------------------------------------------------------------------------
def _write(target: str | Path | BinaryIO, header: bytes, body: bytes) -> None:
    if isinstance(target, str | Path):
        try:
            Path(target).write_bytes(header + body)
        except OSError as err:
            raise MapFileError(f"{target}: cannot write: {err.strerror}") from err
    else:
        target.write(header)
        target.write(body)


def write_bt(
    target: str | Path | BinaryIO,
    resolution: float,
    leaves: LeafArrays,
    *,
    clamp_min_log_odds: float = DEFAULT_CLAMP_MIN,
    clamp_max_log_odds: float = DEFAULT_CLAMP_MAX,
    occupancy_threshold_log_odds: float = 0.0,
) -> int:
    """What C++ writeBinary() writes: the max-likelihood, pruned tree (computed on copies of ``leaves``).

    Returns the number of nodes written (the header's size), usually fewer than the live tree's: max-likelihood
    values make more siblings equal.
    """
    pruned = max_likelihood_pruned(leaves, clamp_min_log_odds, clamp_max_log_odds, occupancy_threshold_log_odds)
    body, count = _encode(pruned, occupancy_threshold_log_odds, full=False)
    _write(target, _header(BT_HEADER, count, resolution), body)
    return count


def write_ot(target: str | Path | BinaryIO, resolution: float, leaves: LeafArrays) -> int:
    """A full `.ot` file of the tree as it is (inner nodes hold the max of their children); returns the number
    of nodes written."""
    body, count = _encode(leaves, 0.0, full=True)
    _write(target, _header(OT_HEADER, count, resolution), body)
    return count


def bt_bytes(resolution: float, leaves: LeafArrays, **sensor_model: float) -> bytes:
    """A `.bt` file as bytes (keywords as :func:`write_bt`)."""
    buffer = io.BytesIO()
    write_bt(buffer, resolution, leaves, **sensor_model)
    return buffer.getvalue()


def _parse_header(data: bytes, name: str) -> tuple[str, str, int, float, int]:
    """(kind, tree id, size, resolution, offset of the body), parsed as AbstractOcTree::readHeader does."""
    newline = data.find(b"\n")
    first = data[: newline if newline >= 0 else len(data)]
    if first.startswith(BT_HEADER):
        kind = "bt"
    elif first.startswith(OT_HEADER):
        kind = "ot"
    else:
        raise MapFileError(
            f"{name}: byte 0: expected '{BT_HEADER.decode()}' or '{OT_HEADER.decode()}', found {first[:40]!r}"
        )
    offset = newline + 1
    tree_id, size, res = "", 0, 0.0
    while True:
        end = data.find(b"\n", offset)
        if end < 0:
            raise MapFileError(f"{name}: byte {offset}: header ended without a 'data' line")
        line = data[offset:end].decode("ascii", errors="replace").strip()
        line_start, offset = offset, end + 1
        if not line or line.startswith("#"):
            continue
        token, _, value = line.partition(" ")
        if token == "data":
            break
        try:
            if token == "id":
                tree_id = value.strip()
            elif token == "size":
                size = int(value)
            elif token == "res":
                res = float(value)
        except ValueError as err:
            raise MapFileError(f"{name}: byte {line_start}: bad header line {line!r}") from err
    if tree_id == "1":  # OctoMap's deprecated id
        tree_id = "OcTree"
    if not tree_id:
        raise MapFileError(f"{name}: header has no 'id' line")
    if not res > 0.0:
        raise MapFileError(f"{name}: header 'res' must be > 0, got {res}")
    if size < 0:
        raise MapFileError(f"{name}: header 'size' must be >= 0, got {size}")
    return kind, tree_id, size, res, offset


def read_octree_file(
    source: str | Path | bytes | BinaryIO,
    *,
    clamp_min_log_odds: float = DEFAULT_CLAMP_MIN,
    clamp_max_log_odds: float = DEFAULT_CLAMP_MAX,
) -> OctreeFile:
    """Read a `.bt` or `.ot` file (kind from its first line); `.bt` leaves take the given clamp values."""
    if isinstance(source, bytes):
        data, name = source, "<bytes>"
    elif isinstance(source, str | Path):
        name = str(source)
        try:
            data = Path(source).read_bytes()
        except OSError as err:
            raise MapFileError(f"{name}: cannot read: {err.strerror}") from err
    else:
        data, name = source.read(), str(getattr(source, "name", "<stream>"))
    kind, tree_id, size, res, offset = _parse_header(data, name)
    if tree_id != "OcTree":
        raise MapFileError(f"{name}: tree type '{tree_id}' is not supported (only OcTree)")
    if size == 0:
        return OctreeFile(kind, tree_id, res, LeafArrays.empty(), 0)
    leaves, count, _ = _decode(
        data, offset, name, full=kind == "ot", clamp_min=clamp_min_log_odds, clamp_max=clamp_max_log_odds
    )
    if count != size:
        raise MapFileError(f"{name}: tree size mismatch: the data holds {count} nodes, the header says size {size}")
    return OctreeFile(kind, tree_id, res, leaves, count)


# -- octomap_msgs/Octomap ----------------------------------------------------------------------------------------
def octomap_message_fields(
    resolution: float, leaves: LeafArrays, *, binary: bool = True, occupancy_threshold_log_odds: float = 0.0
) -> dict[str, object]:
    """Fields of an ``octomap_msgs/msg/Octomap`` (without header) as octomap_msgs' binaryMapToMsg / fullMapToMsg
    fill them: ``binary``, ``id`` 'OcTree', ``resolution`` and ``data`` as int8."""
    payload = encode_binary_payload(leaves, occupancy_threshold_log_odds) if binary else encode_full_payload(leaves)
    return {
        "binary": binary,
        "id": "OcTree",
        "resolution": float(resolution),
        "data": np.frombuffer(payload, dtype=np.int8).copy(),
    }


def leaves_from_octomap_message(
    binary: bool,
    tree_id: str,
    data: bytes | NDArray[np.int8] | NDArray[np.uint8],
    *,
    clamp_min_log_odds: float = DEFAULT_CLAMP_MIN,
    clamp_max_log_odds: float = DEFAULT_CLAMP_MAX,
) -> LeafArrays:
    """Leaves of an ``octomap_msgs/msg/Octomap``'s data (binary or full)."""
    if tree_id not in ("OcTree", "1"):
        raise MapFileError(f"octomap message: tree type '{tree_id}' is not supported (only OcTree)")
    raw = data if isinstance(data, bytes) else np.asarray(data).view(np.uint8).tobytes()
    if binary:
        return decode_binary_payload(
            raw, clamp_min_log_odds=clamp_min_log_odds, clamp_max_log_odds=clamp_max_log_odds, name="octomap message"
        )
    return decode_full_payload(raw, name="octomap message")
