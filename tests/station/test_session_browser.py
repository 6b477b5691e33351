"""Reviewing a finished run (``fleetslam station --session DIR``) in a real headless Chromium: the run's map, findings
and trajectory, a time slider replaying the trajectory and the recorded camera; no robot, no middleware."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from fleetslam.errors import FleetslamError
from fleetslam.geometry import make_pose
from fleetslam.inspection.findings import Finding, FindingStore
from fleetslam.inspection.run_folder import occupied_centres
from fleetslam.mapping.octree import OccupancyOctree
from fleetslam.middleware.recording import BagWriter
from fleetslam.msg.conversions import image_msg
from fleetslam.msg.typesys import serialize
from fleetslam.station.server import StationServer
from fleetslam.trajectory import Trajectory, write_tum

from .conftest import save_screenshot

SPEED = 0.2  # m/s along the camera's z (ahead)
FRAMES_HZ = 5.0


def _jpeg(colour: int) -> bytes:
    import cv2

    ok, buffer = cv2.imencode(".jpg", np.full((60, 80, 3), colour, np.uint8))
    assert ok
    return bytes(buffer.tobytes())


def make_run(run: Path) -> None:
    """A run as the demo leaves it: c3po drove 2 m ahead in 10 s towards a wall, its camera recorded (the frame of
    second t has red level 20·t), one finding on the wall."""
    stamps = np.arange(0.0, 10.0 + 1e-9, 1.0 / FRAMES_HZ)
    poses = [make_pose(translation=[0.0, 0.0, SPEED * t]) for t in stamps]
    write_tum(run / "trajectories" / "c3po.txt", Trajectory.from_lists(list(stamps), poses))
    (run / "fleet_frame.json").write_text(json.dumps({"c3po": {"T_fleet_map": np.eye(4).tolist()}}))
    wall = np.stack(np.meshgrid(np.arange(-1, 1, 0.05), np.arange(-0.5, 0.5, 0.05), [3.0]), -1).reshape(-1, 3)
    octree = OccupancyOctree(0.05)
    for _ in range(3):
        octree.insert_point_cloud(wall.astype(np.float32), np.zeros(3))
    (run / "maps").mkdir()
    octree.write_binary(run / "maps" / "c3po.bt")
    store = FindingStore(run / "findings")
    store.create(Finding(id="", title="crack in the wall", severity="high", status="open", note="", agent="c3po",
                         keyframe_id=3, point=(0.2, 0.1, 2.4), pixel=(40.0, 30.0), stamp_ns=3_000_000_000,
                         photo=_jpeg(60), crop=_jpeg(60), position=(0.2, 0.1, 3.0)))  # fmt: skip
    store.save()
    with BagWriter(run / "recording") as bag:
        wall_clock = time.time_ns()
        for t in stamps:
            pixels = np.zeros((60, 80, 3), np.uint8)
            pixels[:, :, 0] = round(20 * t)
            msg = image_msg(pixels, "rgb8", frame_id="camera", stamp_ns=round(t * 1e9))
            # Received on the wall clock, stamped on the simulated one (as the demo records).
            bag.write("/c3po/camera/rgb/image_raw", "sensor_msgs/msg/Image", wall_clock + int(t * 1e9),
                      serialize(msg, "sensor_msgs/msg/Image"))  # fmt: skip


def test_a_finished_run_is_reviewed_with_a_time_slider(browser_page: Any, tmp_path: Path) -> None:
    page, errors = browser_page
    run = tmp_path / "demo-run"
    make_run(run)
    voxels = len(occupied_centres(run / "maps" / "c3po.bt"))
    with StationServer(None, port=0, session=run) as server:
        page.goto(server.url)
        page.wait_for_function("window.fleetslam.session.data !== null", timeout=30000)
        page.wait_for_function(f"window.fleetslam.voxelCount === {voxels}", timeout=30000)
        assert page.evaluate("window.fleetslam.session.data.camera") == ["c3po"]

        def drawn(point: list[float]) -> np.ndarray:
            return np.array(page.evaluate(f"window.fleetslam.frameOf('c3po', {point}).world"))

        # The finding, where the run last knew it (c3po's map frame, placed and levelled as live).
        page.wait_for_function("Object.keys(window.fleetslam.findingMarkers()).length === 1", timeout=10000)
        marker = page.evaluate("window.fleetslam.findingMarkers()")["F001"]
        assert np.allclose(marker, drawn([0.2, 0.1, 3.0]), atol=1e-4), marker
        # Level: the map frame's "ahead" (z) is drawn horizontal, as the robot drove.
        assert abs((drawn([0, 0, 2.0]) - drawn([0, 0, 0]))[2]) < 1e-6

        # At the end of the run the marker stands where c3po ended; the slider moves it back to 4 s, scrubbed there
        # through 2 s in one go: the frames asked for are throttled, but the one where the slider stops is shown.
        assert np.allclose(page.evaluate("window.fleetslam.frameOf('c3po').marker"), drawn([0, 0, 2.0]), atol=1e-3)
        page.evaluate("() => { const s = document.getElementById('session-time'); for (const t of [2.0, 4.0])"
                      " { s.value = t; s.dispatchEvent(new Event('input')); } }")  # fmt: skip
        assert np.allclose(page.evaluate("window.fleetslam.frameOf('c3po').marker"), drawn([0, 0, 0.8]), atol=1e-3)
        # The recorded camera frame of 4 s (the 21st), red level 80.
        page.wait_for_function("window.fleetslam.lastFrameSeq === 21", timeout=10000)
        red = page.evaluate("""() => {
            const img = document.getElementById('camera'), c = document.createElement('canvas');
            c.width = img.naturalWidth; c.height = img.naturalHeight;
            const g = c.getContext('2d'); g.drawImage(img, 0, 0);
            return g.getImageData(40, 30, 1, 1).data[0]; }""")  # fmt: skip
        assert abs(red - 80) <= 4, red
        save_screenshot(page, tmp_path, "session-review.png")

        # Play replays from there on.
        page.click("#session-play")
        page.wait_for_function("window.fleetslam.session.t > 5.0", timeout=10000)
        page.click("#session-play")
    assert not errors, errors


def test_a_folder_that_is_not_a_run_is_refused_by_name(tmp_path: Path) -> None:
    (tmp_path / "notes").mkdir()
    for folder, reason in ((tmp_path / "missing", "not a directory"), (tmp_path / "notes", "not a fleetslam run")):
        with pytest.raises(FleetslamError, match=reason) as raised:
            StationServer(None, port=0, session=folder).start()
        assert str(folder) in str(raised.value)
