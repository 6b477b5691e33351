"""The inspection report's top-down view of a fleet frame that is a camera's frame (z ahead, y down)."""

from __future__ import annotations

import numpy as np
import pytest

from fleetslam.geometry import pose_from_xyz_rpy
from fleetslam.inspection.report import levelling_rotation

#: base_link → camera optical frame of a level camera (z ahead along the base's x, y down).
OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@pytest.mark.parametrize("pitch", [0.0, 0.1])
def test_a_ground_robots_camera_frames_level_to_z_up(pitch: float) -> None:
    """Cameras on a robot driving on a floor, seen in the first camera's frame: levelled, their heights agree and the
    first camera looks along x."""
    tilt = pose_from_xyz_rpy(0, 0, 0, 0, pitch, 0)[:3, :3]  # the camera pitched down on its mount
    mount = tilt @ OPTICAL
    route = [(3 * np.cos(a), 2 * np.sin(a), a + np.pi / 2) for a in np.linspace(0, 2 * np.pi, 24)]  # an ellipse
    world_cameras = [pose_from_xyz_rpy(x, y, 0.5, 0, 0, yaw)[:3, :3] @ mount for x, y, yaw in route]
    first = world_cameras[0]
    in_fleet = np.stack([first.T @ r for r in world_cameras])  # the fleet frame is the first camera's
    positions = np.array([first.T @ (np.array([x, y, 0.5]) - [route[0][0], route[0][1], 0.5]) for x, y, _ in route])
    level = levelling_rotation(in_fleet, positions)
    assert level @ level.T == pytest.approx(np.eye(3), abs=1e-9) and np.linalg.det(level) == pytest.approx(1.0)
    world_up_in_fleet = first.T @ np.array([0.0, 0.0, 1.0])
    assert level @ world_up_in_fleet == pytest.approx([0.0, 0.0, 1.0], abs=1e-9)
    without_positions = levelling_rotation(in_fleet) @ world_up_in_fleet  # the cameras' own up: at most the pitch off
    assert np.arccos(min(1.0, without_positions[2])) <= pitch + 1e-6  # (a lap's headings average most of it away)
    heading = level @ (first.T @ np.array([1.0, 0.0, 0.0]))  # the robots' mean heading is not the first's here
    assert heading[2] == pytest.approx(0.0, abs=1e-9)


def test_no_cameras_falls_back_to_the_optical_convention() -> None:
    level = levelling_rotation(np.zeros((0, 3, 3)))
    assert level @ np.array([0.0, -1.0, 0.0]) == pytest.approx([0.0, 0.0, 1.0])
    assert level @ np.array([0.0, 0.0, 1.0]) == pytest.approx([1.0, 0.0, 0.0])
