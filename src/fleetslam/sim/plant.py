"""The simulated plant: MuJoCo physics of the hall and its robots, wheel drives, RGB-D rendering, ground truth.

Each robot has a :class:`SimWheels` (the robot stack's :class:`~fleetslam.robot.interfaces.WheelInterface`)
and a :class:`~fleetslam.robot.controller.BaseController` run in simulated time at its control rate;
:meth:`Plant.command` feeds it velocity commands. Rendering reuses one ``mujoco.Renderer`` per resolution
with shadows, reflections and skybox off.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fleetslam._imports import require
from fleetslam.errors import SimulationError
from fleetslam.geometry import invert, make_pose, yaw_of
from fleetslam.intrinsics import Intrinsics
from fleetslam.robot.controller import BaseController, ControllerOutput
from fleetslam.sim.camera import KinectModel, intrinsics_from_config, kinect_from_config
from fleetslam.sim.config import RobotPlacement, SimConfig
from fleetslam.sim.rendering import RGBDRenderer
from fleetslam.sim.robot_model import RobotNames, robot_xml
from fleetslam.sim.world import build_world, world_xml

log = logging.getLogger(__name__)

#: MuJoCo camera frame (x right, y up, looking along -z) → optical frame (x right, y down, z forward).
T_MJCAM_OPTICAL = make_pose(np.diag([1.0, -1.0, -1.0]))

ROBOT_COLORS = ((0.85, 0.65, 0.1), (0.2, 0.45, 0.85), (0.75, 0.2, 0.2), (0.3, 0.7, 0.3))


def import_mujoco() -> Any:
    """Import MuJoCo, selecting a headless GL backend (EGL) unless one was chosen."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    return require("mujoco", "sim")


@dataclass(frozen=True)
class RGBDFrame:
    """One camera frame: colour, measured depth, time and where the optical frame was."""

    rgb: NDArray[np.uint8]
    """(H, W, 3) RGB."""
    depth: NDArray[np.float32]
    """(H, W) z-depth in metres, 0 = invalid."""
    stamp: float
    """Simulated time, s."""
    T_world_camera: NDArray[np.float64]
    """Pose of the optical frame (x right, y down, z forward) in the world."""
    intrinsics: Intrinsics


class SimWheels:
    """The two wheel drives of one robot in the MuJoCo model (a WheelInterface)."""

    def __init__(self, model: Any, data: Any, names: RobotNames, max_torque: float) -> None:
        mujoco = import_mujoco()
        self._data = data
        self.max_torque = max_torque
        joints = [
            mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n)
            for n in (names.left_wheel_joint, names.right_wheel_joint)
        ]
        motors = [
            mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, n) for n in (names.left_motor, names.right_motor)
        ]
        self._qpos = [int(model.jnt_qposadr[j]) for j in joints]
        self._qvel = [int(model.jnt_dofadr[j]) for j in joints]
        self._ctrl = motors

    def wheel_positions(self) -> tuple[float, float]:
        return float(self._data.qpos[self._qpos[0]]), float(self._data.qpos[self._qpos[1]])

    def wheel_velocities(self) -> tuple[float, float]:
        return float(self._data.qvel[self._qvel[0]]), float(self._data.qvel[self._qvel[1]])

    def apply_wheel_efforts(self, left: float, right: float) -> None:
        limit = self.max_torque
        self._data.ctrl[self._ctrl[0]] = float(np.clip(left, -limit, limit))
        self._data.ctrl[self._ctrl[1]] = float(np.clip(right, -limit, limit))


@dataclass
class SimRobot:
    """One robot's handles in the plant."""

    placement: RobotPlacement
    names: RobotNames
    wheels: SimWheels
    controller: BaseController
    body_id: int
    camera_id: int
    rng: np.random.Generator
    controller_enabled: bool = True
    last_output: ControllerOutput | None = None
    next_control: float = 0.0


class Plant:
    """The hall with its robots.

    Args:
        config: simulator configuration (world, camera, robot base, timestep).
        robots: robots to place; defaults to ``config.robots``.
        controllers: run each robot's BaseController in simulated time (else drive wheels directly).
    """

    def __init__(
        self,
        config: SimConfig | None = None,
        robots: Sequence[RobotPlacement] | None = None,
        *,
        controllers: bool = True,
    ) -> None:
        mujoco = import_mujoco()
        self._mujoco = mujoco
        self.config = config if config is not None else SimConfig()
        placements = list(robots) if robots is not None else list(self.config.robots)
        if not placements:
            raise SimulationError("the plant needs at least one robot")
        names = [p.name for p in placements]
        if len(set(names)) != len(names):
            raise SimulationError(f"robot names must be unique, got {names}")
        cam = self.config.camera
        self.intrinsics = intrinsics_from_config(cam)
        builder = build_world(self.config.world)
        bodies, actuators = [], []
        for k, placement in enumerate(placements):
            body, act = robot_xml(
                placement,
                self.config.robot,
                cam,
                fovy_deg=self.intrinsics.fovy_deg,
                mass=self.config.robot_mass,
                wheel_friction=self.config.wheel_friction,
                color=ROBOT_COLORS[k % len(ROBOT_COLORS)],
            )
            bodies.append(body)
            actuators.append(act)
        offscreen = (max(cam.width, 640), max(cam.height, 480))
        self.xml = world_xml(builder, bodies, actuators, timestep=self.config.timestep, offscreen=offscreen)
        try:
            self.model = mujoco.MjModel.from_xml_string(self.xml, builder.assets)
        except ValueError as err:
            raise SimulationError(f"MuJoCo rejected the generated plant model: {err}") from err
        self.data = mujoco.MjData(self.model)
        mujoco.mj_forward(self.model, self.data)
        self.robots: dict[str, SimRobot] = {}
        for k, placement in enumerate(placements):
            rn = RobotNames(placement.name)
            controller = BaseController(self.config.robot)
            controller.reset_odometry(placement.x, placement.y, placement.yaw)
            self.robots[placement.name] = SimRobot(
                placement=placement,
                names=rn,
                wheels=SimWheels(self.model, self.data, rn, self.config.robot.max_wheel_torque),
                controller=controller,
                body_id=mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, rn.base),
                camera_id=mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_CAMERA, rn.camera),
                rng=np.random.default_rng([self.config.noise_seed, k]),
                controller_enabled=controllers,
            )
        self._renderers: dict[tuple[int, int], RGBDRenderer] = {}
        self._kinects: dict[tuple[int, int], KinectModel] = {}

    # -- time and physics -------------------------------------------------------------------------------
    @property
    def sim_time(self) -> float:
        """Simulated time, s."""
        return float(self.data.time)

    @property
    def robot_names(self) -> list[str]:
        return list(self.robots)

    def robot(self, name: str) -> SimRobot:
        try:
            return self.robots[name]
        except KeyError as err:
            raise SimulationError(f"no robot {name!r} in the plant; robots: {', '.join(self.robots)}") from err

    def wheels(self, name: str) -> SimWheels:
        """The WheelInterface of robot ``name``."""
        return self.robot(name).wheels

    def controller(self, name: str) -> BaseController:
        """The base controller of robot ``name``."""
        return self.robot(name).controller

    def command(self, name: str, v: float, omega: float, stamp: float | None = None) -> bool:
        """Offer a velocity command to robot ``name``'s base controller (stamped now unless given)."""
        now = self.sim_time
        return self.robot(name).controller.command(v, omega, now if stamp is None else stamp, now)

    def step(self, duration: float) -> None:
        """Advance physics by ``duration`` seconds (whole timesteps), running controllers at their rate."""
        mujoco = self._mujoco
        dt = self.model.opt.timestep
        period = 1.0 / self.config.robot.control_rate
        steps = max(round(duration / dt), 1) if duration > 0 else 0
        for _ in range(steps):
            now = self.sim_time
            for robot in self.robots.values():
                if robot.controller_enabled and now + 1e-9 >= robot.next_control:
                    robot.last_output = robot.controller.update(now, robot.wheels)
                    robot.next_control += period
                    if robot.next_control <= now:
                        robot.next_control = now + period
            mujoco.mj_step(self.model, self.data)

    # -- ground truth -----------------------------------------------------------------------------------
    def base_pose(self, name: str) -> NDArray[np.float64]:
        """T_world_base_link (4×4) of robot ``name``."""
        robot = self.robot(name)
        return make_pose(self.data.xmat[robot.body_id].reshape(3, 3), self.data.xpos[robot.body_id])

    def camera_pose(self, name: str) -> NDArray[np.float64]:
        """T_world_optical (4×4) of robot ``name``'s camera (x right, y down, z forward)."""
        robot = self.robot(name)
        T_world_mjcam = make_pose(
            self.data.cam_xmat[robot.camera_id].reshape(3, 3), self.data.cam_xpos[robot.camera_id]
        )
        return T_world_mjcam @ T_MJCAM_OPTICAL

    def camera_extrinsics(self, name: str) -> NDArray[np.float64]:
        """T_base_link_optical (4×4): where the camera's optical frame sits on robot ``name``."""
        return invert(self.base_pose(name)) @ self.camera_pose(name)

    def ground_truth(self, name: str) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(T_world_base_link, T_world_optical) of robot ``name``."""
        return self.base_pose(name), self.camera_pose(name)

    def planar_pose(self, name: str) -> tuple[float, float, float]:
        """(x, y, yaw) of robot ``name``'s base in the world."""
        pose = self.base_pose(name)
        return float(pose[0, 3]), float(pose[1, 3]), yaw_of(pose)

    def base_twist(self, name: str) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(linear, angular) velocity of the base in its own frame, m/s and rad/s."""
        robot = self.robot(name)
        vel = np.zeros(6)
        self._mujoco.mj_objectVelocity(self.model, self.data, self._mujoco.mjtObj.mjOBJ_XBODY, robot.body_id, vel, 1)
        return vel[3:].copy(), vel[:3].copy()

    # -- rendering --------------------------------------------------------------------------------------
    def _renderer(self, width: int, height: int) -> RGBDRenderer:
        key = (width, height)
        renderer = self._renderers.get(key)
        if renderer is None:
            vis = self.model.vis.global_
            vis.offwidth = max(width, vis.offwidth)
            vis.offheight = max(height, vis.offheight)
            try:
                renderer = RGBDRenderer(self._mujoco, self.model, width, height)
            except Exception as err:
                raise SimulationError(f"cannot create a {width}x{height} MuJoCo renderer: {err}") from err
            self._renderers[key] = renderer
        return renderer

    def intrinsics_at(self, width: int | None = None, height: int | None = None) -> Intrinsics:
        """The camera intrinsics at a resolution (default: the configured one)."""
        return intrinsics_from_config(self.config.camera, width, height)

    def kinect(self, width: int, height: int) -> KinectModel:
        key = (width, height)
        if key not in self._kinects:
            self._kinects[key] = kinect_from_config(self.config.camera, self.intrinsics_at(width, height))
        return self._kinects[key]

    def render(
        self,
        name: str,
        *,
        width: int | None = None,
        height: int | None = None,
        noise: bool | None = None,
    ) -> RGBDFrame:
        """Render robot ``name``'s camera: RGB and depth (with the Kinect model unless ``noise`` is False).

        The field of view follows the configured focal length at every resolution (fovy is set per call).
        """
        cam = self.config.camera
        w = cam.width if width is None else width
        h = cam.height if height is None else height
        robot = self.robot(name)
        intrinsics = self.intrinsics_at(w, h)
        self.model.cam_fovy[robot.camera_id] = intrinsics.fovy_deg
        image, depth_true = self._renderer(w, h).render(self.data, robot.camera_id)
        apply_noise = cam.noise if noise is None else noise
        if apply_noise:
            depth = self.kinect(w, h).apply(depth_true, robot.rng)
        else:
            depth = np.where((depth_true >= cam.min_depth) & (depth_true <= cam.max_depth), depth_true, 0.0)
            depth = depth.astype(np.float32)
        return RGBDFrame(image, depth, self.sim_time, self.camera_pose(name), intrinsics)

    def close(self) -> None:
        """Release the renderers (GL contexts); call it from the thread that rendered.

        An EGL context stays current on the thread that last rendered with it, so another thread can neither
        use nor free it; renderers are recreated on the next :meth:`render`.
        """
        for key, renderer in list(self._renderers.items()):
            try:
                renderer.close()
            except Exception as err:  # a context still current on another thread; leak it rather than crash
                log.warning("could not release the %dx%d renderer: %s", key[0], key[1], err)
        self._renderers.clear()

    def __enter__(self) -> Plant:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
