"""`fleetslam map build` from RGB-D sequences: TUM folders, simulator exports and recordings, with a trajectory
file, the ground truth or the frames' own poses.

The synthetic sequences look at a wall at world z = WALL_Z from cameras that move towards it and turn about their
vertical axis; depth is rendered analytically, so the wall lands in one layer of voxels only if every pose is
applied as T_world_camera of the optical frame.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from fleetslam.cli.main import main
from fleetslam.datasets.base import Intrinsics, RGBDFrame
from fleetslam.geometry import make_pose, pose_to_quat, so3_exp
from fleetslam.mapping.octree import OccupancyOctree
from fleetslam.mapping.rgbd_scans import RgbdScanCounts, rgbd_scans
from fleetslam.trajectory import Trajectory, read_tum, write_tum

cv2 = pytest.importorskip("cv2")

WALL_Z = 2.02  # inside the voxel layer [2.0, 2.05) at 0.05 m, clear of its faces
FREIBURG1 = Intrinsics(517.3, 516.5, 318.6, 255.3)  # what TumSource takes for a 'freiburg1' folder
FRAMES = 5


def _camera_pose(i: int) -> NDArray[np.float64]:
    """T_world_camera (optical frame): moving towards the wall and turning about the camera's y axis."""
    return make_pose(so3_exp([0.0, 0.06 * (i - 2), 0.0]), [0.05 * i, -0.02 * i, 0.1 * i])


def _wall_depth(pose: NDArray[np.float64], k: Intrinsics) -> NDArray[np.float32]:
    v, u = np.mgrid[0 : k.height, 0 : k.width].astype(np.float64)
    rays = np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u)], axis=-1)  # z = 1: depth is the scale
    along_world_z = rays @ pose[2, :3]
    return ((WALL_Z - pose[2, 3]) / along_world_z).astype(np.float32)


def _write_sequence(
    root: Path, k: Intrinsics, *, groundtruth: bool = True, camera_txt: bool = False, odometry: bool = False
) -> list[float]:
    """A TUM-layout folder (16-bit depth PNGs at 5000 units per metre); returns the frame stamps."""
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    stamps = [100.0 + i / 10.0 for i in range(FRAMES)]
    rgb_lines, depth_lines = ["# timestamp filename"], ["# timestamp filename"]
    for i, stamp in enumerate(stamps):
        depth = np.round(_wall_depth(_camera_pose(i), k) * 5000.0).astype(np.uint16)
        colour = np.full((k.height, k.width, 3), 40 * i, np.uint8)
        cv2.imwrite(str(root / "rgb" / f"{stamp:.6f}.png"), colour)
        cv2.imwrite(str(root / "depth" / f"{stamp + 0.003:.6f}.png"), depth)
        rgb_lines.append(f"{stamp:.6f} rgb/{stamp:.6f}.png")
        depth_lines.append(f"{stamp + 0.003:.6f} depth/{stamp + 0.003:.6f}.png")
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    # Poses at other stamps than the images, as TUM's motion capture: matched by the nearest stamp.
    poses = Trajectory.from_lists([s + 0.004 for s in stamps], [_camera_pose(i) for i in range(FRAMES)])
    if groundtruth:
        write_tum(root / "groundtruth.txt", poses)
    if odometry:
        write_tum(root / "odometry.txt", poses)
    if camera_txt:
        (root / "camera.txt").write_text(f"{k.fx} {k.fy} {k.cx} {k.cy} {k.width} {k.height} 5000\n")
    return stamps


def _assert_wall_map(path: Path, first_camera: NDArray[np.float64]) -> None:
    tree = OccupancyOctree.read(path)
    occupied, _ = tree.occupied_centers()
    assert len(occupied) > 100
    # Every occupied voxel is in the wall's layer: a pose applied the wrong way round would smear the wall.
    # Centres are float64 key arithmetic (exact here); the next layer is 0.05 away.
    assert np.abs(occupied[:, 2] - 2.025).max() < 1e-6
    assert tree.is_occupied([first_camera[0], first_camera[1], WALL_Z]) is True
    # Free space from the camera centre to the wall.
    for fraction in (0.25, 0.5, 0.9):
        between = first_camera + fraction * (np.array([first_camera[0], first_camera[1], WALL_Z]) - first_camera)
        assert tree.is_occupied(between) is False and tree.log_odds(between) is not None
    # Beyond the wall is unknown.
    assert tree.log_odds([first_camera[0], first_camera[1], WALL_Z + 0.3]) is None


@pytest.fixture(scope="module")
def tum_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("tum") / "rgbd_dataset_freiburg1_wall"
    _write_sequence(root, FREIBURG1)
    return root


def _build(*args: str | Path) -> int:
    return main(["map", "build", *(str(a) for a in args), "--no-progress"])


def test_tum_folder_with_its_ground_truth(tum_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "wall.bt"
    assert _build(tum_folder, "-o", out, "--pixel-step", "8", "--resolution", "0.05") == 0
    printed = capsys.readouterr().out
    assert "5 of 5 frames" in printed and "skipped" not in printed
    _assert_wall_map(out, _camera_pose(0)[:3, 3])


def test_tum_folder_with_a_trajectory_file(
    tum_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    truth = read_tum(tum_folder / "groundtruth.txt")
    trajectory = tmp_path / "trajectory.txt"
    # Poses of frames 0, 1, 3, 4: frame 2 has none within 0.02 s and is skipped.
    keep = [0, 1, 3, 4]
    write_tum(trajectory, Trajectory(truth.stamps[keep], truth.poses[keep]))
    out = tmp_path / "wall.ot"
    assert _build(tum_folder, "--kind", "tum", "--trajectory", trajectory, "-o", out, "--pixel-step", "8") == 0
    printed = capsys.readouterr().out
    assert "4 of 5 frames" in printed
    assert f"1 of 5 frames skipped, no pose within 0.02 s in {trajectory}" in printed
    _assert_wall_map(out, _camera_pose(0)[:3, 3])
    # --every 2 uses frames 0, 2, 4; frame 2 has no pose.
    assert _build(tum_folder, "--trajectory", trajectory, "-o", out, "--pixel-step", "8", "--every", "2") == 0
    printed = capsys.readouterr().out
    assert "2 of 5 frames (--every 2)" in printed and "1 of 5 frames skipped" in printed


def test_tum_errors_name_the_problem(tum_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "a.bt"
    # No overlap between the frames' and the trajectory's stamps.
    truth = read_tum(tum_folder / "groundtruth.txt")
    shifted = tmp_path / "shifted.txt"
    write_tum(shifted, Trajectory(truth.stamps + 100.0, truth.poses))
    assert _build(tum_folder, "--trajectory", shifted, "-o", out) == 1
    err = capsys.readouterr().err
    assert f"none of its 5 frames has a pose within 0.02 s in {shifted}" in err
    assert not out.exists()
    # A TUM folder without ground truth needs --trajectory.
    bare = tmp_path / "rgbd_dataset_freiburg1_bare"
    _write_sequence(bare, FREIBURG1, groundtruth=False)
    assert _build(bare, "-o", out) == 2
    err = capsys.readouterr().err
    assert str(bare) in err and "give the camera poses with --trajectory" in err
    assert not out.exists()
    # A malformed trajectory names its file and line.
    broken = tmp_path / "broken.txt"
    broken.write_text("100.0 0 0 0 0 0 0 1\n100.1 0 0 zero 0 0 0 1\n")
    assert _build(tum_folder, "--trajectory", broken, "-o", out) == 1
    assert f"{broken}:2" in capsys.readouterr().err
    # Options out of range, and options for the other kind of input.
    assert _build(tum_folder, "-o", out, "--every", "0") == 2
    assert "every: must be at least 1, got 0" in capsys.readouterr().err
    assert _build(tum_folder, "-o", out, "--origin", "1,2,3") == 2
    assert "--origin" in capsys.readouterr().err
    points = tmp_path / "points.xyz"
    points.write_text("1 0 0\n")
    assert _build(points, "--trajectory", shifted, "-o", out) == 2
    assert "--trajectory" in capsys.readouterr().err
    assert _build(tum_folder, "--kind", "rgbd", "-o", out) == 1
    err = capsys.readouterr().err
    assert "unknown scan input kind 'rgbd'" in err and "mcap, sim, tum" in err


def test_sim_export_with_only_wheel_odometry(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A simulator export without ground truth: the frames' odometry priors are the poses."""
    small = Intrinsics(80.0, 80.0, 39.5, 29.5, 80, 60)
    root = tmp_path / "export"
    _write_sequence(root, small, groundtruth=False, camera_txt=True, odometry=True)
    out = tmp_path / "wall.bt"
    assert _build(root, "-o", out, "--pixel-step", "1") == 0  # guessed: sim (camera.txt)
    assert "5 of 5 frames" in capsys.readouterr().out
    _assert_wall_map(out, _camera_pose(0)[:3, 3])


@dataclass
class _RenderedWall:
    """An RGB-D source rendering the wall on demand; counts the frames it has produced."""

    stamps: list[float]
    poses: list[NDArray[np.float64] | None]
    intrinsics: Intrinsics = field(default_factory=lambda: Intrinsics(20.0, 20.0, 9.5, 7.5, 20, 16))
    name: str = "rendered"
    produced: int = 0

    def __len__(self) -> int:
        return len(self.stamps)

    def __iter__(self) -> Iterator[RGBDFrame]:
        return self.frames()

    def frames(self, every: int = 1) -> Iterator[RGBDFrame]:
        for i in range(0, len(self.stamps), every):
            stamp = self.stamps[i]
            self.produced += 1
            depth = _wall_depth(_camera_pose(i), self.intrinsics)
            rgb = np.zeros((*depth.shape, 3), np.uint8)
            yield RGBDFrame(i, stamp, rgb, depth, prior=self.poses[i])

    def groundtruth(self) -> Trajectory | None:
        return None


def test_scans_are_lazy_and_matched_by_nearest_stamp() -> None:
    source = _RenderedWall([0.0, 1.0, 2.0, 3.0], [None] * 4)
    trajectory = Trajectory.from_lists([0.01, 1.03, 1.99, 3.0, 3.015], [_camera_pose(i) for i in (0, 1, 2, 3, 9)])
    counts = RgbdScanCounts()
    scans = rgbd_scans(source, trajectory, pixel_step=1, counts=counts)
    first = next(scans)
    assert source.produced == 1 and first.id == 0
    np.testing.assert_allclose(first.origin, _camera_pose(0)[:3, 3])
    world = first.world_points()
    np.testing.assert_allclose(world[:, 2], WALL_Z, atol=1e-5)  # float32 depth: ulp 2.4e-7 at 2 m (2.2e-7 measured)
    rest = list(scans)
    assert [s.id for s in rest] == [2, 3]  # frame 1's nearest pose is 0.03 s away
    np.testing.assert_allclose(rest[1].pose, _camera_pose(3))  # 3.0 is nearer than 3.015
    assert (counts.frames, counts.used, counts.unmatched) == (4, 3, 1)


@pytest.mark.parametrize(("frames", "skipped"), [(7, 4), (8, 5)])
def test_every_nth_frame_reads_only_those(frames: int, skipped: int) -> None:
    """Frames between the used ones are never read; the counts still cover the whole sequence (with 8 frames, the
    last one is skipped after the last used one)."""
    source = _RenderedWall([float(i) for i in range(frames)], [_camera_pose(i) for i in range(frames)])
    counts = RgbdScanCounts()
    used = [s.id for s in rgbd_scans(source, None, every=3, counts=counts)]
    assert used == [0, 3, 6] and source.produced == 3
    assert (counts.frames, counts.used, counts.skipped_every) == (frames, 3, skipped)


def test_frames_own_poses_and_their_absence() -> None:
    poses: list[NDArray[np.float64] | None] = [_camera_pose(0), None, _camera_pose(2)]
    counts = RgbdScanCounts()
    used = [s.id for s in rgbd_scans(_RenderedWall([0.0, 1.0, 2.0], poses), None, counts=counts)]
    assert used == [0, 2] and counts.frame_pose_field == "prior" and counts.unmatched == 1
    from fleetslam.errors import ConfigError

    with pytest.raises(ConfigError, match="rendered: no trajectory given"):
        next(rgbd_scans(_RenderedWall([0.0], [None]), None))
    with pytest.raises(ConfigError, match="pixel_step: must be at least 1"):
        next(rgbd_scans(_RenderedWall([0.0], [None]), None, pixel_step=0))


#: Where the optical frame sits on the base, through camera_link (x forward, y left, z up).
BASE_CAMERA_LINK = make_pose(so3_exp([0.0, 0.0, 0.2]), [0.12, 0.0, 0.35])
CAMERA_LINK_OPTICAL = make_pose(np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]), [0.0, 0.02, 0.0])


def _camera_pose_at(i: float) -> NDArray[np.float64]:
    """:func:`_camera_pose` between the frames as well (linear translation, rotation about one axis)."""
    return make_pose(so3_exp([0.0, 0.06 * (i - 2), 0.0]), [0.05 * i, -0.02 * i, 0.1 * i])


def _write_recording(
    folder: Path, stamps: list[float], k: Intrinsics, poses: dict[str, str] | None = None, tf_static: bool = False
) -> None:
    """A rosbag2 folder with MCAP storage, as `fleetslam record` writes it: colour, 32FC1 depth, CameraInfo.

    ``poses``: Odometry topics of base_link in the given frame, sampled five times per frame interval, whose
    camera poses are the frames' :func:`_camera_pose` (``"garbage"`` as the frame: random poses);
    ``tf_static``: the camera's mounting base_link → camera_link → camera_rgb_optical_frame.
    """
    from fleetslam.middleware.recording import BagWriter
    from fleetslam.msg.typesys import get_typestore

    store = get_typestore()
    types = store.types

    def header(stamp: float) -> Any:
        sec = int(stamp)
        time = types["builtin_interfaces/msg/Time"](sec=sec, nanosec=round((stamp - sec) * 1e9))
        return types["std_msgs/msg/Header"](stamp=time, frame_id="camera_rgb_optical_frame")

    def image(stamp: float, encoding: str, pixels: NDArray[np.generic]) -> object:
        step = pixels.strides[0]
        return types["sensor_msgs/msg/Image"](
            header=header(stamp), height=k.height, width=k.width, encoding=encoding, is_bigendian=0, step=step,
            data=np.ascontiguousarray(pixels).view(np.uint8).ravel(),
        )  # fmt: skip

    with BagWriter(folder) as writer:

        def put(topic: str, type_name: str, msg: object, stamp: float) -> None:
            writer.write(topic, type_name, int(stamp * 1e9), bytes(store.serialize_cdr(msg, type_name)))

        info = types["sensor_msgs/msg/CameraInfo"](
            header=header(stamps[0]), height=k.height, width=k.width, distortion_model="plumb_bob", d=np.zeros(5),
            k=k.K.ravel(), r=np.eye(3).ravel(), p=np.zeros(12), binning_x=0, binning_y=0,
            roi=types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
        )  # fmt: skip
        put("/c3po/camera/rgb/camera_info", "sensor_msgs/msg/CameraInfo", info, stamps[0])
        for i, stamp in enumerate(stamps):
            depth = _wall_depth(_camera_pose(i), k)
            colour = np.zeros((k.height, k.width, 3), np.uint8)
            put("/c3po/camera/rgb/image_raw", "sensor_msgs/msg/Image", image(stamp, "rgb8", colour), stamp)
            put("/c3po/camera/depth/image_raw", "sensor_msgs/msg/Image", image(stamp, "32FC1", depth), stamp + 0.002)

        def transform(parent: str, child: str, pose: NDArray[np.float64], stamp: float) -> Any:
            t, q = pose_to_quat(pose)
            return types["geometry_msgs/msg/TransformStamped"](
                header=types["std_msgs/msg/Header"](
                    stamp=types["builtin_interfaces/msg/Time"](sec=int(stamp), nanosec=0), frame_id=parent
                ),
                child_frame_id=child,
                transform=types["geometry_msgs/msg/Transform"](
                    translation=types["geometry_msgs/msg/Vector3"](x=t[0], y=t[1], z=t[2]),
                    rotation=types["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
                ),
            )

        if tf_static:
            mounts = [transform("base_link", "camera_link", BASE_CAMERA_LINK, stamps[0]),
                      transform("camera_link", "camera_rgb_optical_frame", CAMERA_LINK_OPTICAL, stamps[0])]  # fmt: skip
            put("/c3po/tf_static", "tf2_msgs/msg/TFMessage", types["tf2_msgs/msg/TFMessage"](transforms=mounts), 0.0)
        camera_base = np.linalg.inv(BASE_CAMERA_LINK @ CAMERA_LINK_OPTICAL)
        rng = np.random.default_rng(3)
        for topic, frame in (poses or {}).items():
            for j in range(5 * (len(stamps) - 1) + 1):
                stamp = stamps[0] + j * (stamps[1] - stamps[0]) / 5
                pose = (
                    _camera_pose_at(j / 5) @ camera_base
                    if frame != "garbage"
                    else make_pose(translation=rng.normal(size=3))
                )
                t, q = pose_to_quat(pose)
                with_cov = types["geometry_msgs/msg/PoseWithCovariance"](
                    pose=types["geometry_msgs/msg/Pose"](
                        position=types["geometry_msgs/msg/Point"](x=t[0], y=t[1], z=t[2]),
                        orientation=types["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
                    ),
                    covariance=np.zeros(36),
                )
                twist = types["geometry_msgs/msg/TwistWithCovariance"](
                    twist=types["geometry_msgs/msg/Twist"](
                        linear=types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                        angular=types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                    ),
                    covariance=np.zeros(36),
                )
                odom = types["nav_msgs/msg/Odometry"](
                    header=types["std_msgs/msg/Header"](
                        stamp=types["builtin_interfaces/msg/Time"](
                            sec=int(stamp), nanosec=round((stamp - int(stamp)) * 1e9)
                        ),
                        frame_id="world" if frame == "garbage" else frame,
                    ),
                    child_frame_id="base_link", pose=with_cov, twist=twist,
                )  # fmt: skip
                put(topic, "nav_msgs/msg/Odometry", odom, stamp)


def test_recording_with_a_trajectory(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    k = Intrinsics(40.0, 40.0, 19.5, 14.5, 40, 30)
    stamps = [50.0 + i / 15.0 for i in range(FRAMES)]
    recording = tmp_path / "run"
    _write_recording(recording, stamps, k)
    trajectory = tmp_path / "trajectory.txt"
    write_tum(trajectory, Trajectory.from_lists(stamps, [_camera_pose(i) for i in range(FRAMES)]))
    out = tmp_path / "wall.bt"
    # The recording folder (guessed: mcap) and the .mcap file in it.
    for given in (recording, next(recording.glob("*.mcap"))):
        assert _build(given, "--trajectory", trajectory, "-o", out, "--pixel-step", "1") == 0
        assert "5 of 5 frames" in capsys.readouterr().out
        _assert_wall_map(out, _camera_pose(0)[:3, 3])
    # A recording carries no poses of its own: without --trajectory the error says what to give.
    assert _build(recording, "--kind", "mcap", "-o", tmp_path / "x.bt") == 2
    err = capsys.readouterr().err
    assert str(recording) in err and "--trajectory" in err
    assert not (tmp_path / "x.bt").exists()


def test_recording_with_its_ground_truth_and_mounting(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """ground_truth/odom (base_link in world) times the tf_static chain gives the camera poses: the wall is one
    voxel layer. The other robot's ground truth in the same recording is not taken."""
    from fleetslam.datasets import open_source

    k = Intrinsics(40.0, 40.0, 19.5, 14.5, 40, 30)
    stamps = [50.0 + i / 15.0 for i in range(FRAMES)]
    recording = tmp_path / "run"
    topics = {"/c3po/ground_truth/odom": "world", "/a_robot/ground_truth/odom": "garbage"}
    _write_recording(recording, stamps, k, poses=topics, tf_static=True)
    source = open_source(recording)
    truth = source.groundtruth()
    assert truth is not None and len(truth) == 5 * (FRAMES - 1) + 1
    frames = list(source)
    for i, frame in enumerate(frames):
        assert frame.groundtruth is not None and frame.prior is None
        # float64 CDR poses, a three-transform chain and a 1/5-interval interpolation: ~1e-15 (5.6e-16 measured)
        np.testing.assert_allclose(frame.groundtruth, _camera_pose(i), atol=1e-9)
    out = tmp_path / "wall.bt"
    assert _build(recording, "-o", out, "--pixel-step", "1") == 0
    assert "5 of 5 frames" in capsys.readouterr().out
    _assert_wall_map(out, _camera_pose(0)[:3, 3])


def test_recording_with_wheel_odometry_only(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    """Without ground truth, the frames' wheel-odometry poses (odom times the mounting) build the map, in the
    odometry frame, with a warning that it drifts."""
    k = Intrinsics(40.0, 40.0, 19.5, 14.5, 40, 30)
    stamps = [50.0 + i / 15.0 for i in range(FRAMES)]
    recording = tmp_path / "run"
    _write_recording(recording, stamps, k, poses={"/c3po/odom": "odom", "/c3po/slam/odom": "garbage"}, tf_static=True)
    out = tmp_path / "wall.bt"
    assert _build(recording, "-o", out, "--pixel-step", "1") == 0
    assert "5 of 5 frames" in capsys.readouterr().out
    assert "wheel-odometry poses" in caplog.text
    _assert_wall_map(out, _camera_pose(0)[:3, 3])


def test_recording_whose_mounting_is_missing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    """Base poses without tf_static cannot be camera poses: a warning names the frames, the build asks for
    --trajectory and writes nothing."""
    k = Intrinsics(40.0, 40.0, 19.5, 14.5, 40, 30)
    stamps = [50.0 + i / 15.0 for i in range(FRAMES)]
    recording = tmp_path / "run"
    _write_recording(recording, stamps, k, poses={"/c3po/ground_truth/odom": "world"})
    assert _build(recording, "-o", tmp_path / "x.bt") == 2
    assert "--trajectory" in capsys.readouterr().err
    assert (
        "'base_link'" in caplog.text and "'camera_rgb_optical_frame'" in caplog.text and "no tf_static" in caplog.text
    )
    assert not (tmp_path / "x.bt").exists()


@pytest.fixture(scope="module")
def export(tmp_path_factory: pytest.TempPathFactory) -> Path:
    pytest.importorskip("mujoco")
    from fleetslam.sim.export import export_tum

    out = tmp_path_factory.mktemp("rgbd") / "line"
    export_tum(out, route="line", frames=10, width=160, height=120, camera_hz=5.0, progress=False)
    return out


def test_simulator_export_with_its_ground_truth(
    export: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A real simulator export: its ground truth puts the floor at z = 0 with free space above it."""
    out = tmp_path / "map.bt"
    assert _build(export, "-o", out, "--pixel-step", "2") == 0
    assert "10 of 10 frames" in capsys.readouterr().out
    tree = OccupancyOctree.read(out)
    occupied, _ = tree.occupied_centers()
    truth = read_tum(export / "groundtruth.txt")
    camera = truth.poses[0][:3, 3]
    floor = occupied[np.abs(occupied[:, 2]) < 0.06]  # the 0.05 m layers either side of z = 0 (centres ±0.025)
    assert len(floor) > 50
    ahead = floor[np.argsort(np.linalg.norm(floor[:, :2] - camera[:2], axis=1))[len(floor) // 2]]
    between = camera + 0.5 * (ahead - camera)
    assert tree.is_occupied(between) is False and tree.log_odds(between) is not None
