"""`fleetslam map ...` end to end on real files, OctoMap (octomap-python) as the oracle."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fleetslam.cli.main import main
from fleetslam.mapping.octomap_io import read_octree_file
from fleetslam.mapping.scan_io import ScanNode, write_scan_graph

octomap = pytest.importorskip("octomap", reason="octomap-python is the oracle")

DATA = Path(__file__).parents[2] / ".." / "shared" / "data" / "octomap"
GEB079 = DATA / "geb079.bt"


def _scan(seed: int, n: int = 2000) -> np.ndarray:
    """A box room seen from inside: points on walls and floor, sensor frame."""
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    # Distance to the walls of a 4 m × 3 m × 2.5 m room centred on the sensor.
    half = np.array([2.0, 1.5, 1.25])
    t = np.min(half / np.maximum(np.abs(directions), 1e-9), axis=1)
    return (directions * t[:, None]).astype(np.float32)


def test_build_from_graph_matches_octomap(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    poses = [np.eye(4), np.eye(4)]
    poses[1][:3, 3] = [0.3, -0.2, 0.1]
    nodes = [ScanNode(i, poses[i], _scan(i)) for i in range(2)]
    graph = tmp_path / "room.graph"
    write_scan_graph(graph, nodes)
    out = tmp_path / "room.bt"
    assert main(["map", "build", str(graph), "--resolution", "0.1", "-o", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "2 scans" in printed
    reference = octomap.OcTree(0.1)
    for node in nodes:
        reference.insertPointCloud(node.world_points().astype(np.float64), node.pose[:3, 3].copy())
    expected = reference.writeBinary()
    assert out.read_bytes() == expected
    in_file = octomap.OcTree(0.1)
    in_file.readBinary(expected)
    assert f" {in_file.size()} nodes" in printed  # the file's count, not the live tree's


def test_build_from_points_with_origin_and_max_range(tmp_path: Path) -> None:
    points = _scan(5, 500) + np.array([1.0, 2.0, 0.5], np.float32)
    source = tmp_path / "scan.xyz"
    source.write_text("\n".join(f"{x} {y} {z}" for x, y, z in points.tolist()))
    out = tmp_path / "scan.ot"
    argv = ["map", "build", str(source), "--origin", "1,2,0.5", "--max-range", "1.8", "--resolution", "0.1"]
    assert main([*argv, "-o", str(out), "--no-progress"]) == 0
    reference = octomap.OcTree(0.1)
    reference.insertPointCloud(np.loadtxt(source).astype(np.float32).astype(np.float64), np.array([1.0, 2.0, 0.5]), 1.8)
    ours = read_octree_file(out)
    assert ours.kind == "ot" and ours.num_nodes == reference.size()


def test_info_convert_compare(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    if not GEB079.exists():
        pytest.skip(f"{GEB079} not present (../shared/data)")
    assert main(["map", "info", str(GEB079), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    reference = octomap.OcTree(0.1)
    reference.readBinary(GEB079.read_bytes())
    assert info["nodes"] == reference.size() and info["leaves"] == reference.getNumLeafNodes()
    assert info["octomap_memory_bytes"] == reference.memoryUsage()
    # Both are key × resolution in float64 (~1e-15 apart); a key off by one would be 0.1 m off.
    np.testing.assert_allclose(info["bbox_min"], reference.getMetricMin(), atol=1e-5)
    np.testing.assert_allclose(info["bbox_max"], reference.getMetricMax(), atol=1e-5)
    ot = tmp_path / "geb.ot"
    bt = tmp_path / "geb.bt"
    assert main(["map", "convert", str(GEB079), str(ot)]) == 0
    assert main(["map", "convert", str(ot), str(bt)]) == 0
    assert bt.read_bytes() == GEB079.read_bytes()
    capsys.readouterr()
    assert main(["map", "compare", str(GEB079), str(ot), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["agreement"] == 1.0 and result["occupied_iou"] == 1.0


def test_compare_counts_disagreement(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a, b = tmp_path / "a.bt", tmp_path / "b.bt"
    tree = octomap.OcTree(0.1)
    tree.updateNode(np.array([0.05, 0.05, 0.05]), True)
    tree.updateNode(np.array([0.15, 0.05, 0.05]), False)
    a.write_bytes(tree.writeBinary())
    for _ in range(3):  # writeBinary left it at clamp_min: three hits make it occupied
        tree.updateNode(np.array([0.15, 0.05, 0.05]), True)
    tree.updateNode(np.array([0.25, 0.05, 0.05]), True)
    b.write_bytes(tree.writeBinary())
    assert main(["map", "compare", str(a), str(b), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["volume_m3"]["free/occupied"] == pytest.approx(0.001)
    assert result["volume_m3"]["unknown/occupied"] == pytest.approx(0.001)
    assert result["agreement"] == pytest.approx(1 / 3)


def test_errors_are_clear(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.bt"
    bad.write_bytes(b"not a map\n")
    assert main(["map", "info", str(bad)]) == 1
    assert "bad.bt: byte 0: expected" in capsys.readouterr().err
    assert main(["map", "build", str(bad), "-o", str(tmp_path / "x.png")]) == 2
    assert "must end in .bt or .ot" in capsys.readouterr().err
    assert main(["map", "build", str(tmp_path / "a.unknown"), "-o", str(tmp_path / "x.bt")]) == 1
    assert "unknown scan input kind" in capsys.readouterr().err


def test_build_spherical_scan_graph_like_graph2tree(tmp_path: Path) -> None:
    graph = DATA / "spherical_scan.graph"
    if not graph.exists():
        pytest.skip(f"{graph} not present (../shared/data)")
    from fleetslam.mapping.scan_io import read_scan_graph

    out = tmp_path / "spherical.bt"
    assert main(["map", "build", str(graph), "--resolution", "0.05", "-o", str(out), "--no-progress"]) == 0
    reference = octomap.OcTree(0.05)
    for node in read_scan_graph(graph):
        reference.insertPointCloud(node.world_points().astype(np.float64), node.origin)
    assert out.read_bytes() == reference.writeBinary()
