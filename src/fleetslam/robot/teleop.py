"""Teleoperation logic (pure): keyboard layout and joystick mapping to (v, ω), with release/loss handling.

The keyboard layout is teleop_twist_keyboard's non-holonomic one::

    u    i    o
    j    k    l
    m    ,    .

q/z scale both speeds by ±10 %, w/x the linear one, e/c the angular one. A terminal sends no key-up
events, so a key counts as held while its auto-repeat keeps arriving: after a first press the keyboard's
initial repeat delay (``initial_repeat_delay``) may pass before the repeats start, then ``repeat_timeout``
without a repeat means the key was released and the command drops to zero.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from pydantic import Field

from fleetslam.config import ConfigModel, load_config, read_yaml
from fleetslam.errors import ConfigError

#: key → (linear direction, angular direction)
MOVE_BINDINGS: dict[str, tuple[int, int]] = {
    "i": (1, 0),
    "o": (1, -1),
    "j": (0, 1),
    "l": (0, -1),
    "u": (1, 1),
    ",": (-1, 0),
    ".": (-1, 1),
    "m": (-1, -1),
}
#: key → (linear factor, angular factor)
SPEED_BINDINGS: dict[str, tuple[float, float]] = {
    "q": (1.1, 1.1),
    "z": (0.9, 0.9),
    "w": (1.1, 1.0),
    "x": (0.9, 1.0),
    "e": (1.0, 1.1),
    "c": (1.0, 0.9),
}
STOP_KEYS = frozenset({"k", " "})

KEYBOARD_HELP = """\
Moving around:        Speed:
   u    i    o        q/z : all speeds ±10%
   j    k    l        w/x : linear speed ±10%
   m    ,    .        e/c : angular speed ±10%
k or space: stop      Ctrl-C: quit (publishes zero)
"""


class KeyboardTeleop:
    """Key presses in, (v, ω) out.

    Args:
        speed: initial linear speed, m/s.
        turn: initial angular speed, rad/s.
        max_speed: cap of ``speed``.
        max_turn: cap of ``turn``.
        repeat_timeout: a repeating movement key counts as released after this long without a repeat, s.
        initial_repeat_delay: the same after a first press, before auto-repeat has started, s.
    """

    def __init__(
        self,
        *,
        speed: float = 0.3,
        turn: float = 0.8,
        max_speed: float = 0.8,
        max_turn: float = 1.5,
        repeat_timeout: float = 0.2,
        initial_repeat_delay: float = 0.6,
    ) -> None:
        self.max_speed = max_speed
        self.max_turn = max_turn
        self.speed = min(speed, max_speed)
        self.turn = min(turn, max_turn)
        self.repeat_timeout = repeat_timeout
        self.initial_repeat_delay = initial_repeat_delay
        self._direction = (0, 0)
        self._last_key: str | None = None
        self._last_key_time: float | None = None
        self._repeating = False

    def on_key(self, key: str, now: float) -> None:
        """Handle one key (a single character) read at ``now`` (s)."""
        if key in MOVE_BINDINGS:
            self._repeating = (
                key == self._last_key
                and self._last_key_time is not None
                and now - self._last_key_time <= self.initial_repeat_delay
            )
            self._direction = MOVE_BINDINGS[key]
            self._last_key = key
            self._last_key_time = now
        elif key in SPEED_BINDINGS:
            lin, ang = SPEED_BINDINGS[key]
            self.speed = min(self.speed * lin, self.max_speed)
            self.turn = min(self.turn * ang, self.max_turn)
        elif key in STOP_KEYS:
            self._direction = (0, 0)
            self._last_key = None
            self._last_key_time = None

    def tick(self, now: float) -> tuple[float, float]:
        """The (v, ω) to publish at ``now``: the held key's motion, or zero once it has been released."""
        timeout = self.repeat_timeout if self._repeating else self.initial_repeat_delay
        if self._last_key_time is None or now - self._last_key_time > timeout:
            self._direction = (0, 0)
            self._last_key = None
            self._last_key_time = None
            return 0.0, 0.0
        lin, ang = self._direction
        return lin * self.speed, ang * self.turn

    def status(self) -> str:
        """One line with the current speed scales."""
        return f"speed {self.speed:.2f} m/s  turn {self.turn:.2f} rad/s"


class JoyPreset(ConfigModel):
    """Axis/button mapping of one gamepad layout, as teleop_twist_joy's parameters."""

    axis_linear: int = 1
    """Axis index driving the linear velocity (left stick vertical)."""
    axis_angular: int = 0
    """Axis index driving the angular velocity (left stick horizontal)."""
    scale_linear: float = -0.4
    """Linear velocity per unit of axis, m/s; negative because SDL reports stick-up as −1."""
    scale_angular: float = -1.0
    """Angular velocity per unit of axis, rad/s; negative because SDL reports stick-left as −1."""
    scale_linear_turbo: float = -0.8
    """Linear velocity per unit of axis while the turbo button is held, m/s."""
    scale_angular_turbo: float = -1.5
    """Angular velocity per unit of axis while the turbo button is held, rad/s."""
    enable_button: int = 4
    """Deadman button index: motion only while it is held (left bumper)."""
    enable_turbo_button: int = 5
    """Turbo button index (right bumper); -1 disables turbo."""
    require_enable_button: bool = True
    """Whether the deadman button is required."""
    deadzone: float = Field(default=0.1, ge=0.0, lt=1.0)
    """Axis values with smaller magnitude count as zero; the rest is rescaled to start at zero."""
    inactivity_timeout: float = Field(default=2.0, gt=0.0)
    """Publish zero when no joystick event arrived for this long (a frozen driver), s."""
    rate: float = Field(default=20.0, gt=0.0)
    """Publication rate while the robot is being driven, Hz."""


def _axis(axes: Sequence[float], index: int, deadzone: float) -> float:
    if index < 0 or index >= len(axes):
        return 0.0
    value = float(axes[index])
    if not math.isfinite(value) or abs(value) <= deadzone:
        return 0.0
    return math.copysign((min(abs(value), 1.0) - deadzone) / (1.0 - deadzone), value)


def _pressed(buttons: Sequence[int], index: int) -> bool:
    return 0 <= index < len(buttons) and bool(buttons[index])


class JoyMapper:
    """Axes and buttons in, (v, ω) out, with deadman and turbo buttons."""

    def __init__(self, preset: JoyPreset | None = None) -> None:
        self.preset = preset if preset is not None else JoyPreset()

    def map(self, axes: Sequence[float], buttons: Sequence[int]) -> tuple[float, float]:
        """(v, ω) for the current axes (−1..1) and buttons (0/1); zero unless deadman or turbo is held."""
        p = self.preset
        turbo = _pressed(buttons, p.enable_turbo_button)
        enabled = turbo or not p.require_enable_button or _pressed(buttons, p.enable_button)
        if not enabled:
            return 0.0, 0.0
        scale_v = p.scale_linear_turbo if turbo else p.scale_linear
        scale_w = p.scale_angular_turbo if turbo else p.scale_angular
        v = scale_v * _axis(axes, p.axis_linear, p.deadzone)
        omega = scale_w * _axis(axes, p.axis_angular, p.deadzone)
        return v + 0.0, omega + 0.0


JOY_PRESETS: dict[str, JoyPreset] = {
    # Xbox 360/One pads on Linux (xpad driver): LB deadman, RB turbo, left stick drives
    "xbox": JoyPreset(),
    # DualShock 4 / DualSense (hid-playstation driver order): L1 deadman, R1 turbo, left stick drives
    "ps": JoyPreset(enable_button=4, enable_turbo_button=5, deadzone=0.08),
}
"""Built-in gamepad layouts; config/joy_presets.yaml holds the same values for editing."""


class CommandGate:
    """Publishes motion, then ``zero_repeats`` zero commands when it stops, then stays silent.

    Silence once stopped lets other operators (station, autopilot) drive the robot; the repeated zeros make the
    stop survive a lost sample.
    """

    def __init__(self, zero_repeats: int = 3) -> None:
        self.zero_repeats = zero_repeats
        self._zeros_left = 0

    def filter(self, command: tuple[float, float]) -> tuple[float, float] | None:
        """The command to publish this tick, or None to publish nothing."""
        if command != (0.0, 0.0):
            self._zeros_left = self.zero_repeats
            return command
        if self._zeros_left > 0:
            self._zeros_left -= 1
            return 0.0, 0.0
        return None

    def force_stop(self) -> None:
        """Publish zeros on the next ticks even if nothing moved (device lost, quitting)."""
        self._zeros_left = self.zero_repeats


class JoyWatchdog:
    """Forces zero at once when the device is lost or no event arrives for ``inactivity_timeout`` s."""

    def __init__(self, inactivity_timeout: float = 2.0) -> None:
        self.inactivity_timeout = inactivity_timeout
        self._last_event: float | None = None
        self.connected = False

    def on_event(self, now: float) -> None:
        """A joystick event arrived at ``now``."""
        self._last_event = now
        self.connected = True

    def on_device_lost(self) -> None:
        """The device disappeared."""
        self.connected = False
        self._last_event = None

    def active(self, now: float) -> bool:
        """Whether joystick commands may be published at ``now`` (else publish zero)."""
        return self.connected and self._last_event is not None and now - self._last_event <= self.inactivity_timeout


class JoyTeleop:
    """The joystick teleop's whole decision logic: mapping, watchdog and publication gate.

    The driver loop reports events and device changes and calls :meth:`tick` at the preset's rate with the
    current axes and buttons; :meth:`tick` returns what to publish (None: nothing).
    """

    def __init__(self, preset: JoyPreset | None = None, *, zero_repeats: int = 3) -> None:
        self.mapper = JoyMapper(preset)
        self.watchdog = JoyWatchdog(self.mapper.preset.inactivity_timeout)
        self.gate = CommandGate(zero_repeats)
        self._was_active = False

    def on_event(self, now: float) -> None:
        """Any joystick event (axis, button, hat, device added) at ``now``."""
        self.watchdog.on_event(now)

    def on_device_lost(self) -> None:
        """The device disappeared: the next tick publishes zero."""
        self.watchdog.on_device_lost()
        self.gate.force_stop()

    def tick(self, now: float, axes: Sequence[float], buttons: Sequence[int]) -> tuple[float, float] | None:
        """The command to publish at ``now`` for the device state, or None."""
        active = self.watchdog.active(now)
        if self._was_active and not active:
            self.gate.force_stop()
        self._was_active = active
        command = self.mapper.map(axes, buttons) if active else (0.0, 0.0)
        return self.gate.filter(command)


def load_joy_preset(spec: str) -> JoyPreset:
    """A preset by built-in name (``xbox``, ``ps``), a YAML file holding one preset (``pad.yaml``), or a named
    section of a presets file (``config/joy_presets.yaml:ps``).

    Raises:
        ConfigError: unknown name, unreadable file, or invalid keys/values (naming file, key and value).
    """
    if spec in JOY_PRESETS:
        return JOY_PRESETS[spec].model_copy()
    path, _, section = spec.partition(":") if not Path(spec).exists() else (spec, "", "")
    if not Path(path).exists():
        raise ConfigError(
            f"joystick preset {spec!r}: neither a built-in preset ({', '.join(sorted(JOY_PRESETS))}) nor a file"
        )
    if section and section not in read_yaml(path):
        raise ConfigError(f"{path}: no preset named {section!r}")
    return load_config(JoyPreset, path, section=section or None)
