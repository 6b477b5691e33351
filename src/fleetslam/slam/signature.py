"""A location of the map (RTAB-Map "signature") and the links between locations.

Conventions the pipeline follows when it builds a location:
- ``pose`` is the 4×4 world pose ``T_world_base`` of the robot at the keyframe (odometry or optimised);
- ``keypoints`` are pixel coordinates ``(N, 2)`` in the rectified RGB image;
- ``points3d`` are the keypoints back-projected with depth, ``(N, 3)`` in the *camera optical frame*, NaN
  where depth is missing;
- ``descriptors`` are ``(N, 32)`` uint8 for ORB (binary) or ``(N, D)`` float32 for SIFT-like descriptors;
- ``word_ids`` are filled by :class:`fleetslam.slam.memory.Memory` when the location is added.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np
from numpy.typing import NDArray

from fleetslam.geometry import invert


class LinkType(IntEnum):
    """Kind of an edge of the pose graph (values are stored in map.db)."""

    ODOMETRY = 0
    """Between consecutive locations (RTAB-Map "neighbor" link)."""
    LOOP = 1
    """Loop closure found by appearance and verified geometrically (RTAB-Map "global closure")."""
    INTER_SESSION = 2
    """Loop closure between two sessions (map ids) of the same database."""


@dataclass
class Link:
    """Edge ``from_id -> to_id`` with ``transform = T_from_to`` (pose of ``to`` in the frame of ``from``)."""

    from_id: int
    to_id: int
    type: LinkType
    transform: NDArray[np.float64]
    information: NDArray[np.float64] = field(default_factory=lambda: np.eye(6))
    """6×6 information matrix (inverse covariance) over (x, y, z, roll, pitch, yaw)."""

    def inverse(self) -> Link:
        """The same edge seen from ``to_id``."""
        return Link(self.to_id, self.from_id, self.type, invert(self.transform), self.information.copy())


@dataclass
class Signature:
    """One location: what was seen (keypoints, 3D points, descriptors, visual words) and where (pose)."""

    id: int
    stamp: float
    pose: NDArray[np.float64]
    keypoints: NDArray[np.float32]
    points3d: NDArray[np.float32]
    descriptors: NDArray[np.uint8] | NDArray[np.float32]
    word_ids: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    weight: int = 0
    """Number of times this place was seen again while in STM (rehearsal) or by loop closures."""
    map_id: int = 0
    """Session the location was created in (multi-session maps)."""
    links: dict[int, Link] = field(default_factory=dict)
    """Links from this location keyed by the other end's id; ``links[j].from_id == self.id``."""
    rgb_compressed: bytes | None = None
    """Encoded RGB image (JPEG/PNG bytes) or None."""
    depth_compressed: bytes | None = None
    """Encoded depth image (16-bit PNG bytes) or None."""
    label: str = ""

    @property
    def word_count(self) -> int:
        """Keypoints quantised to a word (the others carry -1: beyond the location's word budget)."""
        return int(np.count_nonzero(self.word_ids >= 0))

    def word_counts(self) -> Counter[int]:
        """Occurrences of each visual word in this location (word id -> count)."""
        return Counter(int(w) for w in self.word_ids if w >= 0)

    def add_link(self, link: Link) -> None:
        """Attach a link that starts at this location."""
        if link.from_id != self.id:
            raise ValueError(f"link {link.from_id}->{link.to_id} does not start at location {self.id}")
        self.links[link.to_id] = link


def word_set_similarity(a: Signature, b: Signature) -> float:
    """Rehearsal similarity: words common to both (counted with multiplicity) over the larger word count.

    This is RTAB-Map's ``Signature::compareTo``: 1 for identical word multisets, 0 when nothing is shared.
    """
    ca, cb = a.word_counts(), b.word_counts()
    total = max(sum(ca.values()), sum(cb.values()))
    if total == 0:
        return 0.0
    common = sum(min(n, cb[w]) for w, n in ca.items() if w in cb)
    return common / total
