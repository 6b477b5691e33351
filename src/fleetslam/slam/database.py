"""SQLite map database (``map.db``): locations, links, visual words and keypoint-word associations.

Tables (arrays are stored as raw little-endian bytes with their dtype/shape in columns, so a round trip
is bit-exact):

- ``info(key, value)``: format version and descriptor kind;
- ``nodes``: id, map_id (session), stamp, pose (16 float64), weight, label, memory (stm/wm/ltm),
  keypoints, points3d, descriptors, compressed RGB and depth images (optional);
- ``keypoint_words(node_id, word_ids)``: the word of each keypoint of a node, in keypoint order;
- ``links``: from_id, to_id, type (0 odometry, 1 loop, 2 inter-session), transform (16 float64),
  information (36 float64); both directions are stored;
- ``words(id, descriptor)``: the vocabulary.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Iterable, Mapping
from pathlib import Path
from types import TracebackType
from typing import Literal, cast

import numpy as np
from numpy.typing import NDArray

from fleetslam.errors import SlamError
from fleetslam.slam.signature import Link, LinkType, Signature
from fleetslam.slam.vocabulary import DescriptorKind, VisualVocabulary

FORMAT_VERSION = "1"

_SCHEMA = """
CREATE TABLE IF NOT EXISTS info (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS nodes (
    id INTEGER PRIMARY KEY, map_id INTEGER NOT NULL, stamp REAL NOT NULL, pose BLOB NOT NULL,
    weight INTEGER NOT NULL, label TEXT NOT NULL, memory TEXT NOT NULL,
    n_keypoints INTEGER NOT NULL, keypoints BLOB NOT NULL, points3d BLOB NOT NULL,
    descriptor_dtype TEXT NOT NULL, descriptor_size INTEGER NOT NULL, descriptors BLOB NOT NULL,
    rgb BLOB, depth BLOB
);
CREATE TABLE IF NOT EXISTS keypoint_words (node_id INTEGER PRIMARY KEY, word_ids BLOB NOT NULL);
CREATE TABLE IF NOT EXISTS links (
    from_id INTEGER NOT NULL, to_id INTEGER NOT NULL, type INTEGER NOT NULL,
    transform BLOB NOT NULL, information BLOB NOT NULL, PRIMARY KEY (from_id, to_id)
);
CREATE TABLE IF NOT EXISTS words (id INTEGER PRIMARY KEY, descriptor BLOB NOT NULL);
"""

MemoryState = Literal["stm", "wm", "ltm"]


def _blob(array: NDArray[np.generic], dtype: str) -> bytes:
    return np.ascontiguousarray(array, dtype=np.dtype(dtype).newbyteorder("<")).tobytes()


def _array(blob: bytes, dtype: str, shape: tuple[int, ...]) -> NDArray[np.generic]:
    return np.frombuffer(blob, dtype=np.dtype(dtype).newbyteorder("<")).astype(dtype).reshape(shape)


class MapDatabase:
    """Read/write access to a ``map.db`` file; a context manager that commits and closes on exit."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        try:
            self._connection = sqlite3.connect(str(self.path))
            self._connection.executescript(_SCHEMA)
            row = self._connection.execute("SELECT value FROM info WHERE key='version'").fetchone()
        except sqlite3.DatabaseError as err:
            raise SlamError(f"{self.path}: cannot open map database: {err}") from err
        if row is None:
            self._connection.execute("INSERT INTO info VALUES ('version', ?)", (FORMAT_VERSION,))
        elif row[0] != FORMAT_VERSION:
            raise SlamError(f"{self.path}: map database version {row[0]!r}, expected {FORMAT_VERSION!r}")

    def __enter__(self) -> MapDatabase:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def commit(self) -> None:
        """Make the writes durable."""
        self._connection.commit()

    def close(self) -> None:
        """Commit and close."""
        self._connection.commit()
        self._connection.close()

    # ------------------------------------------------------------------ signatures
    def save_signatures(self, signatures: Iterable[Signature], states: Mapping[int, MemoryState]) -> None:
        """Insert or replace locations (without their links) with their memory state."""
        node_rows = []
        word_rows = []
        for s in signatures:
            desc = np.asarray(s.descriptors)
            dtype = "uint8" if desc.dtype == np.uint8 else "float32"
            size = desc.shape[1] if desc.ndim == 2 else 0
            node_rows.append(
                (
                    s.id,
                    s.map_id,
                    s.stamp,
                    _blob(s.pose, "float64"),
                    s.weight,
                    s.label,
                    states.get(s.id, "wm"),
                    len(s.keypoints),
                    _blob(s.keypoints, "float32"),
                    _blob(s.points3d, "float32"),
                    dtype,
                    size,
                    _blob(desc, dtype),
                    s.rgb_compressed,
                    s.depth_compressed,
                )
            )
            word_rows.append((s.id, _blob(s.word_ids, "int64")))
        self._connection.executemany("INSERT OR REPLACE INTO nodes VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)", node_rows)
        self._connection.executemany("INSERT OR REPLACE INTO keypoint_words VALUES (?,?)", word_rows)

    def load_signatures(self) -> tuple[dict[int, Signature], dict[int, MemoryState]]:
        """Every stored location (links not attached) and its memory state."""
        words = dict(self._connection.execute("SELECT node_id, word_ids FROM keypoint_words"))
        signatures: dict[int, Signature] = {}
        states: dict[int, MemoryState] = {}
        for row in self._connection.execute("SELECT * FROM nodes ORDER BY id"):
            (node_id, map_id, stamp, pose, weight, label, memory, n, kps, pts, dtype, size, desc, rgb, depth) = row
            word_blob = words.get(node_id)
            if word_blob is None:
                raise SlamError(f"{self.path}: node {node_id} has no keypoint_words row")
            signatures[node_id] = Signature(
                id=node_id,
                stamp=stamp,
                pose=cast(NDArray[np.float64], _array(pose, "float64", (4, 4))),
                keypoints=cast(NDArray[np.float32], _array(kps, "float32", (n, 2))),
                points3d=cast(NDArray[np.float32], _array(pts, "float32", (n, 3))),
                descriptors=cast(NDArray[np.uint8], _array(desc, dtype, (n, size))),
                word_ids=cast(NDArray[np.int64], _array(word_blob, "int64", (n,))),
                weight=weight,
                map_id=map_id,
                rgb_compressed=rgb,
                depth_compressed=depth,
                label=label,
            )
            if memory not in ("stm", "wm", "ltm"):
                raise SlamError(f"{self.path}: node {node_id} has memory state {memory!r}")
            states[node_id] = memory
        return signatures, states

    # ------------------------------------------------------------------ links
    def save_links(self, links: Iterable[Link]) -> None:
        """Insert or replace links (give both directions to store both)."""
        rows = [
            (
                link.from_id,
                link.to_id,
                int(link.type),
                _blob(link.transform, "float64"),
                _blob(link.information, "float64"),
            )
            for link in links
        ]
        self._connection.executemany("INSERT OR REPLACE INTO links VALUES (?,?,?,?,?)", rows)

    def load_links(self) -> list[Link]:
        """Every stored link, ordered by (from_id, to_id)."""
        return [
            Link(
                from_id,
                to_id,
                LinkType(kind),
                cast(NDArray[np.float64], _array(transform, "float64", (4, 4))),
                cast(NDArray[np.float64], _array(information, "float64", (6, 6))),
            )
            for from_id, to_id, kind, transform, information in self._connection.execute(
                "SELECT * FROM links ORDER BY from_id, to_id"
            )
        ]

    # ------------------------------------------------------------------ vocabulary
    def save_vocabulary(self, vocabulary: VisualVocabulary) -> None:
        """Replace the stored words by the vocabulary's (all words, active or not)."""
        self._connection.execute("DELETE FROM words")
        self._connection.execute("INSERT OR REPLACE INTO info VALUES ('descriptor_kind', ?)", (vocabulary.kind,))
        self._connection.execute(
            "INSERT OR REPLACE INTO info VALUES ('descriptor_size', ?)", (str(vocabulary.descriptor_size),)
        )
        dtype = "uint8" if vocabulary.kind == "binary" else "float32"
        descriptors = vocabulary.descriptors()
        self._connection.executemany(
            "INSERT INTO words VALUES (?,?)",
            ((i, _blob(descriptors[i], dtype)) for i in range(len(vocabulary))),
        )

    def load_vocabulary(self, nndr_ratio: float = 0.8, max_distance: float = 0.0) -> VisualVocabulary:
        """The stored words as a vocabulary whose words are all inactive until locations reference them."""
        info = dict(self._connection.execute("SELECT key, value FROM info"))
        kind = cast(DescriptorKind, info.get("descriptor_kind", "binary"))
        if kind not in ("binary", "float"):
            raise SlamError(f"{self.path}: info.descriptor_kind = {kind!r} is not 'binary' or 'float'")
        size = int(info.get("descriptor_size", "0"))
        dtype = "uint8" if kind == "binary" else "float32"
        rows = self._connection.execute("SELECT id, descriptor FROM words ORDER BY id").fetchall()
        for expected, (word_id, _) in enumerate(rows):
            if word_id != expected:
                raise SlamError(f"{self.path}: words table is not contiguous (id {word_id} at row {expected})")
        descriptors = (
            np.stack([_array(blob, dtype, (size,)) for _, blob in rows]) if rows else np.zeros((0, size), dtype=dtype)
        )
        return VisualVocabulary.from_words(descriptors, kind, nndr_ratio, max_distance)
