"""The sim node: the plant in (scaled) real time, publishing cameras, ground truth and /clock.

Per robot, in its namespace ``/<robot>``: ``camera/rgb/image_raw`` (sensor_msgs/Image rgb8),
``camera/depth/image_raw`` (32FC1, metres, 0 = invalid), ``camera/rgb/camera_info`` and
``camera/depth/camera_info`` (plumb_bob, zero distortion), ``ground_truth/odom`` (nav_msgs/Odometry of
base_link in the ``world`` frame) and ``tf_static`` (base_link → camera_optical_frame). The robot stack's
:class:`~fleetslam.robot.node.BaseControllerNode` runs in-process on the simulated wheels (``cmd_vel`` in;
``odom``, ``joint_states``, ``tf`` out; ``e_stop``), stepped in simulated time. ``/clock``
(rosgraph_msgs/Clock) carries simulated time; the node logs its real-time factor.
"""

from __future__ import annotations

import logging
import signal
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from fleetslam import topics
from fleetslam.drivers.node import OPTICAL_FRAME, image_messages
from fleetslam.errors import ConfigError
from fleetslam.middleware import Context, Node, Publisher
from fleetslam.msg.conversions import camera_info_msg, odometry_msg, pose_msg, transform_msg
from fleetslam.msg.typesys import get_type, stamp_from_ns
from fleetslam.robot.autopilot import Autopilot, Route, get_route
from fleetslam.robot.node import BaseControllerNode
from fleetslam.sim.config import RobotPlacement, SimConfig
from fleetslam.sim.plant import Plant
from fleetslam.trajectory import tum_line

log = logging.getLogger(__name__)

#: After an operator's `cmd_vel`, the autopilot leaves the robot to them for this long (s, simulated time).
OPERATOR_TAKEOVER_S = 3.0
WORLD_FRAME = "world"


def _publisher(node: Node, topic: topics.Topic) -> Publisher:
    return node.create_publisher(topic.type, topic.name, topic.qos())


def _autopilot(route: Route, placement: RobotPlacement, laps: bool) -> Autopilot:
    """The robot's autopilot on ``route`` from its placement's waypoint, in its odometry frame (which starts at
    its start pose)."""
    try:
        own_route = route.starting_at(placement.route_start_waypoint)[0]
    except ConfigError as err:
        raise ConfigError(f"robot {placement.name}: route_start_waypoint: {err}") from err
    return Autopilot.for_route(own_route, (0.0, 0.0, 0.0), cyclic=laps)


@dataclass
class _RobotIo:
    node: Node
    base: BaseControllerNode
    rgb_pub: Any
    depth_pub: Any
    rgb_info_pub: Any
    depth_info_pub: Any
    truth_pub: Any
    autopilot: Autopilot | None = None


class SimNode:
    """Runs a :class:`Plant` on the middleware (one node per robot plus ``/sim``).

    Args:
        context: the middleware context.
        plant: a plant built with ``controllers=False`` (the controller nodes drive the wheels).
        camera_hz: camera rate in simulated time.
        width, height: camera resolution (default: the plant's configuration).
        rate: simulated seconds per wall second (0 or less: as fast as possible).
        autopilot: name of a route every robot follows from its odometry (None: wait for cmd_vel).
        laps: drive a closed route lap after lap (a patrol) instead of once.
        truth_hz: rate of ground_truth/odom and /clock, simulated Hz.
        ground_truth_dir: also write each robot's ground truth (base_link in world, TUM, at ``truth_hz``) to
            ``<dir>/<robot>.txt``: an evaluation that needs the truth reads it here rather than take every sample
            off the network (the demo's monitor did: a third of what it received).
    """

    def __init__(
        self,
        context: Context,
        plant: Plant,
        *,
        camera_hz: float = 10.0,
        width: int | None = None,
        height: int | None = None,
        rate: float = 1.0,
        autopilot: str | None = None,
        laps: bool = False,
        truth_hz: float = 50.0,
        ground_truth_dir: Path | None = None,
    ) -> None:
        self.context = context
        self.plant = plant
        self.camera_period = 1.0 / camera_hz
        self.truth_period = 1.0 / truth_hz
        self.width = width or plant.config.camera.width
        self.height = height or plant.config.camera.height
        self.intrinsics = plant.intrinsics_at(self.width, self.height)
        self.rate = rate
        self.sim_node = Node("sim", context=context, namespace="/", statistics_period_s=0)
        self.clock_pub = _publisher(self.sim_node, topics.CLOCK)
        route = get_route(autopilot) if autopilot else None
        self.robots: dict[str, _RobotIo] = {}
        self._static_tf: list[Any] = []
        for name in plant.robot_names:
            node = Node("sim_robot", context=context, namespace=f"/{name}", statistics_period_s=0)
            base = BaseControllerNode(
                node, plant.wheels(name), config=plant.config.robot, clock=lambda: plant.sim_time, run_timer=False
            )
            self.robots[name] = _RobotIo(
                node=node,
                base=base,
                rgb_pub=_publisher(node, topics.RGB_IMAGE),
                depth_pub=_publisher(node, topics.DEPTH_IMAGE),
                rgb_info_pub=_publisher(node, topics.CAMERA_INFO),
                depth_info_pub=_publisher(node, topics.DEPTH_CAMERA_INFO),
                truth_pub=_publisher(node, topics.GROUND_TRUTH_ODOM),
                autopilot=_autopilot(route, plant.robot(name).placement, laps) if route is not None else None,
            )
            static_tf = _publisher(node, topics.TF_STATIC)
            static_tf.publish(transform_msg(plant.camera_extrinsics(name), "base_link", OPTICAL_FRAME, 0))
            self._static_tf.append(static_tf)
        self.frames_published = 0
        self.real_time_factor = 0.0
        self._truth_files: dict[str, TextIO] = {}
        if ground_truth_dir is not None:
            ground_truth_dir.mkdir(parents=True, exist_ok=True)
            for name in self.robots:
                truth_file = (ground_truth_dir / f"{name}.txt").open("a", encoding="utf-8")  # a restart appends
                if truth_file.tell() == 0:
                    truth_file.write("# timestamp tx ty tz qx qy qz qw (base_link in world)\n")
                self._truth_files[name] = truth_file

    def _control(self, now: float) -> None:
        for io in self.robots.values():
            external = io.base.last_external_command
            operator_driving = external is not None and now - external < OPERATOR_TAKEOVER_S
            if io.autopilot is not None and not io.autopilot.done and not operator_driving:
                odom = io.base.controller.odometry
                v, omega, _ = io.autopilot.step((odom.x, odom.y, odom.theta), now)
                io.base.controller.command(v, omega, now, now)
            io.base.step(now)

    def _publish_truth(self, now: float) -> None:
        stamp_ns = round(now * 1e9)
        self.clock_pub.publish(get_type("rosgraph_msgs/msg/Clock")(clock=stamp_from_ns(stamp_ns)))
        for name, io in self.robots.items():
            linear, angular = self.plant.base_twist(name)
            base_pose = self.plant.base_pose(name)
            truth = pose_msg(base_pose)
            truth_file = self._truth_files.get(name)
            if truth_file is not None:
                truth_file.write(tum_line(now, base_pose, digits=9))
            io.truth_pub.publish(
                odometry_msg(truth, frame_id=WORLD_FRAME, child_frame_id="base_link", stamp_ns=stamp_ns,
                             linear=linear, angular=angular)
            )  # fmt: skip

    def _publish_cameras(self) -> None:
        for name, io in self.robots.items():
            frame = self.plant.render(name, width=self.width, height=self.height)
            rgb, depth = image_messages(frame, OPTICAL_FRAME)  # the simulator's cameras are drivers like any
            info = camera_info_msg(self.intrinsics, frame_id=OPTICAL_FRAME, stamp_ns=round(frame.stamp * 1e9))
            io.rgb_pub.publish(rgb)
            io.depth_pub.publish(depth)
            io.rgb_info_pub.publish(info)
            io.depth_info_pub.publish(info)
            self.frames_published += 1

    def run(self, duration: float | None = None, stop: threading.Event | None = None, log_period: float = 5.0) -> None:
        """Simulate until ``duration`` simulated seconds passed, ``stop`` is set or the context closes."""
        plant = self.plant
        control_period = 1.0 / plant.config.robot.control_rate
        start_sim = plant.sim_time
        start_wall = time.monotonic()
        try:
            self._loop(duration, stop, log_period, control_period, start_sim, start_wall)
        finally:
            self.plant.close()  # GL contexts must be released by the thread that rendered
        elapsed = time.monotonic() - start_wall
        if elapsed > 0:
            self.real_time_factor = (plant.sim_time - start_sim) / elapsed

    def _loop(
        self,
        duration: float | None,
        stop: threading.Event | None,
        log_period: float,
        control_period: float,
        start_sim: float,
        start_wall: float,
    ) -> None:
        plant = self.plant
        next_camera = next_truth = plant.sim_time
        last_log_wall, last_log_sim = start_wall, start_sim
        while not (stop is not None and stop.is_set()) and not self.context.closed:
            now = plant.sim_time
            if duration is not None and now - start_sim >= duration - 1e-9:
                break
            if now + 1e-9 >= next_truth:
                self._publish_truth(now)
                next_truth += self.truth_period
            if now + 1e-9 >= next_camera:
                self._publish_cameras()
                next_camera += self.camera_period
            self._control(now)
            plant.step(control_period)
            wall = time.monotonic()
            if self.rate > 0:
                ahead = (plant.sim_time - start_sim) / self.rate - (wall - start_wall)
                if ahead > 0:
                    time.sleep(ahead)
            if wall - last_log_wall >= log_period:
                self.real_time_factor = (plant.sim_time - last_log_sim) / (wall - last_log_wall)
                log.info("sim time %.1f s, real-time factor %.2f", plant.sim_time, self.real_time_factor)
                last_log_wall, last_log_sim = wall, plant.sim_time

    def close(self) -> None:
        for truth_file in self._truth_files.values():
            truth_file.close()
        self._truth_files.clear()
        for io in self.robots.values():
            io.node.destroy()
        self.sim_node.destroy()


def run_sim_node(
    config: SimConfig,
    *,
    robots: Sequence[str] | None = None,
    camera_hz: float = 10.0,
    width: int | None = None,
    height: int | None = None,
    rate: float = 1.0,
    autopilot: str | None = None,
    laps: bool = False,
    duration: float | None = None,
    ground_truth_dir: Path | None = None,
) -> int:
    """``fleetslam sim run``: the plant with the named robots (default: all configured) until Ctrl-C."""
    placements = list(config.robots)
    if robots is not None:
        known = {p.name: p for p in placements}
        missing = [r for r in robots if r not in known]
        if missing:
            from fleetslam.errors import ConfigError

            raise ConfigError(
                f"--robots: {', '.join(missing)} not in the simulator configuration (configured: {', '.join(known)})"
            )
        placements = [known[r] for r in robots]
    stop = threading.Event()
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, lambda *_: stop.set())  # supervisors stop us with SIGTERM
    with Context() as ctx, Plant(config, placements, controllers=False) as plant:
        sim = SimNode(
            ctx,
            plant,
            camera_hz=camera_hz,
            width=width,
            height=height,
            rate=rate,
            autopilot=autopilot,
            laps=laps,
            ground_truth_dir=ground_truth_dir,
        )
        log.info(
            "simulating %s at %s×%s, camera %.1f Hz, rate %.2f",
            ", ".join(plant.robot_names),
            sim.width,
            sim.height,
            camera_hz,
            rate,
        )
        try:
            sim.run(duration, stop)
        except KeyboardInterrupt:
            pass
        finally:
            sim.close()
    log.info("stopped at sim time %.1f s, real-time factor %.2f", plant.sim_time, sim.real_time_factor)
    return 0
