"""OctoMap file IO against real OctoMap (octomap-python) and the reference file geb079.bt."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import numpy as np
import pytest

from fleetslam.errors import MapFileError
from fleetslam.mapping.keys import node_centers
from fleetslam.mapping.leaves import LeafArrays
from fleetslam.mapping.octomap_io import (
    DEFAULT_CLAMP_MAX,
    DEFAULT_CLAMP_MIN,
    bt_bytes,
    decode_binary_payload,
    decode_full_payload,
    encode_binary_payload,
    encode_full_payload,
    format_resolution,
    read_octree_file,
    write_bt,
    write_ot,
)

octomap = pytest.importorskip("octomap", reason="octomap-python is the oracle")

DATA = Path(__file__).parents[2] / ".." / "shared" / "data" / "octomap"
GEB079 = DATA / "geb079.bt"
needs_geb079 = pytest.mark.skipif(not GEB079.exists(), reason=f"{GEB079} not present (../shared/data)")


def octomap_tree(seed: int, scans: int = 4, resolution: float = 0.1) -> object:
    """A real OctoMap tree with a mix of clamped (pruned) and unclamped voxels."""
    rng = np.random.default_rng(seed)
    tree = octomap.OcTree(resolution)
    for _ in range(scans):
        points = rng.uniform(-2.0, 2.0, (300, 3))
        points[:, 2] = rng.uniform(0.0, 0.5, 300)
        tree.insertPointCloud(points, np.array([0.0, 0.0, 1.0]))
    return tree


def octomap_leaves(tree: object) -> list[tuple[float, float, float, float, float]]:
    """(x, y, z, size, log-odds) of every leaf, sorted."""
    rows = []
    for leaf in tree.begin_leafs():  # type: ignore[attr-defined]
        c = leaf.getCoordinate()
        rows.append((round(c[0], 6), round(c[1], 6), round(c[2], 6), round(leaf.getSize(), 6), leaf.getValue()))
    return sorted(rows)


def our_leaves(leaves: LeafArrays, resolution: float) -> list[tuple[float, float, float, float, float]]:
    centres = node_centers(leaves.keys, leaves.depths, resolution)
    sizes = resolution * 2.0 ** (16 - leaves.depths.astype(np.float64))
    return sorted(
        (round(float(x), 6), round(float(y), 6), round(float(z), 6), round(float(s), 6), float(v))
        for (x, y, z), s, v in zip(centres, sizes, leaves.log_odds, strict=True)
    )


def test_default_clamps_are_octomaps() -> None:
    tree = octomap.OcTree(0.1)
    assert float(np.float32(tree.getClampingThresMinLog())) == DEFAULT_CLAMP_MIN
    assert float(np.float32(tree.getClampingThresMaxLog())) == DEFAULT_CLAMP_MAX


RESOLUTION_TEXTS = [(0.05, "0.05"), (0.1, "0.1"), (0.08, "0.08"), (1.0, "1"), (0.123456789, "0.123457"),
                    (1e-7, "1e-07"), (2e6, "2e+06")]  # fmt: skip


@pytest.mark.parametrize(("resolution", "text"), RESOLUTION_TEXTS)
def test_resolution_formatted_like_cpp_streams(resolution: float, text: str) -> None:
    assert format_resolution(resolution) == text


@needs_geb079
def test_geb079_round_trips_byte_exact() -> None:
    data = GEB079.read_bytes()
    octree_file = read_octree_file(GEB079)
    assert (octree_file.kind, octree_file.tree_id, octree_file.resolution) == ("bt", "OcTree", 0.08)
    assert octree_file.num_nodes == 532566
    assert bt_bytes(octree_file.resolution, octree_file.leaves) == data
    # The same leaves as OctoMap reads (count and occupied count).
    reference = octomap.OcTree(0.1)
    assert reference.readBinary(data)
    assert reference.size() == octree_file.num_nodes
    assert reference.getNumLeafNodes() == len(octree_file.leaves)


@needs_geb079
def test_geb079_ot_round_trip_keeps_leaves() -> None:
    octree_file = read_octree_file(GEB079.read_bytes())
    buffer = io.BytesIO()
    write_ot(buffer, octree_file.resolution, octree_file.leaves)
    again = read_octree_file(buffer.getvalue())
    assert again.kind == "ot" and again.num_nodes == octree_file.num_nodes
    np.testing.assert_array_equal(again.leaves.keys, octree_file.leaves.keys)
    np.testing.assert_array_equal(again.leaves.depths, octree_file.leaves.depths)
    np.testing.assert_array_equal(again.leaves.log_odds, octree_file.leaves.log_odds)


@pytest.mark.parametrize("seed", [1, 2])
def test_ot_from_octomap_reads_and_writes_back_identically(tmp_path: Path, seed: int) -> None:
    tree = octomap_tree(seed)
    path = tmp_path / "tree.ot"
    tree.write(str(path))  # type: ignore[attr-defined]
    octree_file = read_octree_file(path)
    assert octree_file.num_nodes == tree.size()  # type: ignore[attr-defined]
    assert our_leaves(octree_file.leaves, 0.1) == octomap_leaves(tree)
    out = tmp_path / "ours.ot"
    write_ot(out, octree_file.resolution, octree_file.leaves)
    assert out.read_bytes() == path.read_bytes()


@pytest.mark.parametrize("seed", [3, 4])
def test_bt_equals_octomaps_write_binary_of_an_unclamped_tree(tmp_path: Path, seed: int) -> None:
    """writeBinary does toMaxLikelihood()+prune() on the live tree; we compute the same on arrays."""
    tree = octomap_tree(seed)
    path = tmp_path / "tree.ot"
    tree.write(str(path))  # type: ignore[attr-defined]
    octree_file = read_octree_file(path)
    before = octree_file.leaves.log_odds.copy()
    expected = tree.writeBinary()  # type: ignore[attr-defined]
    ours = bt_bytes(0.1, octree_file.leaves)
    assert ours == expected
    np.testing.assert_array_equal(octree_file.leaves.log_odds, before)  # the input is not modified
    # And OctoMap reads our file into the same tree as ours.
    reread = octomap.OcTree(0.1)
    assert reread.readBinary(ours)
    assert reread.size() == read_octree_file(ours).num_nodes
    assert octomap_leaves(reread) == our_leaves(read_octree_file(ours).leaves, 0.1)


def test_binary_payload_is_the_tree_as_it_is(tmp_path: Path) -> None:
    tree = octomap_tree(5, scans=2)
    tree_file = tmp_ot(tree, tmp_path)
    leaves = read_octree_file(tree_file).leaves
    payload = encode_binary_payload(leaves)
    buffer = io.BytesIO()
    write_bt(buffer, 0.1, leaves)
    # writeBinary() prunes the max-likelihood tree; the message payload keeps the tree's structure ...
    assert payload != buffer.getvalue().split(b"data\n", 1)[1]
    # ... and decodes to the same leaves, classified by occupancy.
    decoded = decode_binary_payload(payload)
    np.testing.assert_array_equal(decoded.keys, leaves.keys)
    np.testing.assert_array_equal(decoded.depths, leaves.depths)
    expected = np.where(leaves.log_odds >= 0, np.float32(DEFAULT_CLAMP_MAX), np.float32(DEFAULT_CLAMP_MIN))
    np.testing.assert_array_equal(decoded.log_odds, expected)
    full = encode_full_payload(leaves)
    assert full == tree_file.read_bytes().split(b"data\n", 1)[1]
    np.testing.assert_array_equal(decode_full_payload(full).log_odds, leaves.log_odds)


def tmp_ot(tree: object, folder: Path) -> Path:
    path = folder / "t.ot"
    tree.write(str(path))  # type: ignore[attr-defined]
    return path


def test_empty_and_root_only_trees() -> None:
    empty = bt_bytes(0.05, LeafArrays.empty())
    assert empty.endswith(b"size 0\nres 0.05\ndata\n")
    assert len(read_octree_file(empty).leaves) == 0
    reference = octomap.OcTree(0.1)
    assert reference.readBinary(empty) and reference.size() == 0
    # A root-only tree is written as a root without children and read back as an occupied root.
    root = LeafArrays(np.zeros((1, 3), np.uint16), np.zeros(1, np.uint8), np.array([1.0], np.float32))
    data = bt_bytes(0.05, root)
    assert data.endswith(b"size 1\nres 0.05\ndata\n\x00\x00")
    back = read_octree_file(data, clamp_max_log_odds=3.5)
    assert back.num_nodes == 1 and back.leaves.depths.tolist() == [0] and back.leaves.log_odds.tolist() == [3.5]


def test_corrupt_files_name_file_and_offset(tmp_path: Path) -> None:
    tree = octomap_tree(6, scans=1)
    data = tree.writeBinary()  # type: ignore[attr-defined]
    path = tmp_path / "cut.bt"
    path.write_bytes(data[:-10])
    with pytest.raises(MapFileError, match=r"cut\.bt: byte \d+: data truncated"):
        read_octree_file(path)
    wrong_size = data.replace(f"size {tree.size()}\n".encode(), f"size {tree.size() + 1}\n".encode())  # type: ignore[attr-defined]
    with pytest.raises(MapFileError, match="tree size mismatch"):
        read_octree_file(wrong_size)
    with pytest.raises(MapFileError, match="byte 0: expected"):
        read_octree_file(b"hello\n")
    with pytest.raises(MapFileError, match="not supported"):
        read_octree_file(data.replace(b"id OcTree", b"id ColorOcTree"))
    with pytest.raises(MapFileError, match="without a 'data' line"):
        read_octree_file(data.split(b"data\n")[0])
    with pytest.raises(MapFileError, match="cannot read"):
        read_octree_file(tmp_path / "missing.bt")
    ot_path = tmp_path / "cut.ot"
    ot_path.write_bytes(tmp_ot(tree, tmp_path).read_bytes()[:-3])
    with pytest.raises(MapFileError, match=r"cut\.ot: byte \d+: data truncated"):
        read_octree_file(ot_path)


def test_overlapping_leaves_are_rejected() -> None:
    keys = np.array([[0, 0, 0], [0, 0, 0]], np.uint16)
    leaves = LeafArrays(keys, np.array([15, 16], np.uint8), np.zeros(2, np.float32))
    with pytest.raises(ValueError, match="overlaps"):
        encode_full_payload(leaves)


def test_write_binary_stops_pruning_like_octomap(tmp_path: Path) -> None:
    """prune() stops after a level that collapses nothing: 8 coarse leaves that become equal under max-likelihood
    stay apart when no finest-level group collapses (a maximal pruning would merge them)."""
    tree = octomap.OcTree(0.1)
    for group in range(8):
        gx, gy, gz = group & 1, (group >> 1) & 1, (group >> 2) & 1
        for voxel in range(8):
            vx, vy, vz = voxel & 1, (voxel >> 1) & 1, (voxel >> 2) & 1
            centre = np.array([2 * gx + vx, 2 * gy + vy, 2 * gz + vz]) * 0.1 + 0.05
            tree.updateNode(centre, float(0.5 + 0.25 * group))  # 8 equal voxels collapse into a depth-15 leaf
    leaves = read_octree_file(tmp_ot(tree, tmp_path)).leaves
    assert sorted(leaves.depths.tolist()) == [15] * 8
    expected = tree.writeBinary()
    assert bt_bytes(0.1, leaves) == expected
    assert read_octree_file(expected).leaves.depths.tolist() == [15] * 8


def test_octomap_message_fields_round_trip(tmp_path: Path) -> None:
    from fleetslam.mapping.octomap_io import leaves_from_octomap_message, octomap_message_fields

    leaves = read_octree_file(tmp_ot(octomap_tree(9, scans=2), tmp_path)).leaves
    for binary in (True, False):
        fields = octomap_message_fields(0.1, leaves, binary=binary)
        assert fields["id"] == "OcTree" and fields["resolution"] == 0.1
        data = fields["data"]
        assert isinstance(data, np.ndarray) and data.dtype == np.int8
        back = leaves_from_octomap_message(binary, "OcTree", data)
        np.testing.assert_array_equal(back.keys, leaves.keys)
        if not binary:
            np.testing.assert_array_equal(back.log_odds, leaves.log_odds)
    with pytest.raises(MapFileError, match="ColorOcTree"):
        leaves_from_octomap_message(True, "ColorOcTree", b"")


@pytest.mark.parametrize("suffix", ["bt", "ot"])
def test_random_corruption_raises_map_file_error_or_reads(tmp_path: Path, suffix: str) -> None:
    tree = octomap_tree(10, scans=1)
    data = tree.writeBinary() if suffix == "bt" else tmp_ot(tree, tmp_path).read_bytes()  # type: ignore[attr-defined]
    body = data.index(b"data\n") + 5
    rng = np.random.default_rng(11)
    for _ in range(200):
        corrupt = bytearray(data)
        for position in rng.integers(body, len(data), 3):
            corrupt[position] = int(rng.integers(0, 256))
        cut = int(rng.integers(body, len(data) + 1))
        with contextlib.suppress(MapFileError):
            read_octree_file(bytes(corrupt[:cut]))
