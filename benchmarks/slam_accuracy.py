"""SLAM accuracy and odometry speed, one JSON line per sequence, with Open3D's RGB-D odometry as the peer.

Sequences: the simulator's 640×480 ``loop_revisit`` route at 14 Hz, about 600 frames (the loop, then its
first metres again so that the camera sees the start from the start's viewpoint), and the ``survey`` route
at 15 Hz, exported into a cache folder when absent (``FLEETSLAM_BENCH_CACHE``, default ``~/.cache/fleetslam/bench``),
plus every TUM sequence folder under ``FLEETSLAM_TUM_DIR`` when set. The simulated sequences run with the
defaults, as on the robot: the exports carry the wheel odometry (each frame's prior) and the camera mounting
(planar motion); TUM's hand-held sequences get a hand-held motion prior and no planar constraint.
Figures: ATE RMSE (SE(3)-aligned, TUM conventions), RPE over 1 frame, loop closures, odometry median/p95 ms
per frame on ONE core (``cv2.setNumThreads(1)``), and the same for Open3D (``compute_rgbd_odometry``, frame to
frame, hybrid term) → ratios. Targets: ATE RMSE ≤ 1.0 cm on the loop with its loop closure detected; odometry median
≤ 20 ms per 640×480 frame.

Usage: python benchmarks/slam_accuracy.py [--frames N] [--only loop|survey|tum] [--no-peer]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from fleetslam.config import load_config
from fleetslam.datasets import RGBDSource, open_source
from fleetslam.eval import ape, rpe
from fleetslam.slam.config import SlamConfig
from fleetslam.slam.pipeline import SlamPipeline
from fleetslam.trajectory import Trajectory


def cache_dir() -> Path:
    return Path(os.environ.get("FLEETSLAM_BENCH_CACHE", Path.home() / ".cache" / "fleetslam" / "bench"))


SIM_SEQUENCES = {"loop": ("loop_revisit", 14.0), "survey": ("survey", 15.0)}
"""Benchmark sequence → (autopilot route, camera rate in Hz) at the autopilot's 0.6 m/s."""


def sim_sequence(route: str, frames: int | None, camera_hz: float) -> Path:
    """Export (once) ``frames`` frames of a route, or the whole route when None."""
    # v2: exports carry the wheel odometry (odometry.txt, the frames' prior) and the camera mounting.
    out = cache_dir() / f"sim_{route}_{camera_hz:g}hz_{frames or 'full'}_v2"
    if not (out / "groundtruth.txt").is_file():
        from fleetslam.sim.export import export_tum

        export_tum(out, route=route, frames=frames, width=640, height=480, camera_hz=camera_hz, progress=True)
    return out


def import_open3d() -> Any:
    """Open3D, or None. Its package ``__init__`` imports the optional plotly/dash web viewer; dash is not
    installed here (its pytest plugin would load into every test run), so an empty stand-in satisfies that
    import: the odometry used below never touches it."""
    import importlib.util
    import types

    if importlib.util.find_spec("open3d") is None:
        return None
    if "dash" not in sys.modules and importlib.util.find_spec("dash") is None:
        stub = types.ModuleType("dash")
        stub.html = stub.dcc = types.ModuleType("dash.stub")  # type: ignore[attr-defined]
        stub.Dash = object  # type: ignore[attr-defined]
        sys.modules.setdefault("dash", stub)
    try:
        import open3d
    except ImportError:
        return None
    return open3d


def peer_open3d(source: RGBDSource, max_frames: int | None) -> dict[str, Any] | None:
    """Open3D frame-to-frame RGB-D odometry (hybrid photometric + depth term), chained."""
    o3d = import_open3d()
    if o3d is None:
        return None
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    k = source.intrinsics
    intr = o3d.camera.PinholeCameraIntrinsic(k.width, k.height, k.fx, k.fy, k.cx, k.cy)
    option = o3d.pipelines.odometry.OdometryOption()
    jacobian = o3d.pipelines.odometry.RGBDOdometryJacobianFromHybridTerm()
    previous = None
    pose = np.eye(4)
    stamps, poses, times = [], [], []
    for frame in source:
        if max_frames is not None and frame.index >= max_frames:
            break
        t0 = time.perf_counter()
        rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.geometry.Image(np.ascontiguousarray(frame.rgb)),
            o3d.geometry.Image(frame.depth),
            depth_scale=1.0,
            depth_trunc=6.0,
            convert_rgb_to_intensity=True,
        )
        if previous is not None:
            ok, T_prev_cur, _ = o3d.pipelines.odometry.compute_rgbd_odometry(
                rgbd, previous, intr, np.eye(4), jacobian, option
            )
            if ok:
                # compute_rgbd_odometry returns the transform taking source (current) points to target (previous).
                pose = pose @ T_prev_cur
        times.append((time.perf_counter() - t0) * 1e3)
        previous = rgbd
        stamps.append(frame.stamp)
        poses.append(pose.copy())
    return {"trajectory": Trajectory.from_lists(stamps, poses), "ms": np.asarray(times[1:] or [0.0])}


def run_sequence(name: str, path: Path, max_frames: int | None, peer: bool, plots: Path | None) -> dict[str, Any]:
    import cv2

    cv2.setNumThreads(1)
    source = open_source(path)
    gt = source.groundtruth()
    config = SlamConfig()
    if not name.startswith("sim_"):
        # TUM's sequences are mostly hand-held: the motion prior must allow a hand's accelerations.
        config = load_config(
            SlamConfig,
            overrides=["odometry.motion_prior_acceleration=10", "odometry.motion_prior_angular_acceleration=10"],
        )
    pipeline = SlamPipeline(config, source)
    t0 = time.perf_counter()
    result = pipeline.run(max_frames)
    wall = time.perf_counter() - t0
    ms = np.asarray(result.frame_ms)
    record: dict[str, Any] = {
        "benchmark": "slam_accuracy",
        "sequence": name,
        "frames": len(result.trajectory),
        "keyframes": len(result.keyframes),
        "loops_accepted": len(result.loops_accepted),
        "loops_rejected": len(result.loops_rejected),
        # Loops between keyframes more than half the run apart: the revisit of the start, not a local one.
        "revisit_loops": sum(1 for a, b in result.loops_accepted if abs(b - a) > len(result.keyframes) // 2),
        "odometry_ms_median": round(float(np.median(ms)), 2),
        "odometry_ms_p95": round(float(np.percentile(ms, 95)), 2),
        "wall_s": round(wall, 1),
        "threads": 1,
    }
    if gt is not None:
        record["ate_rmse_cm"] = round(ape(gt, result.trajectory).rmse * 100, 3)
        record["ate_rmse_cm_odometry_only"] = round(ape(gt, result.odometry).rmse * 100, 3)
        record["rpe_1f_rmse_cm"] = round(rpe(gt, result.trajectory).rmse * 100, 3)
    peer_result = None
    if peer:
        peer_result = peer_open3d(open_source(path), max_frames)
        if peer_result is None:
            record["peer"] = "open3d not installed"
        else:
            peer_ms = float(np.median(peer_result["ms"]))
            record["peer"] = "open3d.pipelines.odometry.compute_rgbd_odometry (hybrid, frame-to-frame)"
            record["peer_ms_median"] = round(peer_ms, 2)
            record["speed_ratio_peer_over_ours"] = round(peer_ms / max(float(np.median(ms)), 1e-9), 2)
            if gt is not None:
                peer_ate = ape(gt, peer_result["trajectory"]).rmse * 100
                record["peer_ate_rmse_cm"] = round(peer_ate, 3)
                record["ate_ratio_peer_over_ours"] = round(peer_ate / max(record["ate_rmse_cm"], 1e-9), 2)
    if gt is not None and plots is not None:
        from fleetslam.eval import plot_ape

        plots.mkdir(parents=True, exist_ok=True)
        others = {"odometry only": result.odometry}
        if peer and peer_result is not None:
            others["Open3D RGB-D odometry"] = peer_result["trajectory"]
        png = plots / f"slam_{name}.png"
        plot_ape(gt, result.trajectory, str(png), others=others, title=f"{name}: fleetslam vs ground truth")
        record["plot"] = str(png)
    record["targets"] = {"ate_rmse_cm_max": 1.0, "odometry_ms_median_max": 20.0}
    return record


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--frames",
        type=int,
        help="frames of the simulated sequences (default: the whole route, about 600 frames for the loop)",
    )
    parser.add_argument("--only", choices=["loop", "survey", "tum"], help="run one kind of sequence")
    parser.add_argument("--no-peer", action="store_true", help="skip the Open3D peer")
    parser.add_argument("--max-frames", type=int, help="process at most N frames per sequence")
    parser.add_argument(
        "--plots", type=Path, default=Path("results/benchmarks"), help="folder for the trajectory plots (PNG)"
    )
    args = parser.parse_args(argv)
    sequences: list[tuple[str, Path]] = []
    for name, (route, camera_hz) in SIM_SEQUENCES.items():
        if args.only in (None, name):
            sequences.append((f"sim_{name}", sim_sequence(route, args.frames, camera_hz)))
    tum_dir = os.environ.get("FLEETSLAM_TUM_DIR")
    if tum_dir and args.only in (None, "tum"):
        for folder in sorted(Path(tum_dir).iterdir()):
            if (folder / "rgb.txt").is_file():
                sequences.append((folder.name, folder))
    for name, path in sequences:
        print(json.dumps(run_sequence(name, path, args.max_frames, not args.no_peer, args.plots)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
