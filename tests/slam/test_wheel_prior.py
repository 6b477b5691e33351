"""The wheel prior's default σ against the simulated robot's own wheel odometry: a calibrated σ, neither so tight
that the wheels override the camera nor so loose that the window's adjustment ignores them."""

from __future__ import annotations

import os

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")
pytest.importorskip("mujoco")

from fleetslam.geometry import invert, pose_from_planar, rotation_angle
from fleetslam.robot.autopilot import Autopilot, get_route
from fleetslam.sim.config import SimConfig
from fleetslam.sim.plant import Plant
from fleetslam.slam.config import OdometryConfig
from fleetslam.slam.odometry import wheel_prior_std

CAMERA_HZ = 30.0


def drive(route: str, seconds: float) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Camera poses (truth) and the wheels' camera poses of the first robot along ``route``, at the camera's rate,
    as the simulator export records them."""
    config = SimConfig()
    placement = config.robots[0]
    autopilot = Autopilot.for_route(get_route(route), (placement.x, placement.y, placement.yaw), max_speed=0.6)
    truth, wheels = [], []
    with Plant(config, [placement]) as plant:
        base_camera = plant.camera_extrinsics(placement.name)
        plant.step(0.5)
        t0 = plant.sim_time
        for k in range(int(seconds * CAMERA_HZ)):
            target = t0 + k / CAMERA_HZ
            while plant.sim_time + 1e-9 < target:
                odom = plant.controller(placement.name).odometry
                v, omega, _ = autopilot.step((odom.x, odom.y, odom.theta), plant.sim_time)
                plant.command(placement.name, v, omega)
                plant.step(min(1.0 / config.robot.control_rate, target - plant.sim_time))
            odom = plant.controller(placement.name).odometry
            truth.append(plant.camera_pose(placement.name))
            wheels.append(pose_from_planar(odom.x, odom.y, odom.theta) @ base_camera)
    return truth, wheels


def test_the_default_wheel_drift_is_calibrated_on_the_simulated_wheels() -> None:
    # Keyframe-spaced steps (the odometry's default spacing) of a drive with straights and turns.
    config = OdometryConfig()
    truth, wheels = drive("survey", 40.0)
    t_ratio, r_ratio = [], []
    start = 0
    for k in range(1, len(truth)):
        moved = invert(truth[start]) @ truth[k]
        far = np.linalg.norm(moved[:3, 3]) > config.keyframe_translation
        if not (far or np.degrees(rotation_angle(moved)) > config.keyframe_rotation_deg):
            continue
        measured = invert(wheels[start]) @ wheels[k]
        error = invert(moved) @ measured
        sigma_t, sigma_r = wheel_prior_std(measured, config.wheel_drift)
        t_ratio.append(np.linalg.norm(error[:3, 3]) / sigma_t)
        r_ratio.append(rotation_angle(error) / sigma_r)
        start = k
    assert len(t_ratio) >= 40
    # Calibrated: the RMS of error/σ near 1. The wheels' error here is mostly along the track (their pose sampled
    # at the control rate, not at the camera's instant), a few millimetres per step; a σ of 3 % of the distance
    # (8 mm per 25 cm) made this 0.4-0.5 and let the camera's own drift through.
    rms_t = float(np.sqrt(np.mean(np.square(t_ratio))))
    assert 0.6 <= rms_t <= 1.6, rms_t
    # The turn's slip is systematic (one way for a whole turn): the rotation prior stays looser than calibrated.
    assert float(np.sqrt(np.mean(np.square(r_ratio)))) <= 1.0
