from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from fleetslam.datasets import guess_kind, open_source
from fleetslam.datasets.tum import TUM_INTRINSICS, associate
from fleetslam.errors import DatasetError


def _write_tum(root: Path, n: int = 5, depth_offset: float = 0.011) -> None:
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    rgb_lines = ["# color images", "# file: 'x.bag'", "# timestamp filename"]
    depth_lines = ["# depth maps", "#", "# timestamp filename"]
    gt_lines = ["# ground truth trajectory"]
    for i in range(n):
        stamp = 1305031102.0 + i / 30.0
        image = np.zeros((48, 64, 3), np.uint8)
        image[:, :, 2] = 10 * i  # red in BGR files
        cv2.imwrite(str(root / f"rgb/{stamp:.6f}.png"), image)
        depth = np.full((48, 64), 5000 * (1 + i), np.uint16)
        cv2.imwrite(str(root / f"depth/{stamp + depth_offset:.6f}.png"), depth)
        rgb_lines.append(f"{stamp:.6f} rgb/{stamp:.6f}.png")
        depth_lines.append(f"{stamp + depth_offset:.6f} depth/{stamp + depth_offset:.6f}.png")
        gt_lines.append(f"{stamp:.4f} {i * 0.1} 0 0 0 0 0 1")
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    (root / "groundtruth.txt").write_text("\n".join(gt_lines) + "\n")


def test_tum_folder_is_parsed_lazily_with_folder_intrinsics(tmp_path: Path) -> None:
    root = tmp_path / "rgbd_dataset_freiburg1_xyz"
    _write_tum(root)
    assert guess_kind(root) == "tum"
    source = open_source(root)
    assert len(source) == 5
    assert source.intrinsics == TUM_INTRINSICS["freiburg1"]
    frames = list(source)
    assert frames[2].rgb[0, 0, 0] == 20 and frames[2].rgb.shape == (48, 64, 3)
    assert frames[3].depth[0, 0] == pytest.approx(4.0)
    gt = source.groundtruth()
    assert gt is not None and len(gt) == 5


def test_unknown_folder_uses_ros_default(tmp_path: Path) -> None:
    root = tmp_path / "mydata"
    _write_tum(root, n=2)
    assert open_source(root).intrinsics.fx == 525.0


def test_depth_too_far_in_time_is_not_associated(tmp_path: Path) -> None:
    root = tmp_path / "far"
    _write_tum(root, n=1, depth_offset=0.025)
    with pytest.raises(DatasetError, match="no RGB/depth pairs"):
        open_source(root, "tum")


def test_malformed_list_names_file_and_line(tmp_path: Path) -> None:
    root = tmp_path / "bad"
    _write_tum(root, n=2)
    with (root / "rgb.txt").open("a") as f:
        f.write("notanumber rgb/x.png\n")
    with pytest.raises(DatasetError, match=r"rgb\.txt:6: timestamp 'notanumber'"):
        open_source(root)


def test_associate_is_greedy_by_smallest_difference() -> None:
    assert associate([0.0, 0.03, 0.06], [0.011, 0.029, 0.2]) == [(0, 0), (1, 1)]


def test_sim_export_reads_camera_file_and_odometry(tmp_path: Path) -> None:
    root = tmp_path / "export"
    _write_tum(root, n=3)
    (root / "intrinsics.yaml").write_text("fx: 100\nfy: 101\ncx: 31.5\ncy: 23.5\nwidth: 64\nheight: 48\n")
    (root / "odometry.txt").write_text((root / "groundtruth.txt").read_text())
    assert guess_kind(root) == "sim"
    source = open_source(root)
    assert source.intrinsics.fy == 101.0
    frames = list(source)
    assert frames[1].prior is not None and frames[1].prior[0, 3] == pytest.approx(0.1)
    assert frames[2].groundtruth is not None


def test_unknown_kind_is_an_error(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="cannot tell"):
        open_source(tmp_path)


def test_float_depth_is_refused_and_a_suspicious_scale_warned_about(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Issue 18, item 6: a float .tiff depth gave an identity trajectory without a word; millimetre data with TUM's
    scale went unnoticed."""
    root = tmp_path / "seq"
    _write_tum(root, n=2)
    first = sorted((root / "depth").iterdir())[0]
    cv2.imwrite(str(first), np.full((48, 64), 1500, np.uint16))  # 1.5 m written in millimetres
    with caplog.at_level("WARNING"):
        frames = list(open_source(root))
    assert frames[0].depth[0, 0] == pytest.approx(0.3)  # read with 5000 per metre, as asked ...
    assert "millimetre data needs depth_scale 1000" in caplog.text  # ... and said loudly
    tiff = first.with_suffix(".tiff")
    cv2.imwrite(str(tiff), np.full((48, 64), 1.5, np.float32))
    depth_list = root / "depth.txt"
    depth_list.write_text(depth_list.read_text().replace(first.name, tiff.name))
    with pytest.raises(DatasetError, match=r"depth image is float32, TUM depth is 16-bit"):
        list(open_source(root))
