"""MJCF of the differential-drive robot: chassis on a free joint, two motor-driven wheels, two casters, camera.

The body frame ``<name>/base_link`` sits on the floor below the wheel axle midpoint (x forward, y left, z up),
so its planar pose is what odometry estimates. Wheels are hinge joints about +y (positive = forward) driven
by torque motors clipped at the configured torque limit; their floor friction is finite so they can slip.
Wheels and casters have contact priority over the floor, so their own friction applies: the wheels grip
with ``wheel_friction``, the casters (condim 1) touch the floor without friction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from fleetslam.robot.config import RobotConfig
from fleetslam.sim.config import CameraConfig, RobotPlacement

CHASSIS_HALF = (0.22, 0.16, 0.06)
"""Half extents of the chassis box, m."""
WHEEL_HALF_WIDTH = 0.02
CASTER_RADIUS = 0.03
CASTER_OFFSET = 0.17


@dataclass(frozen=True)
class RobotNames:
    """MJCF names of one robot's parts (all prefixed with ``<robot>/``)."""

    robot: str

    def _n(self, part: str) -> str:
        return f"{self.robot}/{part}"

    @property
    def base(self) -> str:
        return self._n("base_link")

    @property
    def root_joint(self) -> str:
        return self._n("root")

    @property
    def left_wheel_joint(self) -> str:
        return self._n("left_wheel_joint")

    @property
    def right_wheel_joint(self) -> str:
        return self._n("right_wheel_joint")

    @property
    def left_motor(self) -> str:
        return self._n("left_motor")

    @property
    def right_motor(self) -> str:
        return self._n("right_motor")

    @property
    def camera(self) -> str:
        return self._n("camera")


def robot_xml(
    placement: RobotPlacement,
    robot: RobotConfig,
    camera: CameraConfig,
    *,
    fovy_deg: float,
    mass: float,
    wheel_friction: float,
    color: tuple[float, float, float] = (0.85, 0.55, 0.1),
) -> tuple[str, str]:
    """(worldbody fragment, actuator fragment) of one robot."""
    names = RobotNames(placement.name)
    r = robot.wheel_radius
    half_sep = robot.wheel_separation / 2.0
    cz = r + CHASSIS_HALF[2] * 0.5
    tilt = math.radians(camera.tilt_down_deg)
    s, c = math.sin(tilt), math.cos(tilt)
    rgba = f"{color[0]} {color[1]} {color[2]} 1"
    quat_yaw = f"{math.cos(placement.yaw / 2)} 0 0 {math.sin(placement.yaw / 2)}"
    torque = robot.max_wheel_torque
    wheel_mass = 0.6
    body = f"""
    <body name="{names.base}" pos="{placement.x} {placement.y} 0.002" quat="{quat_yaw}">
      <freejoint name="{names.root_joint}"/>
      <geom name="{names.robot}/chassis" type="box" size="{CHASSIS_HALF[0]} {CHASSIS_HALF[1]} {CHASSIS_HALF[2]}"
            pos="0 0 {cz}" mass="{mass}" rgba="{rgba}" contype="1" conaffinity="1"/>
      <geom name="{names.robot}/mast" type="cylinder" size="0.02 {camera.height_above_floor / 2}"
            pos="{camera.forward_offset - 0.06} 0 {camera.height_above_floor / 2}" mass="0.3" rgba="0.2 0.2 0.2 1"
            contype="0" conaffinity="0"/>
      <geom name="{names.robot}/kinect" type="box" size="0.03 0.14 0.02"
            pos="{camera.forward_offset - 0.035} 0 {camera.height_above_floor}" mass="0.2" rgba="0.05 0.05 0.05 1"
            contype="0" conaffinity="0"/>
      <camera name="{names.camera}" pos="{camera.forward_offset} 0 {camera.height_above_floor}"
              xyaxes="0 -1 0 {s} 0 {c}" fovy="{fovy_deg}"/>
      <body name="{names.robot}/left_wheel" pos="0 {half_sep} {r}">
        <joint name="{names.left_wheel_joint}" type="hinge" axis="0 1 0" damping="0.005" armature="0.002"/>
        <geom type="cylinder" size="{r} {WHEEL_HALF_WIDTH}" quat="0.7071068 0.7071068 0 0" mass="{wheel_mass}"
              friction="{wheel_friction} 0.005 0.0001" condim="3" priority="1" rgba="0.1 0.1 0.1 1"/>
      </body>
      <body name="{names.robot}/right_wheel" pos="0 {-half_sep} {r}">
        <joint name="{names.right_wheel_joint}" type="hinge" axis="0 1 0" damping="0.005" armature="0.002"/>
        <geom type="cylinder" size="{r} {WHEEL_HALF_WIDTH}" quat="0.7071068 0.7071068 0 0" mass="{wheel_mass}"
              friction="{wheel_friction} 0.005 0.0001" condim="3" priority="1" rgba="0.1 0.1 0.1 1"/>
      </body>
      <geom name="{names.robot}/front_caster" type="sphere" size="{CASTER_RADIUS}"
            pos="{CASTER_OFFSET} 0 {CASTER_RADIUS}" mass="0.1" friction="0 0 0" condim="1" priority="1"
            rgba="0.6 0.6 0.6 1"/>
      <geom name="{names.robot}/rear_caster" type="sphere" size="{CASTER_RADIUS}"
            pos="{-CASTER_OFFSET} 0 {CASTER_RADIUS}" mass="0.1" friction="0 0 0" condim="1" priority="1"
            rgba="0.6 0.6 0.6 1"/>
    </body>"""
    actuators = f"""
    <motor name="{names.left_motor}" joint="{names.left_wheel_joint}" gear="1" ctrllimited="true"
           ctrlrange="{-torque} {torque}"/>
    <motor name="{names.right_motor}" joint="{names.right_wheel_joint}" gear="1" ctrllimited="true"
           ctrlrange="{-torque} {torque}"/>"""
    return body, actuators
