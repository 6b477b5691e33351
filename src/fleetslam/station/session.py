"""Reviewing a finished run in the console (``fleetslam station --session DIR``): no robot, no middleware.

Read from the run's directory as the inspection report reads it (:mod:`fleetslam.inspection.report`): the maps
(``maps/<agent>.bt`` in the agent's map frame, ``maps/fleet.bt`` in the fleet frame), SLAM's trajectories
(``trajectories/<agent>.txt``, the camera in the agent's map frame), where each map lies in the fleet frame
(``fleet_frame.json``) and the findings (``findings/``). The page gets them as it gets a live fleet's, plus a
``session`` message: every agent's trajectory with its stamps, which its time slider replays (marker and path up to
the slider's time). The camera is replayed only when the run's recording (``recording/``) holds camera images
(``/<agent>/camera/rgb/image_raw``): the page asks for the frame nearest the slider's time (``session_frame``
{agent, t} → ``image``). The demo records no images by default (a few MB a second): then the camera panel says so.

Which way is up: the cameras' mounting when the recording holds ``tf_static``, else the plane the robots moved in
(the report's :func:`fleetslam.inspection.report.levelling_rotation`), so the review is drawn level as the live
console draws it.
"""

from __future__ import annotations

import base64
import bisect
import logging
from pathlib import Path
from typing import Any

import numpy as np

from fleetslam.errors import FleetslamError
from fleetslam.inspection.findings import FindingStore
from fleetslam.inspection.report import levelling_rotation
from fleetslam.inspection.run_folder import occupied_centres, read_placements, read_trajectories
from fleetslam.station.bridge import FLEET_AGENT, Emit, encode_image, robot_pose
from fleetslam.station.findings import cdr_image_stamp, finding_json
from fleetslam.station.protocol import TeleopGate, VoxelDiff

log = logging.getLogger(__name__)

CAMERA_TOPIC = "/{agent}/camera/rgb/image_raw"
FRAME_WINDOW_NS = 500_000_000
"""A replayed camera frame is the recording's nearest within this of the slider's time."""
REFUSED = "reviewing a finished run: no robot to command"


class SessionFindings:
    """The findings of the run, read only: photos are shown, nothing is picked, created or changed."""

    def __init__(self, run: Path) -> None:
        directory = run / "findings"
        self.store = FindingStore.load(directory) if (directory / "findings.json").is_file() else FindingStore()

    def message(self) -> dict[str, Any]:
        return {"type": "findings", "findings": [finding_json(f) for f in self.store.findings]}

    def photo(self, finding_id: str) -> dict[str, Any]:
        found = {f.id: f for f in self.store.findings}.get(finding_id)
        photo, crop = (found.photo, found.crop) if found is not None else (b"", b"")
        return {"type": "finding_photo", "id": finding_id, "photo": base64.b64encode(photo).decode(),
                "crop": base64.b64encode(crop).decode()}  # fmt: skip

    def pick(self, agent: str, stamp_ns: int, u: float, v: float) -> dict[str, Any]:
        return {"type": "finding_pick", "ok": False, "message": REFUSED}

    def create(self, pick_id: str, title: str, severity: str, note: str) -> dict[str, Any]:
        return {"type": "finding_created", "ok": False, "id": "", "message": REFUSED}

    def update(self, finding_id: str, changes: dict[str, str]) -> dict[str, Any]:
        return {"type": "finding_updated", "ok": False, "id": finding_id, "message": REFUSED}

    def locate(self, agent: str, stamp_ns: int, u: float, v: float) -> dict[str, Any]:
        return {"type": "measure_point", "ok": False, "message": REFUSED}


class SessionBridge:
    """What the console's server asks of its bridge, answered from a finished run's directory."""

    def __init__(self, run: Path, emit: Emit, *, voxel_resolution: float = 0.05) -> None:
        if not run.is_dir():
            raise FleetslamError(f"--session {run}: not a directory")
        self.run = run
        self.emit = emit
        self.voxel_resolution = voxel_resolution
        self.gate = TeleopGate()
        self.findings = SessionFindings(run)
        self.trajectories = read_trajectories(run, "trajectories")
        if not self.trajectories and not (run / "maps").is_dir():
            raise FleetslamError(f"--session {run}: no trajectories/ and no maps/: not a fleetslam run")
        self.placements = {a: p for a, p in read_placements(run).items() if a in self.trajectories}
        self._recorded = self._recorded_mountings()
        self.mountings = self._mountings()
        self._frames = self._index_frames()
        """Per agent with a recorded camera: (header stamps, the recording's timestamps) of its frames, sorted."""
        self._messages = self._load()

    # -- reading the run ---------------------------------------------------------------------------------------
    def _recording(self) -> Path | None:
        folder = self.run / "recording"
        return folder if (folder / "metadata.yaml").is_file() else None

    def _index_frames(self) -> dict[str, tuple[list[int], list[int]]]:
        """The recorded camera frames' header stamps (read without decoding the pixels), to find one by stamp."""
        recording = self._recording()
        if recording is None:
            return {}
        from fleetslam.middleware.recording import bag_topics, read_bag

        topics = {CAMERA_TOPIC.format(agent=a): a for a in self.trajectories}
        wanted = set(topics) & set(bag_topics(recording))
        index: dict[str, list[tuple[int, int]]] = {}
        for message in read_bag(recording, wanted) if wanted else ():
            index.setdefault(topics[message.topic], []).append((cdr_image_stamp(message.data), message.timestamp_ns))
        return {a: ([s for s, _ in sorted(f)], [r for _, r in sorted(f)]) for a, f in index.items()}

    def _mountings(self) -> dict[str, list[float]]:
        """``T_base_camera`` per agent (row-major), as the page draws it upright: the recorded ``tf_static``, else
        levelled by the plane the cameras moved in (a mounting that turns the fleet frame level)."""
        if self._recorded:
            return self._recorded
        placed = [(self.placements[a], t) for a, t in self.trajectories.items() if a in self.placements and len(t)]
        if not placed:
            return {}
        rotations = np.concatenate([T[:3, :3] @ t.poses[:, :3, :3] for T, t in placed])
        positions = np.concatenate([t.positions @ T[:3, :3].T + T[:3, 3] for T, t in placed])
        level = np.eye(4)
        level[:3, :3] = levelling_rotation(rotations, positions)
        # The page turns the fleet frame by mounting · placement⁻¹ of the first placed agent: this makes it ``level``.
        return {a: [float(v) for v in (level @ self.placements[a]).reshape(-1)] for a in self.placements}

    def _recorded_mountings(self) -> dict[str, list[float]]:
        recording = self._recording()
        if recording is None:
            return {}
        from fleetslam.datasets.recorded_poses import mounting, static_transforms
        from fleetslam.middleware.recording import bag_topics, read_bag
        from fleetslam.msg.typesys import deserialize

        out: dict[str, list[float]] = {}
        topics = bag_topics(recording)
        for agent in self.trajectories:
            topic = f"/{agent}/tf_static"
            if topic not in topics:
                continue
            messages = [deserialize(m.data, m.type_name) for m in read_bag(recording, {topic})]
            transforms = static_transforms(messages)
            camera = next((c for c in transforms if c.endswith("optical_frame")), None)
            found = mounting(transforms, "base_link", camera) if camera else None
            if found is not None:
                out[agent] = [float(v) for v in found.reshape(-1)]
        return out

    def _load(self) -> list[dict[str, Any]]:
        out: list[dict[str, Any]] = []
        maps = self.run / "maps"
        for agent in [*sorted(self.trajectories), FLEET_AGENT]:
            path = maps / f"{agent}.bt"
            if not path.is_file():
                continue
            try:
                centres = occupied_centres(path)
            except (FleetslamError, OSError, ValueError) as err:
                log.warning("%s: %s", path, err)
                continue
            voxels = VoxelDiff(self.voxel_resolution)
            keys, _ = voxels.update(centres)
            out.append({"type": "voxels", "agent": agent, "size": self.voxel_resolution, "add": keys,
                        "remove": keys[:0], "total": len(keys), "reset": True})  # fmt: skip
        for agent in sorted(self.trajectories):
            placement = self.placements.get(agent)
            placed = None if placement is None else [float(v) for v in placement.reshape(-1)]
            out.append({"type": "frame", "agent": agent, "mounting": self.mountings.get(agent), "placement": placed})
        out.append(self.findings.message())
        out.append(self.session_message())
        return out

    def session_message(self) -> dict[str, Any]:
        """``session`` {start, end (s), camera: agents whose camera was recorded, agents: {agent: {stamps (s),
        poses [[x, y, z, qx, qy, qz, qw]] of the base in the map frame}}}."""
        agents: dict[str, Any] = {}
        for agent, trajectory in sorted(self.trajectories.items()):
            mounting = self._marker_mounting(agent)
            poses = []
            for camera in trajectory.poses:
                base = robot_pose(camera, mounting)
                poses.append([round(base["x"], 4), round(base["y"], 4), round(base["z"], 4), *base["q"]])
            agents[agent] = {"stamps": [round(float(s), 4) for s in trajectory.stamps], "poses": poses}
        stamps = [s for a in agents.values() for s in a["stamps"]]
        return {"type": "session", "run": self.run.name, "start": min(stamps, default=0.0),
                "end": max(stamps, default=0.0), "camera": sorted(self._frames), "agents": agents}  # fmt: skip

    def _marker_mounting(self, agent: str) -> list[float] | None:
        """The mounting the marker's base is found through: the recorded one; else a level camera."""
        return self._recorded.get(agent)

    # -- what the server asks ------------------------------------------------------------------------------------
    def agent_names(self) -> list[str]:
        return sorted(self.trajectories)

    def snapshot(self) -> list[dict[str, Any]]:
        return [{"type": "agents", "agents": self.agent_names()}, *self._messages]

    def tick_teleop(self, now: float) -> dict[str, tuple[float, float]]:
        return {}

    def estop(self, agent: str, engage: bool, timeout_s: float = 3.0) -> tuple[bool, str]:
        return False, REFUSED

    def frame(self, agent: str, t: float) -> dict[str, Any]:
        """The recorded camera frame of ``agent`` nearest ``t`` (s, the trajectories' clock), as an ``image``."""
        frames, recording = self._frames.get(agent), self._recording()
        if frames is None or recording is None:
            return {"type": "session_frame", "ok": False, "message": f"the recording holds no camera of {agent!r}"}
        stamps, received = frames
        i = nearest_index(stamps, int(t * 1e9))
        if abs(stamps[i] - t * 1e9) > FRAME_WINDOW_NS:
            return {"type": "session_frame", "ok": False, "message": f"no camera frame of {agent!r} near {t:.1f} s"}
        from rosbags.rosbag2 import Reader

        from fleetslam.msg.typesys import deserialize

        with Reader(recording) as reader:
            connections = [c for c in reader.connections if c.topic == CAMERA_TOPIC.format(agent=agent)]
            messages = reader.messages(connections=connections, start=received[i], stop=received[i] + 1)
            payload = next((bytes(d) for _, _, d in messages if cdr_image_stamp(d) == stamps[i]), None)
        if payload is None:
            return {"type": "session_frame", "ok": False, "message": f"the recording lost {agent!r}'s frame"}
        mime, data = encode_image(deserialize(payload, "sensor_msgs/msg/Image"), "rgb")
        return {"type": "image", "agent": agent, "kind": "rgb", "mime": mime, "seq": i + 1, "stamp": str(stamps[i]),
                "data": base64.b64encode(data).decode(), "replay": True}  # fmt: skip

    def close(self) -> None:
        pass


def nearest_index(stamps: list[int], t: int) -> int:
    """Index of the stamp nearest ``t`` (sorted stamps, at least one)."""
    i = bisect.bisect_left(stamps, t)
    if i == 0:
        return 0
    if i >= len(stamps):
        return len(stamps) - 1
    return i if stamps[i] - t < t - stamps[i - 1] else i - 1
