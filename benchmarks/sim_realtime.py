"""Simulator speed: real-time factor of the plant (physics at 2 ms, base controllers at 50 Hz, RGB-D cameras
with the Kinect model) for 1 and 2 robots at 320×240 @ 10 Hz and 640×480 @ 30 Hz, and ms per rendered
RGB-D frame (rendering + Kinect model). Peer for the rendering alone: ``mujoco.Renderer`` (two passes,
colour then depth) on the same model and camera vs our one-pass ``RGBDRenderer``.

Prints one JSON line. Target: 2 robots at 320×240 @ 10 Hz in real time (real_time_factor >= 1).

    MUJOCO_GL=egl python benchmarks/sim_realtime.py [--seconds 4]
"""

from __future__ import annotations

import argparse
import json
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

from fleetslam.sim.config import SimConfig
from fleetslam.sim.plant import Plant, import_mujoco
from fleetslam.sim.rendering import RGBDRenderer


def real_time_factor(robots: int, width: int, height: int, camera_hz: float, seconds: float) -> dict[str, float]:
    """Drive every robot forward-and-turning while rendering its camera at camera_hz; simulated s per wall s."""
    config = SimConfig()
    with Plant(config, config.robots[:robots]) as plant:
        plant.render(plant.robot_names[0], width=width, height=height)  # create the renderer outside the timing
        control = 1.0 / config.robot.control_rate
        frame_period = 1.0 / camera_hz
        next_frame = plant.sim_time
        render_time = 0.0
        frames = 0
        start = time.perf_counter()
        t0 = plant.sim_time
        while plant.sim_time - t0 < seconds:
            for name in plant.robot_names:
                plant.command(name, 0.3, 0.2)
            if plant.sim_time + 1e-9 >= next_frame:
                r0 = time.perf_counter()
                for name in plant.robot_names:
                    plant.render(name, width=width, height=height)
                    frames += 1
                render_time += time.perf_counter() - r0
                next_frame += frame_period
            plant.step(control)
        wall = time.perf_counter() - start
    return {"rtf": (plant.sim_time - t0) / wall, "ms_per_frame": 1000.0 * render_time / max(frames, 1)}


def render_only_ms(width: int, height: int, frames: int = 30) -> tuple[float, float]:
    """(ours, peer) ms per colour + depth frame without the sensor model: our one-pass RGBDRenderer vs
    mujoco.Renderer (colour pass, then a depth pass) on the same plant camera."""
    mujoco = import_mujoco()
    with Plant(SimConfig(), SimConfig().robots[:1]) as plant:
        camera = plant.robot(plant.robot_names[0]).camera_id
        ours = RGBDRenderer(mujoco, plant.model, width, height)
        ours.render(plant.data, camera)
        start = time.perf_counter()
        for _ in range(frames):
            ours.render(plant.data, camera)
        ours_ms = 1000.0 * (time.perf_counter() - start) / frames
        ours.close()
        peer = mujoco.Renderer(plant.model, height, width)
        for flag in (mujoco.mjtRndFlag.mjRND_SHADOW, mujoco.mjtRndFlag.mjRND_REFLECTION):
            peer.scene.flags[flag] = False
        peer.update_scene(plant.data, camera=camera)
        peer.render()
        start = time.perf_counter()
        for _ in range(frames):
            peer.update_scene(plant.data, camera=camera)
            peer.render()
            peer.enable_depth_rendering()
            peer.render()
            peer.disable_depth_rendering()
        peer_ms = 1000.0 * (time.perf_counter() - start) / frames
        peer.close()
    return ours_ms, peer_ms


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=4.0, help="simulated seconds per configuration")
    args = parser.parse_args()
    result: dict[str, float | bool | str] = {"benchmark": "sim_realtime", "cpus": os.cpu_count() or 0}
    for robots in (1, 2):
        for width, height, hz in ((320, 240, 10.0), (640, 480, 30.0)):
            r = real_time_factor(robots, width, height, hz, args.seconds)
            key = f"{robots}robot_{width}x{height}_{int(hz)}hz"
            result[f"rtf_{key}"] = round(r["rtf"], 3)
            result[f"ms_per_rgbd_frame_{key}"] = round(r["ms_per_frame"], 2)
    for width, height in ((320, 240), (640, 480)):
        ours, peer = render_only_ms(width, height)
        result[f"render_only_ms_{width}x{height}"] = round(ours, 2)
        result[f"peer_mujoco_renderer_ms_{width}x{height}"] = round(peer, 2)
        result[f"speedup_vs_peer_{width}x{height}"] = round(peer / ours, 2)
    result["target_2robots_320x240_10hz_realtime"] = float(result["rtf_2robot_320x240_10hz"]) >= 1.0
    print(json.dumps(result))


if __name__ == "__main__":
    main()
