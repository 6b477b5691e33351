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
from typing import Any

import numpy as np

from fleetslam.geometry import pose_to_quat
from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.middleware.conversions import transform_msg
from fleetslam.middleware.typesys import get_type, header, stamp_from_ns
from fleetslam.robot.autopilot import Autopilot, get_route
from fleetslam.robot.node import BaseControllerNode
from fleetslam.sim.camera import CameraIntrinsics
from fleetslam.sim.config import SimConfig
from fleetslam.sim.plant import Plant, RGBDFrame

log = logging.getLogger(__name__)

OPTICAL_FRAME = "camera_optical_frame"
#: After an operator's `cmd_vel`, the autopilot leaves the robot to them for this long (s, simulated time).
OPERATOR_TAKEOVER_S = 3.0
WORLD_FRAME = "world"


def camera_info_msg(intrinsics: CameraIntrinsics, frame_id: str, stamp_ns: int) -> Any:
    """sensor_msgs/msg/CameraInfo of an ideal pinhole camera."""
    k = intrinsics
    roi = get_type("sensor_msgs/msg/RegionOfInterest")(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return get_type("sensor_msgs/msg/CameraInfo")(
        header=header(frame_id, stamp_ns),
        height=k.height,
        width=k.width,
        distortion_model="plumb_bob",
        d=np.zeros(5),
        k=k.K.reshape(9).astype(np.float64),
        r=np.eye(3).reshape(9),
        p=np.array([k.fx, 0.0, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0]),
        binning_x=0,
        binning_y=0,
        roi=roi,
    )


def image_msgs(frame: RGBDFrame, frame_id: str) -> tuple[Any, Any]:
    """(rgb8 Image, 32FC1 Image) of a frame."""
    image_type = get_type("sensor_msgs/msg/Image")
    stamp_ns = round(frame.stamp * 1e9)
    h, w = frame.depth.shape
    rgb = image_type(
        header=header(frame_id, stamp_ns),
        height=h,
        width=w,
        encoding="rgb8",
        is_bigendian=0,
        step=w * 3,
        data=np.ascontiguousarray(frame.rgb).reshape(-1),
    )
    depth = image_type(
        header=header(frame_id, stamp_ns),
        height=h,
        width=w,
        encoding="32FC1",
        is_bigendian=0,
        step=w * 4,
        data=np.ascontiguousarray(frame.depth, dtype="<f4").view(np.uint8).reshape(-1),
    )
    return rgb, depth


def odometry_msg(pose: np.ndarray, linear: np.ndarray, angular: np.ndarray, stamp_ns: int) -> Any:
    """nav_msgs/msg/Odometry of a ground-truth pose (world frame) and body twist."""
    t, q = pose_to_quat(pose)
    T = get_type
    vec3 = T("geometry_msgs/msg/Vector3")
    return T("nav_msgs/msg/Odometry")(
        header=header(WORLD_FRAME, stamp_ns),
        child_frame_id="base_link",
        pose=T("geometry_msgs/msg/PoseWithCovariance")(
            pose=T("geometry_msgs/msg/Pose")(
                position=T("geometry_msgs/msg/Point")(x=float(t[0]), y=float(t[1]), z=float(t[2])),
                orientation=T("geometry_msgs/msg/Quaternion")(
                    x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])
                ),
            ),
            covariance=np.zeros(36),
        ),
        twist=T("geometry_msgs/msg/TwistWithCovariance")(
            twist=T("geometry_msgs/msg/Twist")(
                linear=vec3(x=float(linear[0]), y=float(linear[1]), z=float(linear[2])),
                angular=vec3(x=float(angular[0]), y=float(angular[1]), z=float(angular[2])),
            ),
            covariance=np.zeros(36),
        ),
    )


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
        self.clock_pub = self.sim_node.create_publisher("rosgraph_msgs/msg/Clock", "/clock", QoSProfile(depth=1))
        route = get_route(autopilot) if autopilot else None
        self.robots: dict[str, _RobotIo] = {}
        self._static_tf: list[Any] = []
        for name in plant.robot_names:
            node = Node("sim_robot", context=context, namespace=f"/{name}", statistics_period_s=0)
            base = BaseControllerNode(
                node, plant.wheels(name), config=plant.config.robot, clock=lambda: plant.sim_time, run_timer=False
            )
            sensor_qos = QoSProfile(depth=2)
            self.robots[name] = _RobotIo(
                node=node,
                base=base,
                rgb_pub=node.create_publisher("sensor_msgs/msg/Image", "camera/rgb/image_raw", sensor_qos),
                depth_pub=node.create_publisher("sensor_msgs/msg/Image", "camera/depth/image_raw", sensor_qos),
                rgb_info_pub=node.create_publisher("sensor_msgs/msg/CameraInfo", "camera/rgb/camera_info", sensor_qos),
                depth_info_pub=node.create_publisher(
                    "sensor_msgs/msg/CameraInfo", "camera/depth/camera_info", sensor_qos
                ),
                truth_pub=node.create_publisher("nav_msgs/msg/Odometry", "ground_truth/odom", QoSProfile(depth=10)),
                autopilot=Autopilot.for_route(route, (0.0, 0.0, 0.0), cyclic=laps) if route is not None else None,
            )
            static_tf = node.create_publisher(
                "tf2_msgs/msg/TFMessage", "tf_static", QoSProfile(durability="transient_local", depth=1)
            )
            static_tf.publish(transform_msg(plant.camera_extrinsics(name), "base_link", OPTICAL_FRAME, 0))
            self._static_tf.append(static_tf)
        self.frames_published = 0
        self.real_time_factor = 0.0

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
            io.truth_pub.publish(odometry_msg(self.plant.base_pose(name), linear, angular, stamp_ns))

    def _publish_cameras(self) -> None:
        for name, io in self.robots.items():
            frame = self.plant.render(name, width=self.width, height=self.height)
            rgb, depth = image_msgs(frame, OPTICAL_FRAME)
            info = camera_info_msg(self.intrinsics, OPTICAL_FRAME, round(frame.stamp * 1e9))
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
            ctx, plant, camera_hz=camera_hz, width=width, height=height, rate=rate, autopilot=autopilot, laps=laps
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
