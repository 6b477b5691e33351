"""Inspection findings (pure): what an operator saw, where, and how it is kept.

A finding is anchored to the keyframe it was seen from: the point is stored in that keyframe's camera (optical)
frame, and its position in the agent's map is recomputed from the keyframe's *current* pose
(:func:`anchored_position`), so it follows the keyframe when the graph is re-optimised, and the agent's placement
in the fleet frame when its map is merged.

:class:`FindingStore` creates, updates and closes findings (every field validated, errors naming the field and
value) and keeps them as ``findings.json`` plus ``<id>.jpg`` (the photo) and ``<id>_crop.jpg`` (a crop around the
picked pixel) in a directory (the run's ``findings/``); :meth:`FindingStore.load` reads them back.

Picking (:func:`pick_point`, :func:`anchor_to_keyframe`, :func:`crop_around`) turns a pixel of a camera frame,
its depth image, the camera's intrinsics and pose into the anchored point.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fleetslam.errors import FindingError
from fleetslam.geometry import invert, transform_points
from fleetslam.intrinsics import Intrinsics

__all__ = [
    "FINDINGS_FILE",
    "SEVERITIES",
    "STATUSES",
    "Finding",
    "FindingStore",
    "anchor_to_keyframe",
    "anchored_position",
    "crop_around",
    "pick_point",
]

SEVERITIES = ("info", "low", "medium", "high", "critical")
"""A finding's severity, mildest first."""
STATUSES = ("open", "closed")
FINDINGS_FILE = "findings.json"
MAX_TITLE = 200
MAX_NOTE = 5000
JPEG_MAGIC = b"\xff\xd8"


@dataclass(frozen=True)
class Finding:
    """One finding. ``point`` is in the camera frame of keyframe ``keyframe_id`` of ``agent`` (the index of the
    keyframe in the agent's keyframe path); ``pixel`` is where it was picked in ``photo``."""

    id: str
    title: str
    severity: str
    status: str
    note: str
    agent: str
    keyframe_id: int
    point: tuple[float, float, float]
    pixel: tuple[float, float]
    stamp_ns: int
    """When the photo was taken (the camera frame's stamp)."""
    photo: bytes = field(default=b"", repr=False)
    """JPEG of the camera frame (empty: none)."""
    crop: bytes = field(default=b"", repr=False)
    """JPEG of the region around ``pixel`` (empty: none)."""
    position: tuple[float, float, float] | None = None
    """Last known position in the agent's map frame (from the keyframe's pose then); for readers without poses."""
    fleet_position: tuple[float, float, float] | None = None
    """Last known position in the fleet frame (None: the agent was not placed in it)."""

    def validated(self) -> Finding:
        """This finding, or FindingError naming the field and value at fault."""
        where = f"finding {self.id or '(new)'}"

        def fail(name: str, value: object, why: str) -> FindingError:
            return FindingError(f"{where}: {name} {value!r} {why}")

        if not self.title.strip():
            raise fail("title", self.title, "is empty: give the finding a title")
        if len(self.title) > MAX_TITLE:
            raise fail("title", self.title[:20] + "...", f"is longer than {MAX_TITLE} characters")
        if len(self.note) > MAX_NOTE:
            raise fail("note", self.note[:20] + "...", f"is longer than {MAX_NOTE} characters")
        if self.severity not in SEVERITIES:
            raise fail("severity", self.severity, f"is not one of {', '.join(SEVERITIES)}")
        if self.status not in STATUSES:
            raise fail("status", self.status, f"is not one of {', '.join(STATUSES)}")
        if not self.agent.strip() or "/" in self.agent.strip("/"):
            raise fail("agent", self.agent, "is not an agent's name")
        if self.keyframe_id < 0:
            raise fail("keyframe_id", self.keyframe_id, "is negative")
        if len(self.point) != 3 or not all(math.isfinite(c) for c in self.point):
            raise fail("point", self.point, "is not a finite 3D point")
        if len(self.pixel) != 2 or not all(math.isfinite(c) for c in self.pixel):
            raise fail("pixel", self.pixel, "is not a finite (u, v)")
        for name, data in (("photo", self.photo), ("crop", self.crop)):
            if data and not data.startswith(JPEG_MAGIC):
                raise fail(name, data[:4], "is not a JPEG image")
        return self

    def to_json(self) -> dict[str, Any]:
        """The JSON form (``findings.json``): images by file name, not inline."""
        out = asdict(self)
        out["photo"] = f"{self.id}.jpg" if self.photo else ""
        out["crop"] = f"{self.id}_crop.jpg" if self.crop else ""
        out["point"], out["pixel"] = list(self.point), list(self.pixel)
        for name in ("position", "fleet_position"):
            out[name] = None if out[name] is None else list(out[name])
        return out


def _finding_from_json(data: Mapping[str, Any], directory: Path, where: str) -> Finding:
    try:
        images = {}
        for name in ("photo", "crop"):
            file = str(data.get(name) or "")
            if file and (Path(file).name != file or not (directory / file).is_file()):
                raise FindingError(f"{where}: {name} {file!r} is not a file in {directory}")
            images[name] = (directory / file).read_bytes() if file else b""

        def triple(value: Any) -> tuple[float, float, float] | None:
            return None if value is None else (float(value[0]), float(value[1]), float(value[2]))

        point = triple(data["point"])
        assert point is not None
        return Finding(
            id=str(data["id"]), title=str(data["title"]), severity=str(data["severity"]), status=str(data["status"]),
            note=str(data.get("note", "")), agent=str(data["agent"]), keyframe_id=int(data["keyframe_id"]),
            point=point, pixel=(float(data["pixel"][0]), float(data["pixel"][1])), stamp_ns=int(data["stamp_ns"]),
            photo=images["photo"], crop=images["crop"], position=triple(data.get("position")),
            fleet_position=triple(data.get("fleet_position")),
        ).validated()  # fmt: skip
    except (KeyError, TypeError, ValueError, IndexError, AssertionError) as err:
        raise FindingError(f"{where}: malformed finding ({type(err).__name__}: {err})") from err


class FindingStore:
    """The findings of a run: create, update, close; ``save`` writes them to ``directory`` (when given)."""

    def __init__(self, directory: Path | None = None, findings: Sequence[Finding] = ()) -> None:
        self.directory = directory
        self._findings: dict[str, Finding] = {f.id: f for f in findings}

    @property
    def findings(self) -> list[Finding]:
        """Every finding, in the order they were created."""
        return list(self._findings.values())

    def get(self, finding_id: str) -> Finding:
        try:
            return self._findings[finding_id]
        except KeyError:
            raise FindingError(f"no finding {finding_id!r} (known: {', '.join(self._findings) or 'none'})") from None

    def _next_id(self) -> str:
        numbers = [int(i[1:]) for i in self._findings if i[:1] == "F" and i[1:].isdigit()]
        return f"F{max(numbers, default=0) + 1:03d}"

    def create(self, draft: Finding) -> Finding:
        """Add ``draft`` under a new id (its own is ignored), open unless it says closed; returns it."""
        checked = replace(draft, id="", status=draft.status or "open").validated()
        finding = replace(checked, id=self._next_id())
        self._findings[finding.id] = finding
        self._save_one(finding)
        return finding

    def update(
        self,
        finding_id: str,
        *,
        title: str | None = None,
        severity: str | None = None,
        status: str | None = None,
        note: str | None = None,
    ) -> Finding:
        """Change the given fields (None: unchanged); returns the finding as it is now."""
        old = self.get(finding_id)
        finding = replace(
            old, title=old.title if title is None else title, severity=old.severity if severity is None else severity,
            status=old.status if status is None else status, note=old.note if note is None else note,
        ).validated()  # fmt: skip
        self._findings[finding_id] = finding
        self._save_one(finding)
        return finding

    def close(self, finding_id: str, note: str | None = None) -> Finding:
        """Mark a finding closed (optionally with a new note)."""
        return self.update(finding_id, status="closed", note=note)

    def set_positions(self, positions: Mapping[str, tuple[NDArray[np.float64], NDArray[np.float64] | None]]) -> bool:
        """Record each finding's current position (map frame, fleet frame or None); whether any changed."""
        changed = False
        for finding_id, (in_map, in_fleet) in positions.items():
            old = self._findings.get(finding_id)
            if old is None:
                continue
            new = replace(
                old, position=_rounded(in_map), fleet_position=None if in_fleet is None else _rounded(in_fleet)
            )
            if new != old:
                self._findings[finding_id] = new
                changed = True
        return changed

    # -- files ---------------------------------------------------------------------------------------------------
    def _save_one(self, finding: Finding) -> None:
        if self.directory is None:
            return
        self.directory.mkdir(parents=True, exist_ok=True)
        for data, name in ((finding.photo, f"{finding.id}.jpg"), (finding.crop, f"{finding.id}_crop.jpg")):
            if data and not (self.directory / name).is_file():
                _write_atomic(self.directory / name, data)
        self.save()

    def save(self) -> Path | None:
        """Write ``findings.json`` (and any image not yet written); returns its path (None without a directory)."""
        if self.directory is None:
            return None
        self.directory.mkdir(parents=True, exist_ok=True)
        for finding in self._findings.values():
            for data, name in ((finding.photo, f"{finding.id}.jpg"), (finding.crop, f"{finding.id}_crop.jpg")):
                if data and not (self.directory / name).is_file():
                    _write_atomic(self.directory / name, data)
        document = {"version": 1, "findings": [f.to_json() for f in self._findings.values()]}
        path = self.directory / FINDINGS_FILE
        _write_atomic(path, (json.dumps(document, indent=2) + "\n").encode())
        return path

    @classmethod
    def load(cls, directory: Path) -> FindingStore:
        """The findings saved in ``directory`` (none when it holds no ``findings.json``); FindingError names the
        file and the finding at fault."""
        path = directory / FINDINGS_FILE
        if not path.is_file():
            return cls(directory)
        try:
            document = json.loads(path.read_text(encoding="utf-8"))
            entries = document["findings"]
            if not isinstance(entries, list):
                raise TypeError(f"'findings' is a {type(entries).__name__}, not a list")
        except (ValueError, KeyError, TypeError) as err:
            raise FindingError(f"{path}: not a findings file ({err})") from err
        findings = [_finding_from_json(e, directory, f"{path} finding {i}") for i, e in enumerate(entries)]
        return cls(directory, findings)


def _rounded(point: ArrayLike) -> tuple[float, float, float]:
    x, y, z = (round(float(c), 4) for c in np.asarray(point, dtype=np.float64).reshape(3))
    return (x, y, z)


def _write_atomic(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


# -- picking and anchoring -----------------------------------------------------------------------------------------
def pick_point(
    depth: NDArray[np.floating], intrinsics: Intrinsics, u: float, v: float, *, window: int = 2
) -> NDArray[np.float64]:
    """The 3D point (camera optical frame, m) seen at pixel ``(u, v)`` (pixel centres at integers) of a depth image
    registered to the camera of ``intrinsics``: the pixel's depth, or where it has none the median of the valid
    depths within ``window`` pixels. FindingError when the pixel is outside the image or no depth is near it."""
    h, w = depth.shape
    if intrinsics.width != w or intrinsics.height != h:
        intrinsics = intrinsics.scaled(w, h)
    col, row = round(u), round(v)
    if not (0 <= col < w and 0 <= row < h):
        raise FindingError(f"pixel ({u:.1f}, {v:.1f}) is outside the {w}x{h} image")
    z = float(depth[row, col])
    if not (math.isfinite(z) and z > 0):
        patch = depth[max(0, row - window) : row + window + 1, max(0, col - window) : col + window + 1]
        valid = patch[np.isfinite(patch) & (patch > 0)]
        if not valid.size:
            raise FindingError(f"pixel ({u:.1f}, {v:.1f}) has no depth (nothing in range there): pick another")
        z = float(np.median(valid))
    return np.array([(u - intrinsics.cx) / intrinsics.fx * z, (v - intrinsics.cy) / intrinsics.fy * z, z])


def anchor_to_keyframe(
    point_camera: ArrayLike, T_map_camera: ArrayLike, keyframe_poses: Sequence[ArrayLike]
) -> tuple[int, NDArray[np.float64]]:
    """The keyframe to anchor a point seen from ``T_map_camera`` to (the nearest, the latest of equals) and the
    point in that keyframe's camera frame. FindingError when the agent has no keyframe yet."""
    if not len(keyframe_poses):
        raise FindingError("the agent has no keyframe yet: a finding needs one to be anchored to")
    T_map_camera = np.asarray(T_map_camera, dtype=np.float64)
    centres = np.array([np.asarray(p, dtype=np.float64)[:3, 3] for p in keyframe_poses])
    distances = np.linalg.norm(centres - T_map_camera[:3, 3], axis=1)
    index = int(len(distances) - 1 - np.argmin(distances[::-1]))
    in_map = transform_points(T_map_camera, np.asarray(point_camera, dtype=np.float64).reshape(1, 3))
    return index, transform_points(invert(keyframe_poses[index]), in_map)[0]


def anchored_position(point_keyframe: ArrayLike, T_map_keyframe: ArrayLike) -> NDArray[np.float64]:
    """Where a point anchored to a keyframe is now, in the frame of the keyframe's pose."""
    return transform_points(T_map_keyframe, np.asarray(point_keyframe, dtype=np.float64).reshape(1, 3))[0]


def crop_around(image: NDArray[Any], u: float, v: float, *, size: int = 96) -> NDArray[Any]:
    """The ``size``×``size`` region of ``image`` centred on ``(u, v)`` (moved inside the image at its borders)."""
    h, w = image.shape[:2]
    size = min(size, h, w)
    left = min(max(0, round(u) - size // 2), w - size)
    top = min(max(0, round(v) - size // 2), h - size)
    return image[top : top + size, left : left + size]
