"""The base controller's default gains on the MuJoCo plant's wheel motors (the drive they are tuned for)."""

from __future__ import annotations

import math

import pytest

pytest.importorskip("mujoco")

from fleetslam.sim.config import RobotPlacement, SimConfig
from fleetslam.sim.plant import Plant


def test_default_gains_track_and_brake_on_the_simulated_robot() -> None:
    plant = Plant(SimConfig(), robots=[RobotPlacement(name="c3po", x=0.0, y=0.0, yaw=0.0)])
    outputs = []
    while plant.sim_time < 4.0:
        if plant.sim_time < 2.5:
            plant.command("c3po", 0.5, 0.8 if plant.sim_time > 1.0 else 0.0)
        plant.step(0.02)
        out = plant.robot("c3po").last_output
        assert out is not None
        outputs.append((plant.sim_time, out))
    straight = [o for t, o in outputs if 0.8 < t < 1.0]
    assert all(abs(o.odometry.v - 0.5) < 0.05 for o in straight)
    turning = [o for t, o in outputs if 1.8 < t < 2.5]
    assert all(abs(o.odometry.v - 0.5) < 0.05 and abs(o.odometry.omega - 0.8) < 0.08 for o in turning)
    # commands stop at 2.5 s: timeout 0.5 s, then braking at 1.5 m/s² takes 0.33 s
    stopped = [o for t, o in outputs if t > 3.5]
    assert all(o.command == (0.0, 0.0) and abs(o.odometry.v) < 0.03 for o in stopped)
    assert math.isfinite(stopped[-1].odometry.x)
