from __future__ import annotations

import itertools

import pytest

from fleetslam.robot.config import RobotConfig
from fleetslam.robot.controller import BaseController, ControllerOutput
from fleetslam.robot.interfaces import WheelInterface

from .wheel_model import MotorWheels

DT = 0.02


def _run(ctrl: BaseController, wheels: MotorWheels, start: float, duration: float) -> list[ControllerOutput]:
    outputs = []
    for k in range(round(duration / DT)):
        now = start + k * DT
        outputs.append(ctrl.update(now, wheels))
        wheels.advance(DT)
    return outputs


def test_motor_model_is_a_wheel_interface() -> None:
    assert isinstance(MotorWheels(), WheelInterface)


def test_tracks_a_command_and_odometry_follows() -> None:
    ctrl, wheels = BaseController(), MotorWheels()
    t = 0.0
    outputs: list[ControllerOutput] = []
    while t < 3.0:  # a teleop publishing at 10 Hz
        assert ctrl.command(0.4, 0.5, stamp=t, now=t + 0.01)
        outputs += _run(ctrl, wheels, t, 0.1)
        t += 0.1
    last = outputs[-1]
    assert last.command == pytest.approx((0.4, 0.5))
    # The PI loops leave no steady-state error (2e-13 measured after 3 s); 0.02 and 0.03 are 5 % and 6 %.
    assert last.odometry.v == pytest.approx(0.4, abs=0.02)
    assert last.odometry.omega == pytest.approx(0.5, abs=0.03)
    assert not last.timed_out
    # acceleration within limits: the limited v never grows faster than 0.8 m/s²
    vs = [o.command[0] for o in outputs]
    assert max(b - a for a, b in itertools.pairwise(vs)) <= 0.8 * DT + 1e-9  # + round-off of v + a·dt (~1e-17)


def test_watchdog_brakes_to_zero_within_timeout_and_deceleration() -> None:
    config = RobotConfig()
    ctrl, wheels = BaseController(config), MotorWheels()
    t = 0.0
    while t < 2.0:
        ctrl.command(0.8, 0.0, stamp=t, now=t)
        _run(ctrl, wheels, t, 0.1)
        t += 0.1
    last_command = t - 0.1
    outputs = _run(ctrl, wheels, t, 2.0)
    times = [t + k * DT for k in range(len(outputs))]
    # still driving until the timeout, then braking within the deceleration limit
    moving = [o for o, tt in zip(outputs, times, strict=True) if tt - last_command <= config.cmd_vel_timeout]
    assert all(o.command[0] == pytest.approx(0.8) for o in moving)
    braking_time = 0.8 / config.linear.max_deceleration
    stop_deadline = last_command + config.cmd_vel_timeout + braking_time + 2 * DT
    for o, tt in zip(outputs, times, strict=True):
        if tt > stop_deadline:
            assert o.command == (0.0, 0.0)
            assert o.timed_out
    vs = [o.command[0] for o in outputs]
    assert max(a - b for a, b in itertools.pairwise(vs)) <= config.linear.max_deceleration * DT + 1e-9  # round-off
    assert abs(outputs[-1].odometry.v) < 0.01  # the wheels really stopped (7e-7 m/s measured)


def test_stale_and_out_of_order_commands_are_dropped() -> None:
    ctrl = BaseController(RobotConfig(cmd_vel_timeout=0.5))
    assert not ctrl.command(0.5, 0.0, stamp=10.0, now=10.6)
    assert ctrl.timed_out(10.6)
    assert ctrl.command(0.5, 0.0, stamp=10.5, now=10.6)
    assert not ctrl.command(0.1, 0.0, stamp=10.4, now=10.6)
    assert not ctrl.command(float("nan"), 0.0, stamp=10.6, now=10.6)
    assert ctrl.dropped_commands == 3


def test_estop_latches_zero_until_released() -> None:
    ctrl, wheels = BaseController(), MotorWheels()
    t = 0.0
    while t < 1.5:
        ctrl.command(0.6, 0.0, stamp=t, now=t)
        _run(ctrl, wheels, t, 0.1)
        t += 0.1
    assert wheels.wheel_velocities()[0] > 5.0  # 0.6 m/s on 0.075 m wheels is 8 rad/s
    ctrl.estop(True)
    for _ in range(10):  # commands keep coming, all refused
        assert not ctrl.command(0.6, 0.0, stamp=t, now=t)
        outputs = _run(ctrl, wheels, t, 0.1)
        t += 0.1
        assert all(o.estopped and o.command == (0.0, 0.0) and o.setpoints == (0.0, 0.0) for o in outputs)
    assert abs(wheels.wheel_velocities()[0]) < 0.05  # 1 s at zero set-point: 4e-4 rad/s measured, 0.05 = 0.6 % of 8
    ctrl.estop(False)
    out = _run(ctrl, wheels, t, 0.2)[-1]  # released, but no fresh command yet: stays stopped
    assert out.command == (0.0, 0.0)
    t += 0.2
    assert ctrl.command(0.3, 0.0, stamp=t, now=t)
    out = _run(ctrl, wheels, t, 0.46)[-1]  # within the timeout of that one command
    assert out.command[0] == pytest.approx(0.3)


def test_efforts_respect_the_torque_limit() -> None:
    config = RobotConfig(max_wheel_torque=0.5)
    ctrl, wheels = BaseController(config), MotorWheels()
    ctrl.command(0.8, 1.5, stamp=0.0, now=0.0)
    outputs = _run(ctrl, wheels, 0.0, 0.4)
    assert max(abs(e) for o in outputs for e in o.efforts) <= 0.5  # clipped: exactly the limit at most


def test_future_stamp_cannot_keep_the_robot_moving() -> None:
    ctrl = BaseController(RobotConfig(cmd_vel_timeout=0.5))
    assert ctrl.command(0.5, 0.0, stamp=100.0, now=1.0)
    assert not ctrl.timed_out(1.4)
    assert ctrl.timed_out(1.6)
