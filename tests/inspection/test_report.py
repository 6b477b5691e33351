"""The inspection report of a run written here (findings, a map, trajectories, statistics as the demo writes them):
``report.html`` and a real ``report.pdf`` printed by Debian's Chromium, rendered back with poppler."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from fleetslam.geometry import pose_from_xyz_rpy
from fleetslam.inspection.findings import Finding, FindingStore
from fleetslam.inspection.report import build_report, write_inspection_report
from fleetslam.trajectory import Trajectory, write_tum

MAGENTA = (255, 0, 255)


def _photo(colour: tuple[int, int, int]) -> bytes:
    pixels = np.zeros((240, 320, 3), dtype=np.uint8)
    pixels[:] = (40, 60, 80)
    pixels[60:180, 80:240] = colour[::-1]  # OpenCV writes BGR
    ok, data = cv2.imencode(".jpg", pixels, [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    return data.tobytes()


def _run(tmp_path: Path) -> Path:
    """A run directory as the demo leaves it, with two findings."""
    run = tmp_path / "run"
    store = FindingStore(run / "findings")
    store.create(Finding(
        id="", title="Cracked weld on <pipe> 7", severity="critical", status="", note="north flange\n2 cm long",
        agent="c3po", keyframe_id=4, point=(0.1, 0.0, 2.0), pixel=(160.0, 120.0), stamp_ns=1_764_000_000_000_000_000,
        photo=_photo(MAGENTA), crop=_photo(MAGENTA),
    ))  # fmt: skip
    store.create(Finding(
        id="", title="Missing guard", severity="low", status="", note="", agent="r2d2", keyframe_id=1,
        point=(0.0, 0.0, 1.0), pixel=(10.0, 20.0), stamp_ns=1_764_000_060_000_000_000,
    ))  # fmt: skip
    store.create(Finding(
        id="", title="Loose cable", severity="info", status="", note="", agent="c3po", keyframe_id=0,
        point=(0.0, 0.0, 1.0), pixel=(1.0, 2.0), stamp_ns=23_800_000_000,  # the simulator's clock
    ))  # fmt: skip
    store.close("F002", note="fitted")
    store.set_positions({"F001": (np.array([2.0, 1.0, 0.5]), None), "F002": (np.array([1.0, 0.0, 0.3]), None)})
    store.save()
    # r2d2's map is placed 3 m along x in the fleet frame (c3po's map), 2 cm off the truth.
    placed = pose_from_xyz_rpy(3.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    truth = pose_from_xyz_rpy(3.02, 0.0, 0.0, 0.0, 0.0, 0.0)
    (run / "fleet_frame.json").write_text(json.dumps({"r2d2": {"placed_after_s": 30.0, "T_fleet_map": placed.tolist(),
                                                                "true_T_fleet_map": truth.tolist()}}))  # fmt: skip
    (run / "start_poses.yaml").write_text(yaml.safe_dump({"fleet_frame_of": "c3po"}))
    for robot in ("c3po", "r2d2"):
        stamps = np.arange(50) * 0.1
        poses = [pose_from_xyz_rpy(0.1 * i, 0.02 * np.sin(i), 0.3, 0.0, 0.0, 0.0) for i in range(50)]
        write_tum(run / "ground_truth" / f"{robot}.txt", Trajectory.from_lists(stamps.tolist(), poses))
        noisy = [p.copy() for p in poses]
        for p in noisy[::2]:
            p[1, 3] += 0.01
        write_tum(run / "trajectories" / f"{robot}.txt", Trajectory.from_lists(stamps.tolist(), noisy))
    from fleetslam.mapping.octree import OccupancyOctree

    tree = OccupancyOctree(0.1)
    wall = np.array([[x, 2.0, z] for x in np.arange(-1, 6, 0.05) for z in np.arange(0.2, 1.2, 0.1)])
    tree.insert_point_cloud(wall, [2.0, 0.0, 0.5])
    (run / "maps").mkdir()
    tree.write_binary(run / "maps" / "fleet.bt")
    (run / "slam.json").write_text(json.dumps({"c3po": {"keyframes": "41", "loop_closures": "3"}, "r2d2": None}))
    rows = [
        {"agent": "c3po", "topic": "/c3po/keyframes", "bandwidth_bps": 12000.0, "delivered": 40, "dropped": 1},
        {"agent": "c3po", "topic": "/c3po/path", "bandwidth_bps": 800.0, "delivered": 10, "dropped": 0},
    ]
    (run / "statistics.json").write_text(json.dumps(rows))
    return run


def test_the_report_holds_every_finding_placed_in_the_fleet_frame(tmp_path: Path) -> None:
    report = build_report(_run(tmp_path))
    first, second, third = report.findings
    assert third.time == "t = 23.8 s (simulated clock)" and third.where.startswith("unknown")
    assert first.where == "(2.00, 1.00, 0.50) m in the fleet frame"  # c3po's map is the fleet frame
    assert second.where == "(4.00, 0.00, 0.30) m in the fleet frame"  # r2d2's, placed 3 m along x
    assert first.photo.startswith("data:image/jpeg;base64,") and second.photo == ""
    assert (first.time, second.time) == ("2025-11-24 16:00:00 UTC", "2025-11-24 16:01:00 UTC")
    assert report.overview.startswith("data:image/png;base64,")
    assert [row[0] for row in report.summary.rows] == ["critical", "low", "info"]
    accuracy = {row[0]: row for row in report.accuracy.rows}
    assert accuracy["r2d2"][-1] == "0.020" and accuracy["c3po"][2] == "41"
    assert 0.0 < float(accuracy["c3po"][1]) < 0.01
    assert report.network.rows == [["c3po", "12.8", "50", "1", "/c3po/keyframes (12.0 kB/s)"]]
    assert report.coverage.rows[0][0] == "fleet" and int(report.coverage.rows[0][1]) > 50


def test_report_pdf_pages_render_with_the_findings(tmp_path: Path) -> None:
    for tool in ("pdftoppm", "pdftotext"):
        if shutil.which(tool) is None:
            pytest.skip(f"{tool} is not installed (Debian: poppler-utils, scripts/setup installs it)")
    if not any(shutil.which(c) for c in ("chromium", "chromium-browser", "google-chrome")):
        pytest.skip("no Chromium to print with (scripts/setup installs Debian's)")
    run = _run(tmp_path)
    html, pdf = write_inspection_report(run)
    assert html == run / "inspection" / "report.html" and pdf == run / "inspection" / "report.pdf"
    text = html.read_text()
    assert "Cracked weld on &lt;pipe&gt; 7" in text and "<pipe>" not in text  # escaped
    assert pdf.read_bytes().startswith(b"%PDF-")
    subprocess.run(["pdftoppm", "-r", "40", "-png", str(pdf), str(tmp_path / "page")], check=True, timeout=120)
    pages = sorted(tmp_path.glob("page-*.png"))
    assert pages, "pdftoppm rendered no page"
    images = [cv2.imread(str(p))[:, :, ::-1] for p in pages]
    assert all(image.std() > 5 for image in images)  # not blank
    # The first finding's photo (a magenta block) is on a page.
    magenta = [int(np.all(np.abs(image.astype(int) - MAGENTA) < 40, axis=-1).sum()) for image in images]
    assert max(magenta) > 200, magenta
    printed = subprocess.run(["pdftotext", "-layout", str(pdf), "-"], check=True, capture_output=True, text=True,
                             timeout=60).stdout  # fmt: skip
    expected_texts = [
        "Inspection report", "Cracked weld on <pipe> 7", "F001", "Missing guard", "F002", "closed", "critical",
        "(2.00, 1.00, 0.50) m in the fleet frame", "(4.00, 0.00, 0.30) m in the fleet frame", "north flange",
        "fitted", "Coverage", "Accuracy per robot", "Network", "/c3po/keyframes",
    ]  # fmt: skip
    for expected in expected_texts:
        assert expected in printed, expected
