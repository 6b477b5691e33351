"""MCAP recordings of camera topics (``sensor_msgs/msg/Image`` colour + depth, ``CameraInfo``).

Messages are CDR-encoded ROS 2 types, decoded with fleetslam's typestore (ROS 2 Jazzy and our own types, no
middleware needed). A colour
image is paired with the depth image whose header stamp is closest within ``max_difference``; frames are
decoded while iterating. Depth ``16UC1`` is millimetres, ``32FC1`` metres.

Camera poses, when the recording has them (:mod:`fleetslam.datasets.recorded_poses`): the simulator's
``ground_truth/odom`` is the ground truth and the wheel odometry ``odom`` each frame's prior, both times the
camera's mounting from ``tf_static``, interpolated at the frames' stamps. Topics in the image topics' namespace
(``/c3po/...``) win over others.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable, Iterator
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from mcap.reader import make_reader
from numpy.typing import NDArray

from fleetslam.datasets.base import Intrinsics, RGBDFrame
from fleetslam.datasets.recorded_poses import (
    camera_trajectory,
    mounting,
    odometry_trajectory,
    stamp_seconds,
    static_transforms,
)
from fleetslam.errors import DatasetError, MessageError
from fleetslam.msg.conversions import depth_from_image, intrinsics_from_camera_info, rgb_from_image
from fleetslam.msg.typesys import deserialize
from fleetslam.trajectory import InterpolatedPose, Trajectory

log = logging.getLogger(__name__)

#: Odometry poses further apart than this (s) are a hole in the recording: no pose is interpolated across it.
MAX_POSE_GAP = 0.25


@contextlib.contextmanager
def _unreadable_as_dataset_error(path: Path) -> Iterator[None]:
    """A garbage or truncated file makes the mcap library raise anything from its own errors to struct's and
    zstd's: one DatasetError naming the file instead."""
    try:
        yield
    except DatasetError:
        raise
    except Exception as err:  # mcap.exceptions.McapError, struct.error, EOFError, ValueError, zstd/lz4 errors
        raise DatasetError(f"{path}: not a readable MCAP file ({type(err).__name__}: {err})") from err


def _frame_images(rgb: Any, depth: Any, where: str) -> tuple[NDArray[np.uint8], NDArray[np.float32]]:
    """RGB uint8 and depth metres of a colour/depth Image pair (see :mod:`fleetslam.msg.conversions`)."""
    try:
        return rgb_from_image(rgb), depth_from_image(depth)
    except MessageError as err:
        raise DatasetError(f"{where}: {err}") from err


class McapSource:
    """Colour/depth pairs of an MCAP file, decoded lazily."""

    def __init__(
        self,
        path: Path,
        rgb_topic: str | None = None,
        depth_topic: str | None = None,
        max_difference: float = 0.02,
        intrinsics: Intrinsics | None = None,
    ) -> None:
        if path.is_dir():
            files = sorted(path.glob("*.mcap"))
            if not files:
                raise DatasetError(f"{path}: no .mcap file in folder")
            path = files[0]
        if not path.is_file():
            raise DatasetError(f"{path}: MCAP file not found")
        self.path = path
        self.name = path.stem
        self.max_difference = max_difference
        image_topics: list[str] = []
        odometry_topics: list[str] = []
        self._tf_static_topics: list[str] = []
        info_topic: str | None = None
        with path.open("rb") as f, _unreadable_as_dataset_error(path):
            summary = make_reader(f).get_summary()
        if summary is None:
            raise DatasetError(f"{path}: MCAP file has no summary (unfinished recording?)")
        for channel in summary.channels.values():
            schema = summary.schemas.get(channel.schema_id)
            type_name = schema.name if schema is not None else ""
            if type_name == "sensor_msgs/msg/Image":
                image_topics.append(channel.topic)
            elif type_name == "sensor_msgs/msg/CameraInfo" and info_topic is None:
                info_topic = channel.topic
            elif type_name == "nav_msgs/msg/Odometry":
                odometry_topics.append(channel.topic)
            elif type_name == "tf2_msgs/msg/TFMessage" and channel.topic.endswith("tf_static"):
                self._tf_static_topics.append(channel.topic)
        self.rgb_topic = rgb_topic or next((t for t in image_topics if "depth" not in t), None)
        self.depth_topic = depth_topic or next((t for t in image_topics if "depth" in t), None)
        if self.rgb_topic is None or self.depth_topic is None:
            raise DatasetError(f"{path}: need colour and depth Image topics, found {image_topics}")
        self.camera_frame = ""
        self._index = self._pair_index()
        self.intrinsics = intrinsics or self._read_intrinsics(info_topic)
        namespace = self.depth_topic.split("/camera/")[0] if "/camera/" in self.depth_topic else ""
        self.groundtruth_topic = _pick(namespace, [t for t in odometry_topics if t.endswith("ground_truth/odom")])
        self.odometry_topic = _pick(
            namespace,
            [t for t in odometry_topics if t.endswith("/odom") and not t.endswith(("ground_truth/odom", "slam/odom"))],
        )
        self._poses: dict[str, Trajectory | None] = {}

    def _messages(self, topics: list[str]) -> Iterator[tuple[str, Any]]:
        for topic, decode in self._raw_messages(topics):
            yield topic, decode()

    def _raw_messages(self, topics: list[str]) -> Iterator[tuple[str, Callable[[], Any]]]:
        """Messages in log order, each with a function that decodes it (skipped messages cost no decoding)."""
        with self.path.open("rb") as f, _unreadable_as_dataset_error(self.path):
            for schema, channel, message in make_reader(f).iter_messages(topics=topics):
                if schema is None:
                    raise DatasetError(f"{self.path}: the messages on {channel.topic} have no schema")
                yield channel.topic, partial(self._decode, bytes(message.data), schema.name, channel.topic)

    def _decode(self, data: bytes, type_name: str, topic: str) -> Any:
        try:
            return deserialize(data, type_name)
        except MessageError as err:  # a corrupt message, or a type the typestore does not know
            raise DatasetError(f"{self.path}: a {type_name} message on {topic} cannot be decoded: {err}") from err

    def _pair_index(self) -> list[tuple[int, int]]:
        # Stamps only on this pass; images are decoded again while iterating to keep memory flat.
        stamps: dict[str, list[float]] = {self.rgb_topic or "": [], self.depth_topic or "": []}
        for topic, msg in self._messages([self.rgb_topic or "", self.depth_topic or ""]):
            stamps[topic].append(stamp_seconds(msg))
            if topic == self.depth_topic and not self.camera_frame:
                self.camera_frame = str(msg.header.frame_id)
        from fleetslam.datasets.tum import associate

        pairs = associate(stamps[self.rgb_topic or ""], stamps[self.depth_topic or ""], self.max_difference)
        if not pairs:
            raise DatasetError(f"{self.path}: no colour/depth pairs within {self.max_difference} s")
        return pairs

    def _read_intrinsics(self, info_topic: str | None) -> Intrinsics:
        if info_topic is None:
            raise DatasetError(f"{self.path}: no sensor_msgs/msg/CameraInfo topic; give the intrinsics")
        for _, msg in self._messages([info_topic]):
            try:
                return intrinsics_from_camera_info(msg)
            except MessageError as err:
                raise DatasetError(f"{self.path}: CameraInfo on {info_topic}: {err}") from err
        raise DatasetError(f"{self.path}: CameraInfo topic {info_topic} has no messages")

    def __len__(self) -> int:
        return len(self._index)

    def __iter__(self) -> Iterator[RGBDFrame]:
        return self.frames()

    def frames(self, every: int = 1) -> Iterator[RGBDFrame]:
        wanted_rgb = {i: n for n, (i, _) in enumerate(self._index) if n % every == 0}
        wanted_depth = {j: n for n, (_, j) in enumerate(self._index) if n % every == 0}
        truth, prior = self.groundtruth(), self.odometry()
        truth_at = None if truth is None else InterpolatedPose(truth, MAX_POSE_GAP, self.max_difference)
        prior_at = None if prior is None else InterpolatedPose(prior, MAX_POSE_GAP, self.max_difference)
        pending: dict[int, dict[str, Any]] = {}
        counts = {self.rgb_topic: 0, self.depth_topic: 0}
        next_out = 0
        for topic, decode in self._raw_messages([self.rgb_topic or "", self.depth_topic or ""]):
            k = counts[topic]
            counts[topic] = k + 1
            table = wanted_rgb if topic == self.rgb_topic else wanted_depth
            n = table.get(k)
            if n is None:
                continue
            slot = pending.setdefault(n, {})
            key = "rgb" if topic == self.rgb_topic else "depth"
            slot[key] = decode()
            while next_out in pending and len(pending[next_out]) == 2:
                pair = pending.pop(next_out)
                where = f"{self.path} frame {next_out}"
                stamp = stamp_seconds(pair["rgb"])
                rgb, depth = _frame_images(pair["rgb"], pair["depth"], where)
                yield RGBDFrame(
                    next_out,
                    stamp,
                    rgb,
                    depth,
                    prior=None if prior_at is None else prior_at(stamp),
                    groundtruth=None if truth_at is None else truth_at(stamp),
                )
                next_out += every

    def groundtruth(self) -> Trajectory | None:
        """The camera's ground-truth trajectory (``T_world_camera``): ``ground_truth/odom`` times the mounting."""
        return self._camera_poses(self.groundtruth_topic)

    def odometry(self) -> Trajectory | None:
        """The camera's wheel-odometry trajectory (``T_odom_camera``): ``odom`` times the mounting."""
        return self._camera_poses(self.odometry_topic)

    def _camera_poses(self, topic: str | None) -> Trajectory | None:
        if topic is None:
            return None
        if topic not in self._poses:
            self._poses[topic] = self._read_camera_poses(topic)
        return self._poses[topic]

    def _read_camera_poses(self, topic: str) -> Trajectory | None:
        _, base_frame, base = odometry_trajectory(msg for _, msg in self._messages([topic]))
        if len(base) == 0:
            return None
        transforms = static_transforms(msg for _, msg in self._messages(self._tf_static_topics))
        base_camera = mounting(transforms, base_frame, self.camera_frame)
        if base_camera is None:
            log.warning(
                "%s: %s has poses of %r, but %s has no chain of transforms from it to the images' frame %r; "
                "those poses are not used",
                self.path, topic, base_frame, " or ".join(self._tf_static_topics) or "the recording (no tf_static)",
                self.camera_frame,
            )  # fmt: skip
            return None
        return camera_trajectory(base, base_camera)


def _pick(namespace: str, topics: list[str]) -> str | None:
    """The topic in ``namespace`` (the images'), else the first one, else None."""
    own = sorted(t for t in topics if namespace and t.startswith(namespace + "/"))
    candidates = own or sorted(topics)
    return candidates[0] if candidates else None


def open_mcap(
    path: Path,
    *,
    rgb_topic: str | None = None,
    depth_topic: str | None = None,
    max_difference: float = 0.02,
    intrinsics: Intrinsics | None = None,
) -> McapSource:
    """Open an MCAP recording (topics guessed: the Image topic with 'depth' in its name is the depth)."""
    return McapSource(path, rgb_topic, depth_topic, max_difference, intrinsics)
