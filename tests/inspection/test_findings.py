"""The findings store (validation, files written and read back) and the picking and anchoring of points."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from fleetslam.errors import FindingError
from fleetslam.geometry import pose_from_xyz_rpy, random_pose, transform_points
from fleetslam.inspection.findings import (
    Finding,
    FindingStore,
    anchor_to_keyframe,
    anchored_position,
    crop_around,
    pick_point,
)
from fleetslam.intrinsics import Intrinsics


def _jpeg(seed: int, size: tuple[int, int] = (48, 64)) -> bytes:
    pixels = np.random.default_rng(seed).integers(0, 255, (*size, 3), dtype=np.uint8)
    ok, data = cv2.imencode(".jpg", pixels)
    assert ok
    return data.tobytes()


def _draft(**changes: object) -> Finding:
    base = Finding(
        id="", title="corroded flange", severity="high", status="", note="north side, <b>flaking</b>",
        agent="c3po", keyframe_id=3, point=(0.1, -0.2, 1.5), pixel=(120.5, 80.0), stamp_ns=1_700_000_000_000_000_000,
        photo=_jpeg(1), crop=_jpeg(2, (24, 24)),
    )  # fmt: skip
    return replace(base, **changes)  # type: ignore[arg-type]


def test_findings_are_numbered_saved_and_read_back(tmp_path: Path) -> None:
    store = FindingStore(tmp_path / "findings")
    first = store.create(_draft())
    second = store.create(_draft(title="leak", severity="critical", agent="r2d2", photo=b"", crop=b""))
    assert (first.id, first.status, second.id) == ("F001", "open", "F002")
    store.update("F002", note="dripping")
    closed = store.close("F001", note="fixed on site")
    assert (closed.status, closed.note, closed.title) == ("closed", "fixed on site", "corroded flange")
    assert store.set_positions({"F001": (np.array([1.0, 2.0, 3.0]), None)})
    assert not store.set_positions({"F001": (np.array([1.0, 2.0, 3.0]), None)})  # unchanged
    store.save()
    folder = tmp_path / "findings"
    assert sorted(p.name for p in folder.iterdir()) == ["F001.jpg", "F001_crop.jpg", "findings.json"]
    assert (folder / "F001.jpg").read_bytes() == first.photo
    document = json.loads((folder / "findings.json").read_text())
    assert [f["id"] for f in document["findings"]] == ["F001", "F002"]
    assert document["findings"][0]["photo"] == "F001.jpg" and document["findings"][1]["photo"] == ""

    loaded = FindingStore.load(folder)
    assert loaded.findings == store.findings  # every field, the images' bytes included
    assert loaded.get("F001").position == (1.0, 2.0, 3.0)
    assert loaded.create(_draft()).id == "F003"  # numbering goes on after a reload


@pytest.mark.parametrize(
    ("changes", "field_and_value"),
    [
        ({"title": "  "}, "title '  '"),
        ({"severity": "urgent"}, "severity 'urgent'"),
        ({"status": "pending"}, "status 'pending'"),
        ({"agent": ""}, "agent ''"),
        ({"point": (0.0, float("nan"), 1.0)}, "point (0.0, nan, 1.0)"),
        ({"photo": b"\x89PNG"}, "photo b'\\x89PNG'"),
        ({"keyframe_id": -1}, "keyframe_id -1"),
    ],
)
def test_invalid_findings_are_refused_naming_field_and_value(
    tmp_path: Path, changes: dict[str, object], field_and_value: str
) -> None:
    store = FindingStore(tmp_path)
    with pytest.raises(FindingError, match=f"finding \\(new\\): {_escape(field_and_value)}"):
        store.create(_draft(**changes))
    assert store.findings == [] and not (tmp_path / "findings.json").exists()


def _escape(text: str) -> str:
    import re

    return re.escape(text)


def test_updates_are_validated_and_unknown_ids_named(tmp_path: Path) -> None:
    store = FindingStore(tmp_path)
    store.create(_draft())
    with pytest.raises(FindingError, match="finding F001: severity 'severe' is not one of info, low"):
        store.update("F001", severity="severe")
    assert store.get("F001").severity == "high"
    with pytest.raises(FindingError, match="no finding 'F009' \\(known: F001\\)"):
        store.close("F009")


def test_a_malformed_findings_file_is_named(tmp_path: Path) -> None:
    (tmp_path / "findings.json").write_text('{"findings": [{"id": "F001"}]}')
    with pytest.raises(FindingError, match=r"findings\.json finding 0: malformed finding"):
        FindingStore.load(tmp_path)
    (tmp_path / "findings.json").write_text("not json")
    with pytest.raises(FindingError, match=r"findings\.json: not a findings file"):
        FindingStore.load(tmp_path)
    assert FindingStore.load(tmp_path / "absent").findings == []


def test_a_picked_pixel_is_the_point_its_depth_shows() -> None:
    intrinsics = Intrinsics(200.0, 210.0, 79.5, 59.5, 160, 120)
    depth = np.full((120, 160), 2.0, dtype=np.float32)
    depth[:, 100:] = 3.0
    depth[50, 40] = 0.0  # a hole: the median around it
    assert np.allclose(pick_point(depth, intrinsics, 120.0, 30.0), [(120 - 79.5) / 200 * 3, (30 - 59.5) / 210 * 3, 3])
    assert np.allclose(pick_point(depth, intrinsics, 40.0, 50.0)[2], 2.0)
    # A half-resolution depth image of the same camera: intrinsics scaled to it.
    half = depth[::2, ::2]
    assert np.allclose(pick_point(half, intrinsics, 20.0, 10.0)[2], 2.0)
    with pytest.raises(FindingError, match=r"pixel \(170.0, 10.0\) is outside the 160x120 image"):
        pick_point(depth, intrinsics, 170.0, 10.0)
    with pytest.raises(FindingError, match="has no depth"):
        pick_point(np.zeros((120, 160), np.float32), intrinsics, 10.0, 10.0)


def test_an_anchored_point_moves_with_its_keyframe() -> None:
    rng = np.random.default_rng(4)
    keyframes = [pose_from_xyz_rpy(x, 0.0, 0.3, -np.pi / 2, 0.0, -np.pi / 2) for x in (0.0, 1.0, 2.0, 3.0)]
    camera = keyframes[2] @ pose_from_xyz_rpy(0.1, 0.0, 0.05, 0.0, 0.1, 0.0)
    seen = np.array([0.2, -0.1, 2.5])
    index, in_keyframe = anchor_to_keyframe(seen, camera, keyframes)
    assert index == 2
    world = transform_points(camera, seen[None])[0]
    assert np.allclose(anchored_position(in_keyframe, keyframes[2]), world)
    # The graph is re-optimised (or merged into another frame): the whole map moves rigidly.
    correction = random_pose(rng)
    assert np.allclose(
        anchored_position(in_keyframe, correction @ keyframes[2]), transform_points(correction, [world])[0]
    )
    with pytest.raises(FindingError, match="no keyframe yet"):
        anchor_to_keyframe(seen, camera, [])


def test_crops_stay_inside_the_image() -> None:
    image = np.arange(120 * 160).reshape(120, 160)
    assert crop_around(image, 80, 60, size=20)[0, 0] == image[50, 70]
    assert crop_around(image, 2, 118, size=20).shape == (20, 20)
    assert crop_around(image, 2, 118, size=20)[0, 0] == image[100, 0]
