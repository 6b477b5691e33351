"""Keyframe summaries: what is kept, how small they are on the wire, and hostile messages refused by field."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fleetslam.datasets.base import Intrinsics
from fleetslam.errors import MessageError
from fleetslam.fusion.keyframe_summary import (
    KEYPOINT_SUBPIXELS,
    spread_selection,
    summarize,
    summary_fields,
    summary_from_message,
)
from fleetslam.geometry import random_pose
from fleetslam.msg.typesys import deserialize, message_from_dict, serialize

TYPE = "fleetslam_msgs/msg/KeyframeSummary"
INTRINSICS = Intrinsics(fx=525.0, fy=525.0, cx=319.5, cy=239.5, width=640, height=480)


def keyframe_features(rng: np.random.Generator, n: int = 1000):
    keypoints = rng.uniform([0, 0], [640, 480], size=(n, 2)).astype(np.float32)
    depth = rng.uniform(0.4, 6.0, n)
    depth[rng.random(n) < 0.2] = np.nan  # no depth: not summarised
    points = np.column_stack(
        [(keypoints[:, 0] - 319.5) / 525.0 * depth, (keypoints[:, 1] - 239.5) / 525.0 * depth, depth]
    )
    descriptors = rng.integers(0, 256, size=(n, 32), dtype=np.uint8)
    return keypoints, points, descriptors


def wire_round_trip(summary, pose_ns: int = 123):
    fields = summary_fields(summary)
    fields["header"] = {"stamp": {"sec": 0, "nanosec": pose_ns}, "frame_id": "c3po/map"}
    data = serialize(message_from_dict(TYPE, fields), TYPE)
    return data, deserialize(data, TYPE)


def test_a_summary_keeps_features_with_depth_spread_over_the_image_and_fits_20_kB() -> None:
    rng = np.random.default_rng(1)
    keypoints, points, descriptors = keyframe_features(rng)
    pose = random_pose(rng)
    summary = summarize("c3po", 12, 5, pose, INTRINSICS, keypoints, points, descriptors, max_features=400, epoch=77)
    assert len(summary) == 400
    assert np.isfinite(summary.depth).all()
    # Spread: every cell of a 4x4 grid keeps a fair share of the 400.
    cells = (summary.keypoints[:, 0] // 160).astype(int) * 4 + (summary.keypoints[:, 1] // 120).astype(int)
    assert np.bincount(cells, minlength=16).min() >= 15
    data, msg = wire_round_trip(summary)
    assert len(data) <= 20_000, len(data)
    back = summary_from_message(msg, pose, 5)
    np.testing.assert_array_equal(back.keypoints, summary.keypoints)
    np.testing.assert_allclose(back.depth, summary.depth, atol=1e-6)
    np.testing.assert_array_equal(back.descriptors, summary.descriptors)
    assert back.epoch == 77
    assert back.intrinsics == INTRINSICS
    # The 3D points are the originals within the quantisation: 1/16 px and half a millimetre.
    original = {tuple(d): p for d, p in zip(descriptors.tolist(), points, strict=True)}
    sent = np.array([original[tuple(d)] for d in back.descriptors.tolist()])
    assert np.abs(back.points3d - sent).max() < 0.002


def test_selection_is_deterministic_and_takes_everything_when_few() -> None:
    rng = np.random.default_rng(2)
    keypoints = rng.uniform([0, 0], [640, 480], size=(900, 2))
    first = spread_selection(keypoints, 300, 640, 480)
    np.testing.assert_array_equal(first, spread_selection(keypoints, 300, 640, 480))
    assert len(np.unique(first)) == 300
    np.testing.assert_array_equal(spread_selection(keypoints[:50], 300, 640, 480), np.arange(50))


def test_keypoints_are_quantised_as_on_the_wire() -> None:
    keypoints = np.array([[100.03, 200.49]], np.float32)
    summary = summarize("c3po", 1, 0, np.eye(4), INTRINSICS, keypoints, np.array([[0.1, 0.2, 1.0]]),
                        np.zeros((1, 32), np.uint8))  # fmt: skip
    assert np.all(summary.keypoints * KEYPOINT_SUBPIXELS == np.round(summary.keypoints * KEYPOINT_SUBPIXELS))
    assert np.abs(summary.keypoints - keypoints).max() <= 0.5 / KEYPOINT_SUBPIXELS


@pytest.mark.parametrize(
    ("field", "value", "named"),
    [
        ("keypoints", np.zeros(3, np.uint16), "keypoint values"),
        ("descriptors", np.zeros(5, np.uint8), "descriptor bytes"),
        ("descriptor_length", 0, "descriptor_length"),
        ("depth_mm", np.zeros(2, np.uint16), "depth 0"),
        ("intrinsics", np.array([np.nan, 1.0, 1.0, 1.0]), "intrinsics"),
        ("intrinsics", np.array([-5.0, 1.0, 1.0, 1.0]), "focal lengths"),
        ("width", 0, "image size"),
    ],
)
def test_a_malformed_summary_is_refused_naming_the_field(field: str, value: object, named: str) -> None:
    summary = summarize(
        "r2d2", 4, 0, np.eye(4), INTRINSICS, np.array([[10.0, 20.0], [30.0, 40.0]]),
        np.array([[0.0, 0.0, 1.0], [0.1, 0.1, 2.0]]), np.zeros((2, 32), np.uint8),
    )  # fmt: skip
    fields = summary_fields(summary)
    fields["header"] = {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": "r2d2/map"}
    fields[field] = value
    msg = deserialize(serialize(message_from_dict(TYPE, fields), TYPE), TYPE)
    with pytest.raises(MessageError, match=named) as caught:
        summary_from_message(msg, np.eye(4), 0)
    assert "'r2d2'" in str(caught.value)


def test_too_many_features_or_a_non_finite_pose_are_refused() -> None:
    n = 5000
    fields = {
        "agent": "r2d2", "id": 1, "intrinsics": np.array([525.0, 525.0, 319.5, 239.5]), "width": 640,
        "height": 480, "keypoints": np.ones(2 * n, np.uint16), "depth_mm": np.ones(n, np.uint16),
        "descriptor_length": 1, "descriptors": np.zeros(n, np.uint8),
    }  # fmt: skip
    msg = deserialize(serialize(message_from_dict(TYPE, fields), TYPE), TYPE)
    with pytest.raises(MessageError, match="5000 features"):
        summary_from_message(msg, np.eye(4), 0)
    fields.update(keypoints=np.ones(2, np.uint16), depth_mm=np.ones(1, np.uint16), descriptors=np.zeros(1, np.uint8))
    msg = deserialize(serialize(message_from_dict(TYPE, fields), TYPE), TYPE)
    bad_pose = np.eye(4)
    bad_pose[0, 3] = np.inf
    with pytest.raises(MessageError, match="pose"):
        summary_from_message(msg, bad_pose, 0)


def test_summaries_are_frozen() -> None:
    summary = summarize("c3po", 1, 0, np.eye(4), INTRINSICS, np.zeros((0, 2)), np.zeros((0, 3)),
                        np.zeros((0, 32), np.uint8))  # fmt: skip
    assert len(summary) == 0
    with pytest.raises(dataclasses.FrozenInstanceError):
        summary.agent = "x"  # type: ignore[misc]
