"""The examples of docs/extending.md, run as a user runs them: a new odometry front-end through the offline
pipeline, and a camera driver publishing to a real router on loopback."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.msg.conversions import transform_matrix
from fleetslam.trajectory import read_tum

from ..support import wait_until

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def run_example(name: str, *args: str, timeout_s: float = 120.0) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "FLEETSLAM_LISTEN": "tcp/127.0.0.1:0"}
    env.pop("FLEETSLAM_ROUTER", None)
    return subprocess.run(
        [sys.executable, str(EXAMPLES / f"{name}.py"), *args],
        capture_output=True, text=True, timeout=timeout_s, env=env, check=False,
    )  # fmt: skip


def test_wheel_odometry_front_end_example(tmp_path: Path) -> None:
    done = run_example("wheel_odometry_frontend", "--frames", "40", "--out", str(tmp_path / "out"))
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout.strip().splitlines()[-1])
    # 1.2 m of a circle, a keyframe every 25 cm; loop closure off (no features); the wheels' 2 % slip on one side
    # and 1 % on the radius leave a few millimetres after alignment.
    assert summary["frames"] == 40 and 4 <= summary["keyframes"] <= 6
    assert summary["loop_closure"] is False and not (tmp_path / "out" / "map.db").exists()
    assert 0.0 < summary["ate_cm"] < 1.0
    assert len(read_tum(tmp_path / "out" / "trajectory.txt")) == 40


def test_camera_driver_example(router_endpoint: str, make_context: Any) -> None:
    spec = importlib.util.spec_from_file_location("camera_driver", EXAMPLES / "camera_driver.py")
    assert spec is not None and spec.loader is not None
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    received: dict[str, list[Any]] = {"rgb": [], "depth": [], "info": [], "tf_static": []}
    context: Context = make_context()
    with Node("listener", context=context) as listener:
        for key, type_name, topic in (
            ("rgb", "sensor_msgs/msg/Image", "/cam0/camera/rgb/image_raw"),
            ("depth", "sensor_msgs/msg/Image", "/cam0/camera/depth/image_raw"),
            ("info", "sensor_msgs/msg/CameraInfo", "/cam0/camera/rgb/camera_info"),
        ):
            listener.create_subscription(type_name, topic, received[key].append, QoSProfile(depth=20))
        listener.create_subscription(
            "tf2_msgs/msg/TFMessage", "/cam0/tf_static", received["tf_static"].append,
            QoSProfile(durability="transient_local", depth=1),
        )  # fmt: skip
        done = run_example(
            "camera_driver", "--router", router_endpoint, "--namespace", "/cam0", "--frames", "10", "--rate", "20",
            "--wait-subscriber", "20",
        )  # fmt: skip
        assert done.returncode == 0, done.stderr
        wait_until(lambda: min(len(received[k]) for k in ("rgb", "depth", "info")) == 10, 5.0)
    counts = {key: len(messages) for key, messages in received.items()}
    # The camera's publishers keep the last frames and drop under congestion (rmw_zenoh's KEEP_LAST): on a starved
    # machine a frame may be dropped; what arrives must be exact.
    assert min(counts["rgb"], counts["depth"], counts["info"]) >= 8, counts
    assert "synthetic: 10 frames published" in done.stderr
    shifts = []
    for rgb in received["rgb"]:
        assert (rgb.width, rgb.height, rgb.encoding) == (160, 120, "rgb8")
        pixels = np.asarray(rgb.data).reshape(120, 160, 3)
        (shift,) = [i for i in range(10) if np.array_equal(pixels, example.checkerboard(160, 120, i))]
        shifts.append(shift)
    assert shifts == sorted(set(shifts))  # each frame once, in order
    for depth in received["depth"]:
        metres = np.frombuffer(np.asarray(depth.data).tobytes(), "<f4").reshape(120, 160)
        assert (metres[:, :20] == 0).all() and (metres[:, 20:] == 2.0).all()
    rgb_stamps = {(m.header.stamp.sec, m.header.stamp.nanosec) for m in received["rgb"]}
    for info in received["info"]:
        assert info.k[0] == 128.0
    assert len(rgb_stamps & {(m.header.stamp.sec, m.header.stamp.nanosec) for m in received["info"]}) >= 8
    (transform,) = received["tf_static"][-1].transforms
    np.testing.assert_allclose(transform_matrix(transform.transform), example.BASE_CAMERA, atol=1e-12)
