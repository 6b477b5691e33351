"""RViz 1 display configurations for a fleet (pure: agents in, the `.rviz` YAML document out).

Per agent: its map as a box cloud (``map/occupied``) and as cube-list markers (``map/markers``), its SLAM path
with a set of axes on every keyframe (``path`` is the keyframes' poses), its pose, its camera image, and tf; plus
the fused fleet map. Each agent gets its own colour.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import yaml

#: RGB colours given to agents in order (the console's palette order: red, blue, green, amber, violet).
AGENT_COLOURS = ["230; 57; 70", "69; 123; 157", "42; 157; 143", "233; 196; 106", "131; 56; 236"]


def _display(cls: str, name: str, topic: str | None = None, options: dict[str, Any] | None = None) -> dict[str, Any]:
    display: dict[str, Any] = {"Class": f"rviz/{cls}", "Name": name, "Enabled": True}
    if topic is not None:
        display["Marker Topic" if cls == "MarkerArray" else "Topic"] = topic
    display.update(options or {})
    return display


def _boxes(colour: str | None) -> dict[str, Any]:
    colouring = {"Color Transformer": "FlatColor", "Color": colour} if colour else {"Color Transformer": "AxisColor"}
    return {"Style": "Boxes", "Size (m)": 0.05, "Queue Size": 2, **colouring}


def _keyframe_axes(colour: str) -> dict[str, Any]:
    """SLAM's ``path`` is its keyframes' poses: the line joins them and each is drawn as a set of axes."""
    return {"Color": colour, "Line Style": "Lines", "Pose Style": "Axes", "Length": 0.2, "Radius": 0.02}


def agent_displays(agent: str, colour: str) -> list[dict[str, Any]]:
    ns = f"/{agent.strip('/')}"
    return [
        _display("PointCloud2", f"{agent} map", f"{ns}/map/occupied", _boxes(colour)),
        _display("MarkerArray", f"{agent} map cubes", f"{ns}/map/markers", {"Queue Size": 2}),
        _display("Path", f"{agent} path and keyframes", f"{ns}/path", _keyframe_axes(colour)),
        _display("Odometry", f"{agent} pose", f"{ns}/slam/odom", {"Keep": 1, "Shape": {"Value": "Axes"}}),
        _display("Image", f"{agent} camera", f"{ns}/camera/rgb/image_raw", {"Transport Hint": "raw", "Queue Size": 2}),
    ]


def rviz_config(agents: Sequence[str], *, fixed_frame: str = "map", width: int = 1024, height: int = 768) -> str:
    """The `.rviz` file showing ``agents`` (names without slashes, e.g. ``c3po``) in ``fixed_frame``."""
    displays: list[dict[str, Any]] = [
        _display("Grid", "grid", options={"Cell Size": 1, "Plane Cell Count": 20}),
        _display("TF", "tf", options={"Show Names": True, "Marker Scale": 0.5}),
        _display("PointCloud2", "fleet map", "/fleet/map/occupied", _boxes(None)),
    ]
    for index, agent in enumerate(agents):
        displays += agent_displays(agent, AGENT_COLOURS[index % len(AGENT_COLOURS)])
    document = {
        "Panels": [{"Class": "rviz/Displays", "Name": "Displays"}],
        "Visualization Manager": {
            "Class": "",
            "Displays": displays,
            "Enabled": True,
            "Global Options": {"Background Color": "48; 48; 48", "Fixed Frame": fixed_frame, "Frame Rate": 10},
            "Name": "root",
            "Tools": [{"Class": "rviz/MoveCamera"}, {"Class": "rviz/Select"}, {"Class": "rviz/Measure"}],
            "Value": True,
            "Views": {
                "Current": {
                    "Class": "rviz/Orbit",
                    "Distance": 12.0,
                    "Focal Point": {"X": 0.0, "Y": 0.0, "Z": 0.0},
                    "Pitch": 0.8,
                    "Yaw": 0.8,
                    "Name": "Current View",
                    "Target Frame": "<Fixed Frame>",
                }
            },
        },
        "Window Geometry": {"Height": height, "Width": width, "X": 0, "Y": 0, "Hide Left Dock": True},
    }
    return yaml.safe_dump(document, sort_keys=False, width=120)
