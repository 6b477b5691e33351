"""Export a simulated drive as a TUM RGB-D dataset folder.

The robot follows a named route with the autopilot (pure pursuit → base controller → wheel torques →
physics); frames are rendered at ``camera_hz`` in simulated time. Written files: ``rgb/*.png``,
``depth/*.png`` (uint16, metres × 5000, 0 = invalid), ``rgb.txt``, ``depth.txt``, ``associations.txt``,
``groundtruth.txt`` (T_world_optical at every frame), ``odometry.txt`` (the camera pose from the wheel
odometry, T_odom_optical, at every frame), ``base_camera.txt`` (T_base_link_optical, 4×4), ``camera.txt``,
``intrinsics.yaml`` and the ``sim_config.yaml`` used.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from numpy.typing import NDArray

from fleetslam._imports import require
from fleetslam.config import dump_config
from fleetslam.errors import DatasetError, SimulationError
from fleetslam.geometry import pose_from_planar
from fleetslam.intrinsics import Intrinsics
from fleetslam.robot.autopilot import Autopilot, get_route
from fleetslam.sim.config import SimConfig
from fleetslam.sim.plant import Plant
from fleetslam.trajectory import Trajectory, write_tum

log = logging.getLogger(__name__)

DEPTH_SCALE = 5000.0
"""TUM depth PNG units per metre."""


@dataclass(frozen=True)
class ExportResult:
    """What :func:`export_tum` wrote."""

    path: Path
    frames: int
    duration: float
    """Simulated seconds covered by the frames."""
    route_completed: bool
    intrinsics: Intrinsics
    groundtruth: Trajectory
    """T_world_optical at every frame."""


def depth_to_png16(depth: NDArray[np.floating], scale: float = DEPTH_SCALE) -> NDArray[np.uint16]:
    """Metric depth (0/NaN invalid) → TUM 16-bit units (0 = invalid, saturating at 65535)."""
    d = np.nan_to_num(np.asarray(depth, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    return np.clip(np.round(d * scale), 0, 65535).astype(np.uint16)


def write_camera_files(out: Path, intrinsics: Intrinsics, depth_scale: float = DEPTH_SCALE) -> None:
    """``camera.txt`` (one line: fx fy cx cy width height depth_scale) and ``intrinsics.yaml``."""
    k = intrinsics
    (out / "camera.txt").write_text(
        "# fx fy cx cy width height depth_scale\n"
        f"{k.fx:.6f} {k.fy:.6f} {k.cx:.6f} {k.cy:.6f} {k.width} {k.height} {depth_scale:g}\n",
        encoding="utf-8",
    )
    data = {
        "fx": k.fx,
        "fy": k.fy,
        "cx": k.cx,
        "cy": k.cy,
        "width": k.width,
        "height": k.height,
        "depth_scale": depth_scale,
        "distortion_model": "plumb_bob",
        "D": [0.0] * 5,
    }
    (out / "intrinsics.yaml").write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")


def export_tum(
    out_dir: str | Path,
    *,
    config: SimConfig | None = None,
    robot: str = "c3po",
    route: str = "loop",
    frames: int | None = None,
    width: int | None = None,
    height: int | None = None,
    camera_hz: float = 30.0,
    max_speed: float = 0.6,
    max_duration: float = 600.0,
    settle: float = 0.5,
    progress: bool = True,
) -> ExportResult:
    """Drive ``robot`` along ``route`` in the plant and write a TUM RGB-D folder to ``out_dir``.

    Stops after ``frames`` frames, or (if None) when the route is completed, or after ``max_duration``
    simulated seconds. Only the exported robot is placed in the plant; it stands still for ``settle`` seconds
    before the first frame (stamps are simulated time, so they start at ``settle``).
    """
    cv2 = require("cv2", "sim")
    from tqdm import tqdm

    cfg = config if config is not None else SimConfig()
    placements = [p for p in cfg.robots if p.name == robot]
    if not placements:
        raise SimulationError(
            f"robot {robot!r} is not in the simulator configuration (robots: {', '.join(p.name for p in cfg.robots)})"
        )
    if camera_hz <= 0:
        raise SimulationError(f"camera rate must be > 0 Hz, got {camera_hz}")
    out = Path(out_dir)
    try:
        (out / "rgb").mkdir(parents=True, exist_ok=True)
        (out / "depth").mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise DatasetError(f"{out}: cannot create the export folder: {err.strerror}") from err
    placement = placements[0]
    w = cfg.camera.width if width is None else width
    h = cfg.camera.height if height is None else height
    autopilot = Autopilot.for_route(get_route(route), (placement.x, placement.y, placement.yaw), max_speed=max_speed)
    control_period = 1.0 / cfg.robot.control_rate
    frame_period = 1.0 / camera_hz
    stamps: list[float] = []
    poses: list[NDArray[np.float64]] = []
    wheel_poses: list[NDArray[np.float64]] = []
    rgb_lines: list[str] = []
    depth_lines: list[str] = []
    assoc_lines: list[str] = []
    completed = False
    with Plant(cfg, [placement]) as plant:
        intrinsics = plant.intrinsics_at(w, h)
        base_camera = plant.camera_extrinsics(robot)
        bar = tqdm(total=frames, unit="frame", desc=f"export {route}", disable=not progress)
        plant.step(settle)  # let the robot settle on its wheels before the first frame
        t0 = plant.sim_time
        k = 0
        while frames is None or k < frames:
            target = t0 + k * frame_period
            while plant.sim_time + 1e-9 < target:
                # the autopilot steers on wheel odometry, as on the real robot (slip makes it drift)
                odom = plant.controller(robot).odometry
                v, omega, done = autopilot.step((odom.x, odom.y, odom.theta), plant.sim_time)
                completed = completed or done
                plant.command(robot, v, omega)
                plant.step(min(control_period, target - plant.sim_time))
            frame = plant.render(robot, width=w, height=h)
            name = f"{frame.stamp:017.6f}"  # zero-padded so that file names sort by time
            cv2.imwrite(str(out / "rgb" / f"{name}.png"), frame.rgb[..., ::-1])
            cv2.imwrite(str(out / "depth" / f"{name}.png"), depth_to_png16(frame.depth))
            stamp = f"{frame.stamp:.6f}"
            rgb_lines.append(f"{stamp} rgb/{name}.png")
            depth_lines.append(f"{stamp} depth/{name}.png")
            assoc_lines.append(f"{stamp} rgb/{name}.png {stamp} depth/{name}.png")
            stamps.append(frame.stamp)
            poses.append(frame.T_world_camera)
            odom = plant.controller(robot).odometry
            wheel_poses.append(pose_from_planar(odom.x, odom.y, odom.theta) @ base_camera)
            bar.update(1)
            k += 1
            if frames is None and (completed or plant.sim_time >= max_duration):
                break
        bar.close()
        config_text = dump_config(cfg)
    header = "# {kind}\n# file: 'fleetslam sim export, route {route}, robot {robot}'\n# timestamp filename\n"
    (out / "rgb.txt").write_text(
        header.format(kind="color images", route=route, robot=robot) + "\n".join(rgb_lines) + "\n", encoding="utf-8"
    )
    (out / "depth.txt").write_text(
        header.format(kind="depth maps", route=route, robot=robot) + "\n".join(depth_lines) + "\n", encoding="utf-8"
    )
    (out / "associations.txt").write_text("\n".join(assoc_lines) + "\n", encoding="utf-8")
    groundtruth = Trajectory.from_lists(stamps, poses)
    write_tum(out / "groundtruth.txt", groundtruth)
    write_tum(out / "odometry.txt", Trajectory.from_lists(stamps, wheel_poses))
    np.savetxt(out / "base_camera.txt", base_camera, fmt="%.9f", header="T_base_link_camera_optical (4x4)")
    write_camera_files(out, intrinsics)
    (out / "sim_config.yaml").write_text(config_text, encoding="utf-8")
    duration = stamps[-1] - stamps[0] if stamps else 0.0
    log.info("exported %d frames (%.1f s simulated) of route %s to %s", len(stamps), duration, route, out)
    return ExportResult(out, len(stamps), duration, completed, intrinsics, groundtruth)
