"""Teleoperation drivers: a raw-mode terminal keyboard and an SDL joystick (pygame), publishing cmd_vel.

The decisions (key layout, release detection, deadman/turbo, device loss) live in the pure
:mod:`fleetslam.robot.teleop`; this module only reads devices, keeps time and publishes.
"""

from __future__ import annotations

import logging
import os
import select
import sys
import threading
import time
from collections.abc import Callable
from typing import Any, TextIO

from fleetslam._imports import require
from fleetslam.errors import FleetslamError
from fleetslam.middleware import Node
from fleetslam.msg.typesys import get_type, header
from fleetslam.robot.teleop import KEYBOARD_HELP, CommandGate, JoyPreset, JoyTeleop, KeyboardTeleop
from fleetslam.topics import CMD_VEL, CMD_VEL_STAMPED

log = logging.getLogger(__name__)

_QUIT_KEYS = frozenset({"\x03", "\x04"})  # Ctrl-C, Ctrl-D (raw mode delivers them as characters)


class TwistPublisher:
    """Publishes (v, ω) as geometry_msgs/msg/Twist, or TwistStamped when ``stamped``."""

    def __init__(
        self, node: Node, topic: str = CMD_VEL.name, *, stamped: bool = False, frame_id: str = "base_link"
    ) -> None:
        self.node = node
        self.stamped = stamped
        self.frame_id = frame_id
        self._twist = get_type("geometry_msgs/msg/Twist")
        self._vector = get_type("geometry_msgs/msg/Vector3")
        self._stamped = get_type("geometry_msgs/msg/TwistStamped")
        contract = CMD_VEL_STAMPED if stamped else CMD_VEL
        self.publisher = node.create_publisher(contract.type, topic, contract.qos())

    @property
    def topic(self) -> str:
        return self.publisher.topic

    def publish(self, v: float, omega: float) -> None:
        twist = self._twist(
            linear=self._vector(x=float(v), y=0.0, z=0.0), angular=self._vector(x=0.0, y=0.0, z=float(omega))
        )
        if self.stamped:
            self.publisher.publish(self._stamped(header=header(self.frame_id, self.node.now_ns()), twist=twist))
        else:
            self.publisher.publish(twist)


def run_keyboard(
    publisher: TwistPublisher,
    teleop: KeyboardTeleop,
    *,
    rate: float = 10.0,
    stdin: TextIO | None = None,
    out: TextIO | None = None,
    stop: threading.Event | None = None,
) -> None:
    """Drive from the terminal until Ctrl-C / Ctrl-D (or ``stop``); always publishes zero on the way out.

    Raises:
        FleetslamError: stdin is not a terminal.
    """
    import termios
    import tty

    stdin = stdin if stdin is not None else sys.stdin
    out = out if out is not None else sys.stderr
    if not stdin.isatty():
        raise FleetslamError("teleop keyboard: standard input is not a terminal; run it in an interactive shell")
    fd = stdin.fileno()
    saved = termios.tcgetattr(fd)
    gate = CommandGate()
    period = 1.0 / rate
    out.write(KEYBOARD_HELP + f"publishing on {publisher.topic}\n{teleop.status()}\n")
    out.flush()
    try:
        tty.setraw(fd)
        next_tick = time.monotonic()
        while stop is None or not stop.is_set():
            ready, _, _ = select.select([fd], [], [], max(0.0, next_tick - time.monotonic()))
            now = time.monotonic()
            if ready:
                keys = os.read(fd, 64).decode(errors="ignore")
                if any(k in _QUIT_KEYS for k in keys):
                    break
                for key in keys:
                    before = teleop.status()
                    teleop.on_key(key, now)
                    if teleop.status() != before:
                        out.write(f"\r{teleop.status()}   \r\n")
                        out.flush()
            if now >= next_tick:
                next_tick = max(next_tick + period, now)
                command = gate.filter(teleop.tick(now))
                if command is not None:
                    publisher.publish(*command)
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)
        publisher.publish(0.0, 0.0)


def _import_pygame() -> Any:
    # SDL needs no window or sound for joysticks; set before pygame initialises SDL
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    os.environ.setdefault("SDL_AUDIODRIVER", "dummy")
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    return require("pygame", "teleop")


def run_joystick(
    publisher: TwistPublisher,
    preset: JoyPreset,
    *,
    device_index: int = 0,
    stop: threading.Event | None = None,
    clock: Callable[[], float] = time.monotonic,
) -> None:
    """Drive from an SDL joystick until Ctrl-C (or ``stop``); publishes zero at once when the device is lost,
    goes silent for ``preset.inactivity_timeout``, or on the way out. Waits for a device to appear."""
    pygame = _import_pygame()
    pygame.display.init()
    pygame.joystick.init()
    teleop = JoyTeleop(preset)
    joystick: Any = None
    period = 1.0 / preset.rate
    log.info("waiting for joystick %d; publishing on %s", device_index, publisher.topic)
    try:
        while stop is None or not stop.is_set():
            now = clock()
            for event in pygame.event.get():
                if event.type == pygame.JOYDEVICEADDED and joystick is None and event.device_index == device_index:
                    joystick = pygame.joystick.Joystick(event.device_index)
                    log.info("joystick connected: %s", joystick.get_name())
                    teleop.on_event(now)
                elif event.type == pygame.JOYDEVICEREMOVED:
                    if joystick is not None and event.instance_id == joystick.get_instance_id():
                        log.warning("joystick lost: stopping the robot")
                        joystick = None
                        teleop.on_device_lost()
                elif event.type in (
                    pygame.JOYAXISMOTION,
                    pygame.JOYBUTTONDOWN,
                    pygame.JOYBUTTONUP,
                    pygame.JOYHATMOTION,
                ):
                    teleop.on_event(now)
            if joystick is not None:
                axes = [joystick.get_axis(i) for i in range(joystick.get_numaxes())]
                buttons = [joystick.get_button(i) for i in range(joystick.get_numbuttons())]
            else:
                axes, buttons = [], []
            command = teleop.tick(now, axes, buttons)
            if command is not None:
                publisher.publish(*command)
            time.sleep(max(0.0, period - (clock() - now)))
    finally:
        publisher.publish(0.0, 0.0)
        pygame.joystick.quit()
        pygame.display.quit()
