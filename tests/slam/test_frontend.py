"""The front-end seam: the registry that ``odometry.kind`` selects from, and a front-end without features (the
wheel-odometry example of docs/extending.md) running through the pipeline with loop closure off."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from fleetslam.config import load_config
from fleetslam.errors import ConfigError, SlamError
from fleetslam.geometry import invert
from fleetslam.slam.config import FeatureConfig, OdometryConfig, SlamConfig
from fleetslam.slam.frontend import FRONT_ENDS, KeyframeObservation, make_odometry
from fleetslam.slam.loop_closure import make_loop_closure_detector
from fleetslam.slam.loop_config import LoopClosureConfig, MemoryConfig
from fleetslam.slam.odometry import VisualOdometry
from fleetslam.slam.pipeline import SlamPipeline

from .loop_scene import CAMERA_MATRIX, make_place, observe, place_pose
from .test_odometry import INTRINSICS

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def load_example(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_default_kind_is_the_visual_odometry_with_loop_closure() -> None:
    odometry = make_odometry(OdometryConfig(), FeatureConfig(), INTRINSICS)
    assert isinstance(odometry, VisualOdometry) and odometry.provides_features
    assert SlamPipeline(SlamConfig(), intrinsics=INTRINSICS).loop_closure
    assert not SlamPipeline(SlamConfig(loop_closure_enabled=False), intrinsics=INTRINSICS).loop_closure


def test_an_unknown_kind_names_the_known_ones() -> None:
    config = load_config(SlamConfig, overrides=["odometry.kind=lidar"])
    with pytest.raises(ConfigError, match=r"odometry.kind = 'lidar' is unknown; known kinds: \['visual'\]"):
        SlamPipeline(config, intrinsics=INTRINSICS)


def test_a_front_end_without_features_runs_with_loop_closure_off(tmp_path: Path) -> None:
    example = load_example("wheel_odometry_frontend")
    drive = example.SyntheticDrive(40)
    config = load_config(SlamConfig, overrides=["odometry.kind=wheels"])
    assert config.loop_closure_enabled  # configured on: the front-end turns it off
    pipeline = SlamPipeline(config, drive, front_ends={**FRONT_ENDS, "wheels": example.make_wheel_odometry})
    assert not pipeline.loop_closure
    result = pipeline.run()
    # Keyframes every 25 cm of the 1.2 m drive, linked by odometry only; no memory, no hypotheses, no map.db.
    assert 4 <= len(result.keyframes) <= 6
    assert {c.kind for c in pipeline.constraints()} == {"odometry"}
    assert not any("memory" in f or "hypothesis" in f for f in result.stats["frames"])
    assert result.loops_accepted == [] and pipeline.loops_retracted == 0
    assert not pipeline.save_map(tmp_path / "map.db") and not (tmp_path / "map.db").exists()
    assert pipeline.bag_of_words(1)[0].size == 0
    # Odometry links alone: the optimised trajectory is the wheels' own, relative to the first frame.
    wheels = np.array([invert(drive.wheels[0]) @ w for w in drive.wheels])
    np.testing.assert_allclose(result.trajectory.poses, wheels, atol=1e-6)


def test_loop_closure_refuses_a_keyframe_without_features() -> None:
    detector = make_loop_closure_detector(LoopClosureConfig(), MemoryConfig(), CAMERA_MATRIX)
    featureless = KeyframeObservation(0.0, np.eye(4))
    with pytest.raises(SlamError, match="needs the keyframe's features"):
        detector.process(featureless)
    rng = np.random.default_rng(5)
    place = make_place(rng, place_pose(0))
    detector.process(observe(rng, place, place.pose).keyframe(1.0))
    assert detector.relocalize(featureless, detector.locations()) is None
    # The same place seen again relocalises on it.
    found = detector.relocalize(observe(rng, place, place.pose).keyframe(2.0), detector.locations())
    assert found is not None and found[0] == 1 and found[1].accepted
