"""The generated RViz configuration names every agent's topics and is what `fleetslam bridge rviz-config` writes."""

from __future__ import annotations

from pathlib import Path

import yaml

from fleetslam.cli.main import main
from fleetslam.ros1.rviz import rviz_config


def test_each_agent_gets_its_maps_path_keyframes_pose_and_camera(tmp_path: Path) -> None:
    out = tmp_path / "fleet.rviz"
    assert main(["bridge", "rviz-config", "c3po", "r2d2", "--fixed-frame", "fleet", "-o", str(out)]) == 0
    document = yaml.safe_load(out.read_text(encoding="utf-8"))
    assert out.read_text(encoding="utf-8") == rviz_config(["c3po", "r2d2"], fixed_frame="fleet")
    manager = document["Visualization Manager"]
    assert manager["Global Options"]["Fixed Frame"] == "fleet"
    topics = {d.get("Topic", d.get("Marker Topic")) for d in manager["Displays"]}
    for agent in ("c3po", "r2d2"):
        for topic in ("map/occupied", "map/markers", "path", "slam/odom", "camera/rgb/image_raw"):
            assert f"/{agent}/{topic}" in topics
    colours = {d["Color"] for d in manager["Displays"] if d["Name"] in ("c3po map", "r2d2 map")}
    assert len(colours) == 2
    (keyframes,) = [d for d in manager["Displays"] if d.get("Topic") == "/c3po/path"]
    assert keyframes["Class"] == "rviz/Path" and keyframes["Pose Style"] == "Axes"  # a set of axes per keyframe
