"""Scan inputs: OctoMap ScanGraph files, scan logs, point files and map collections."""

from __future__ import annotations

import bz2
from pathlib import Path

import numpy as np
import pytest

from fleetslam.errors import DatasetError
from fleetslam.geometry import random_pose
from fleetslam.mapping.scan_io import (
    ScanEdge,
    ScanNode,
    load_scan_graph,
    pose_from_wxyz,
    read_map_collection,
    read_scan_graph,
    read_scan_log,
    read_xyz,
    write_scan_graph,
)

DATA = Path(__file__).parents[2] / ".." / "shared" / "data" / "octomap"


def _need(path: Path) -> Path:
    if not path.exists():
        pytest.skip(f"{path} not present (../shared/data)")
    return path


def test_spherical_scan_graph_is_one_plausible_scan() -> None:
    path = _need(DATA / "spherical_scan.graph")
    nodes = read_scan_graph(path)
    assert len(nodes) == 1
    node = nodes[0]
    # 4 (node count) + 4 (point count) + 28 per point + 64 (pose) + 4 (id) + 4 (edge count) bytes.
    assert path.stat().st_size == 4 + 4 + 28 * len(node.points) + 64 + 4 + 4
    assert node.points.shape == (101 * 101, 3) and node.points.dtype == np.float32
    ranges = np.linalg.norm(node.points, axis=1)
    assert ranges.min() > 0.5 and ranges.max() < 10.0
    # The file's float32 pose: identity rotation, so world points are float32 sums (0.0 measured); 1e-6 ≈ 2 ulp at 4 m.
    np.testing.assert_allclose(node.pose[:3, :3], np.eye(3), atol=1e-6)
    np.testing.assert_allclose(node.world_points(), node.points + node.pose[:3, 3].astype(np.float32), atol=1e-6)


def test_scan_graph_write_read_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(7)
    nodes = [ScanNode(i + 10, random_pose(rng, 3.0), rng.normal(size=(50 + i, 3)).astype(np.float32)) for i in range(3)]
    edges = [ScanEdge(10, 11, random_pose(rng), 0.5), ScanEdge(11, 12, random_pose(rng), 2.0)]
    path = tmp_path / "g.graph"
    write_scan_graph(path, nodes, edges)
    graph = load_scan_graph(path)
    assert [n.id for n in graph.nodes] == [10, 11, 12]
    for ours, theirs in zip(nodes, graph.nodes, strict=True):
        np.testing.assert_array_equal(theirs.points, ours.points)
        # Poses pass through OctoMap's float32 storage: half an ulp is 4.8e-7 below 16 m (8e-8 measured).
        np.testing.assert_allclose(theirs.pose, ours.pose, atol=1e-6)
    assert [(e.first, e.second, e.weight) for e in graph.edges] == [(10, 11, 0.5), (11, 12, 2.0)]
    for node in graph.nodes:
        # OctoMap's float32 quaternion arithmetic agrees with the matrix to float precision: a few float32 eps
        # (1.2e-7) of coordinates up to ~10 m, ~1e-6 (5e-7 measured).
        expected = node.points.astype(np.float64) @ node.pose[:3, :3].T + node.pose[:3, 3]
        np.testing.assert_allclose(node.world_points(), expected, atol=2e-5)
        np.testing.assert_allclose(node.origin, node.pose[:3, 3], atol=2e-5)
    # Writing what was read reproduces the file.
    again = tmp_path / "again.graph"
    write_scan_graph(again, graph.nodes, graph.edges)
    assert again.read_bytes() == path.read_bytes()
    np.testing.assert_allclose(graph.edges[0].constraint, edges[0].constraint, atol=1e-6)  # float32, as the poses


def test_truncated_graph_names_the_byte(tmp_path: Path) -> None:
    rng = np.random.default_rng(8)
    path = tmp_path / "g.graph"
    write_scan_graph(path, [ScanNode(0, np.eye(4), rng.normal(size=(10, 3)).astype(np.float32))])
    path.write_bytes(path.read_bytes()[:100])
    with pytest.raises(DatasetError, match=r"g\.graph: byte 8: file truncated reading node 0's 10 points"):
        read_scan_graph(path)


def test_quaternion_convention_is_wxyz() -> None:
    half = np.sqrt(0.5)
    pose = pose_from_wxyz([1, 2, 3], [half, 0, 0, half])  # 90° about z
    np.testing.assert_allclose(pose[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-12)  # sqrt(0.5) rounding: ~2e-16
    np.testing.assert_array_equal(pose_from_wxyz([0, 0, 0], [0, 0, 0, 0]), np.eye(4))


def test_real_scan_dat_bz2() -> None:
    points = read_xyz(_need(DATA / "scan.dat.bz2"))
    assert points.dtype == np.float32 and points.shape[1] == 3
    assert len(points) > 10_000
    np.testing.assert_allclose(points[0], [-0.0434742, -4.82982, 0.499645], rtol=1e-6)  # float32: rel 6e-8


def test_xyz_errors_name_the_line(tmp_path: Path) -> None:
    path = tmp_path / "p.xyz.bz2"
    path.write_bytes(bz2.compress(b"# comment\n1 2 3\n\n4 5 six\n"))
    with pytest.raises(DatasetError, match=r"p\.xyz\.bz2:4: expected 'x y z', found '4 5 six'"):
        read_xyz(path)
    path.write_bytes(bz2.compress(b"1 2 3\n4 5 6 7\n"))
    np.testing.assert_array_equal(read_xyz(path), [[1, 2, 3], [4, 5, 6]])


def test_scan_log_nodes(tmp_path: Path) -> None:
    path = tmp_path / "scan.log"
    path.write_text("NODE 1 2 3 0 0 1.5707963\n1 0 0\n2 0 0\nNODE 0 0 0 0 0 0\n0 0 1\n")
    nodes = read_scan_log(path)
    assert [len(n.points) for n in nodes] == [2, 1]
    # yaw 1.5707963 is π/2 − 2.7e-8: 2.7e-8 m at 1 m, plus float32 rounding (2.4e-7 at 3 m)
    np.testing.assert_allclose(nodes[0].world_points()[0], [1, 3, 3], atol=1e-6)
    path.write_text("1 2 3\n")
    with pytest.raises(DatasetError, match=r"scan\.log:1: a point before the first NODE"):
        read_scan_log(path)


def test_map_collection(tmp_path: Path) -> None:
    entries = read_map_collection(_need(DATA / "mapcoll.txt"))
    assert [e.id for e in entries] == ["cup0815", "glass", "cup08w5"]
    assert entries[0].path == DATA / "geb079.bt"
    np.testing.assert_allclose(entries[0].pose[:3, 3], [1, 2, 3])
    bad = tmp_path / "coll.txt"
    bad.write_text("MAPNODEID a\nMAPNODEPOSE 1 2 3 0 0 0\n")
    with pytest.raises(DatasetError, match=r"coll\.txt:2: expected MAPNODEFILENAME"):
        read_map_collection(bad)


def test_scan_sources_by_name(tmp_path: Path) -> None:
    from fleetslam.mapping.scan_io import load_scans, scan_kind

    assert scan_kind("a/b/scan.dat.bz2") == "xyz" and scan_kind("x.graph") == "graph"
    path = tmp_path / "p.txt"
    path.write_text("1 2 3\n")
    (scan,) = load_scans(path, origin=[1, 0, 0])
    np.testing.assert_array_equal(scan.origin, [1, 0, 0])
    np.testing.assert_array_equal(scan.world_points(), [[1, 2, 3]])
    with pytest.raises(DatasetError, match="unknown scan input kind 'nope'"):
        load_scans(path, kind="nope")
