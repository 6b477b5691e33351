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


@pytest.mark.parametrize("speed", [0.3, 0.8])
def test_watchdog_has_the_robot_stopped_within_the_timeout_at_any_speed(speed: float) -> None:
    """Issue 18, D6: the base kept full speed for the whole timeout and only then braked (0.71-1.09 s to stop). Now
    the set-point reaches zero by the last command's deadline, and the wheels stand within it."""
    config = RobotConfig()
    ctrl, wheels = BaseController(config), MotorWheels()
    period = 0.05  # a 20 Hz command stream, the console's
    outputs: list[ControllerOutput] = []
    last_command = 0.0
    for k in range(round(3.0 / DT)):
        now = k * DT
        if now >= last_command + period - 1e-9 or k == 0:
            assert ctrl.command(speed, 0.0, stamp=now, now=now)
            last_command = now
        outputs.append(ctrl.update(now, wheels))
        wheels.advance(DT)
    # Full speed as long as the stream holds, up to what can still be braked within the timeout after each command.
    period = 3 * DT  # commands are sent on control steps: every third one
    early = 2.0 / config.control_rate  # the set-point is zero this much before the deadline
    # Between commands the bound falls from decel·(timeout − early) to decel·(timeout − early − period): a sawtooth.
    lowest = min(speed, config.linear.max_deceleration * (config.cmd_vel_timeout - early - period))
    highest = min(speed, config.linear.max_deceleration * (config.cmd_vel_timeout - early))
    assert all(lowest - 0.02 <= o.odometry.v <= highest + 0.02 for o in outputs[-25:])
    start = 3.0 - DT + DT  # the link is cut: no command after last_command
    after = _run(ctrl, wheels, start, 1.5)
    times = [start + k * DT for k in range(len(after))]
    deadline = last_command + config.cmd_vel_timeout - early
    for o, t in zip(after, times, strict=True):
        if t >= deadline - 1e-9:
            assert o.command == (0.0, 0.0)
    stopped = next(t for o, t in zip(after, times, strict=True) if abs(o.odometry.v) < 0.01)
    assert stopped - last_command <= config.cmd_vel_timeout  # the wheels themselves
    vs = [o.command[0] for o in [*outputs, *after]]
    assert max(a - b for a, b in itertools.pairwise(vs)) <= config.linear.max_deceleration * DT + 1e-9  # round-off
    assert abs(after[-1].odometry.v) < 0.01


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
    outputs = _run(ctrl, wheels, t, 0.5)  # moves again, and that one command is braked away within its timeout
    assert max(o.command[0] for o in outputs) > 0.1 and outputs[-1].command == (0.0, 0.0)


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
