"""TUM RGB-D export round trip: files, formats, depth scale and ground truth consistent with the depth."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")
pytest.importorskip("mujoco")
cv2 = pytest.importorskip("cv2")

from fleetslam.geometry import transform_points  # noqa: E402
from fleetslam.sim.camera import CameraIntrinsics  # noqa: E402
from fleetslam.sim.export import depth_to_png16, export_tum  # noqa: E402
from fleetslam.trajectory import read_tum  # noqa: E402


def _read_list(path: Path) -> list[tuple[float, str]]:
    rows = []
    for line in path.read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        stamp, name = line.split()
        rows.append((float(stamp), name))
    return rows


def test_depth_png_encoding_uses_tum_scale() -> None:
    depth = np.array([[0.0, 1.0, np.nan], [0.5, 4.25, 20.0]], dtype=np.float32)
    png = depth_to_png16(depth)
    assert png.dtype == np.uint16
    np.testing.assert_array_equal(png, [[0, 5000, 0], [2500, 21250, 65535]])


def test_export_round_trip(tmp_path: Path) -> None:
    out = tmp_path / "loop"
    result = export_tum(out, route="loop", frames=12, width=160, height=120, camera_hz=10.0, progress=False)
    assert result.frames == 12
    assert result.duration == pytest.approx(1.1, abs=1e-6)  # 11 float64 camera periods: ~1e-15
    rgb = _read_list(out / "rgb.txt")
    depth = _read_list(out / "depth.txt")
    assert (out / "rgb.txt").read_text().startswith("# color images")
    assert len(rgb) == len(depth) == 12
    assert [s for s, _ in rgb] == [s for s, _ in depth]
    assert np.allclose(np.diff([s for s, _ in rgb]), 0.1)
    assert len((out / "associations.txt").read_text().splitlines()) == 12
    gt = read_tum(out / "groundtruth.txt")
    assert len(gt) == 12
    np.testing.assert_allclose(gt.stamps, [s for s, _ in rgb], atol=1e-6)  # both written with 6 decimals
    assert np.linalg.norm(gt.positions[-1] - gt.positions[0]) > 0.1  # the robot drove
    fx, fy, cx, cy, width, height, scale = (float(v) for v in (out / "camera.txt").read_text().splitlines()[1].split())
    assert (width, height, scale) == (160, 120, 5000)
    intrinsics = CameraIntrinsics(fx, fy, cx, cy, 160, 120)
    assert intrinsics == result.intrinsics
    assert (out / "intrinsics.yaml").is_file() and (out / "sim_config.yaml").is_file()
    for (stamp, rgb_name), (_, depth_name), pose in zip(rgb, depth, gt.poses, strict=True):
        image = cv2.imread(str(out / rgb_name), cv2.IMREAD_UNCHANGED)
        assert image.shape == (120, 160, 3) and image.dtype == np.uint8 and image.std() > 5
        raw = cv2.imread(str(out / depth_name), cv2.IMREAD_UNCHANGED)
        assert raw.dtype == np.uint16 and raw.shape == (120, 160)
        metres = raw.astype(np.float64) / scale
        valid = metres[metres > 0]
        assert valid.size > 1000 and valid.min() >= 0.5 and valid.max() <= 4.5
        # the ground-truth optical pose puts the floor back at z = 0 (lower image half, within the noise)
        lower = metres.copy()
        lower[: 120 * 2 // 3] = 0
        points = transform_points(pose, intrinsics.backproject(lower))
        floor = points[points[:, 2] < 0.15]
        assert len(floor) > 200, stamp
        # Kinect σ ≤ 6 mm at 2 m, mostly along rays that graze the floor; the median of > 200 points: 7e-5 measured
        assert abs(float(np.median(floor[:, 2]))) < 0.01

    # Wheel odometry and the camera mounting: the odometry's camera poses follow the truth over this short
    # drive (wheel slip aside), and the mounting maps the optical frame onto a base on the floor plane.
    from fleetslam.datasets import open_source
    from fleetslam.geometry import invert

    odometry = read_tum(out / "odometry.txt")
    np.testing.assert_allclose(odometry.stamps, gt.stamps, atol=1e-6)  # 6 decimals
    base_camera = np.loadtxt(out / "base_camera.txt")
    moved_truth = invert(gt.poses[0]) @ gt.poses[-1]
    moved_wheels = invert(odometry.poses[0]) @ odometry.poses[-1]
    distance = np.linalg.norm(moved_truth[:3, 3])
    assert np.linalg.norm(moved_truth[:3, 3] - moved_wheels[:3, 3]) < 0.05 * distance  # slip: 2.3 % measured
    bases = [pose @ invert(base_camera) for pose in gt.poses]
    assert max(abs(b[2, 3] - bases[0][2, 3]) for b in bases) < 0.002  # the base stays at one height (1 µm measured)
    source = open_source(out)
    np.testing.assert_allclose(source.base_camera, base_camera)
    first = next(iter(source))
    assert first.prior is not None
