"""Typed configuration of the simulated plant: world, Kinect-like camera, robots and their start poses."""

from __future__ import annotations

import math
from typing import Literal

from pydantic import Field

from fleetslam.config import ConfigModel
from fleetslam.robot.config import RobotConfig


class CameraConfig(ConfigModel):
    """A Kinect v1-like RGB-D camera mounted on the robot, looking forward."""

    width: int = Field(default=640, gt=0)
    """Image width, pixels."""
    height: int = Field(default=480, gt=0)
    """Image height, pixels."""
    focal_length: float = Field(default=525.0, gt=0.0)
    """Focal length in pixels at 640 px width (fx = fy); scaled with the width for other resolutions."""
    height_above_floor: float = Field(default=0.5, gt=0.0)
    """Height of the optical centre above the floor, m."""
    forward_offset: float = 0.10
    """Position of the optical centre ahead of the wheel axle, m."""
    tilt_down_deg: float = 5.0
    """Downward pitch of the optical axis, degrees (0 = horizontal)."""
    min_depth: float = Field(default=0.5, ge=0.0)
    """Nearest valid depth, m; closer pixels are invalid (0)."""
    max_depth: float = Field(default=4.5, gt=0.0)
    """Farthest valid depth, m; farther pixels are invalid (0)."""
    noise_coefficient: float = Field(default=1.43e-3, ge=0.0)
    """k in the axial noise σ(z) = k·z² (m⁻¹); quantisation counts towards it."""
    disparity_focal_length: float = Field(default=580.0, gt=0.0)
    """Focal length of the IR camera used for disparity quantisation, pixels."""
    baseline: float = Field(default=0.075, gt=0.0)
    """Projector–IR camera baseline for disparity quantisation, m."""
    disparity_step: float = Field(default=0.125, ge=0.0)
    """Disparity quantisation step, pixels (Kinect v1: 1/8); 0 disables quantisation."""
    max_incidence_deg: float = Field(default=80.0, gt=0.0, le=90.0)
    """Pixels whose surface normal is further than this from the viewing ray are invalid, degrees."""
    edge_jump: float = Field(default=0.05, ge=0.0)
    """A depth jump to a neighbour larger than this fraction of the depth marks both pixels invalid."""
    noise: bool = True
    """Apply the sensor model; False gives the rendered ground-truth depth (range limits still apply)."""


class RobotPlacement(ConfigModel):
    """One robot in the plant: its name (the MJCF name prefix and topic namespace) and start pose."""

    name: str = Field(default="c3po", pattern=r"^[A-Za-z][A-Za-z0-9_]*$")
    """Robot name (a ROS name token); MJCF names are prefixed with ``<name>/``, topics live under ``/<name>``."""
    x: float = 0.0
    """Start position x in the world, m."""
    y: float = 0.0
    """Start position y in the world, m."""
    yaw: float = 0.0
    """Start heading, rad."""
    route_start_waypoint: int = Field(default=0, ge=0)
    """Where on a closed autopilot route this robot starts: the waypoint it stands at, facing the next (0: the
    route's own start). Robots sharing a patrol start apart on it; the robot must be placed there
    (:meth:`fleetslam.robot.autopilot.Route.starting_at` gives the pose)."""


def _default_robots() -> list[RobotPlacement]:
    return [
        RobotPlacement(name="c3po", x=-12.0, y=-7.5, yaw=0.0),
        RobotPlacement(name="r2d2", x=8.0, y=8.0, yaw=math.pi),
    ]


class WorldConfig(ConfigModel):
    """The procedurally generated inspection hall."""

    length: float = Field(default=32.0, ge=30.0)
    """Hall extent along x, m."""
    width: float = Field(default=22.0, ge=20.0)
    """Hall extent along y, m."""
    wall_height: float = Field(default=4.0, gt=0.0)
    """Height of the walls, m."""
    seed: int = 7
    """Seed of the procedural textures and clutter placement."""
    texture_size: int = Field(default=256, ge=16)
    """Side of the square procedural texture images, pixels."""
    surfaces: Literal["procedural", "photographic"] = "procedural"
    """Textures of walls, floor, crates and posters: 'procedural' (generated concrete, bricks, tiles…) or
    'photographic' (scikit-image's sample photographs of brick, gravel, grass, coins, text and scenes; needs
    scikit-image): a scene unlike the one the SLAM defaults were developed on."""


class SimConfig(ConfigModel):
    """The simulator: world, physics, camera, robots."""

    world: WorldConfig = WorldConfig()
    """The hall."""
    camera: CameraConfig = CameraConfig()
    """The RGB-D camera of every robot."""
    robot: RobotConfig = RobotConfig()
    """Base geometry, limits and controller (shared with the robot stack)."""
    robots: list[RobotPlacement] = Field(default_factory=_default_robots)
    """Robots in the plant and their start poses."""
    timestep: float = Field(default=0.002, gt=0.0)
    """Physics time step, s."""
    wheel_friction: float = Field(default=0.9, ge=0.0)
    """Sliding friction coefficient between wheel and floor (wheels slip beyond it)."""
    robot_mass: float = Field(default=8.0, gt=0.0)
    """Mass of the chassis, kg."""
    noise_seed: int = 0
    """Seed of the depth-noise random generator (reproducible exports)."""
