"""Relocalisation: after a texture-less stretch, a lost frame is verified against recent locations and the
odometry continues from the map instead of from a guess."""

from __future__ import annotations

import numpy as np

from fleetslam.config import load_config
from fleetslam.datasets.base import RGBDFrame
from fleetslam.geometry import invert, pose_from_xyz_rpy
from fleetslam.slam.config import SlamConfig
from fleetslam.slam.pipeline import SlamPipeline

from .test_odometry import BASE, INTRINSICS
from .textured_room import make_textures, render


def run_with_blackout(candidates: int) -> tuple[SlamPipeline, list[np.ndarray], list[np.ndarray], list[dict]]:
    """Move 8 cm sideways in 8 frames, see nothing for 4 frames while moving back 6 cm, then see again."""
    textures = make_textures(np.random.default_rng(2))
    config = load_config(SlamConfig, overrides=[f"relocalization_candidates={candidates}"])
    pipeline = SlamPipeline(config, intrinsics=INTRINSICS)
    offsets = [0.01 * k for k in range(9)] + [0.08 - 0.015 * k for k in range(1, 5)] + [0.02] * 3
    truth, estimates = [], []
    for index, x in enumerate(offsets):
        pose = BASE @ pose_from_xyz_rpy(x, 0.0, 0.0, 0.0, 0.0, 0.0)
        rgb, depth = render(pose, INTRINSICS, textures)
        if 9 <= index < 13:  # the blackout: a texture-less view without depth
            rgb, depth = np.full_like(rgb, 128), np.zeros_like(depth)
        step = pipeline.step(RGBDFrame(index, index / 30.0, rgb, depth))
        truth.append(invert(BASE) @ pose)
        estimates.append(step.pose)
    return pipeline, truth, estimates, pipeline.result().stats["frames"]


def test_lost_frame_is_relocalised_on_a_recent_location() -> None:
    _, truth, estimates, frames = run_with_blackout(10)
    relocalised = [f for f in frames if "relocalized_on" in f]
    assert relocalised and relocalised[0]["index"] == 13, [f.get("relocalized_on") for f in frames]
    # Verified against a keyframe 2 cm away: PnP on ~700 points, 0.5-1.0 mm measured on 3 SIMD paths.
    for k in (13, 14, 15):
        assert np.linalg.norm(estimates[k][:3, 3] - truth[k][:3, 3]) < 0.01, (k, estimates[k][:3, 3])


def test_without_relocalisation_the_guess_is_kept() -> None:
    _, truth, estimates, frames = run_with_blackout(0)
    assert not any("relocalized_on" in f for f in frames)
    # Constant velocity carried the camera on sideways through the blackout; the map restarted there.
    assert np.linalg.norm(estimates[15][:3, 3] - truth[15][:3, 3]) > 0.05  # 99 mm: 4 frames at 1-1.5 cm each way
