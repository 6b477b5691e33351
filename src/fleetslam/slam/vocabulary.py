"""Incremental visual-word dictionary (RTAB-Map ``VWDictionary`` in incremental mode) with an inverted index.

A new descriptor joins its nearest *active* word when it passes the nearest-neighbour distance ratio test
(``d1 < nndr_ratio * d2``, RTAB-Map Kp/NndrRatio) and, optionally, an absolute distance bound; otherwise it
becomes a new word whose descriptor is the descriptor itself. Word ids are consecutive integers from 0.

The inverted index maps each word to the locations referencing it (location id -> occurrences). Only
locations in RAM (STM + WM) reference words: when a location goes to long-term memory its references are
removed, and a word without references leaves the active nearest-neighbour index, as in RTAB-Map; it comes
back when a location referencing it is retrieved.

Nearest neighbours are exact: binary descriptors are compared by Hamming distance on packed ``uint64`` lanes (a
numba kernel when numba is installed; else OpenCV's ``batchDistance``; else ``numpy.bitwise_count`` in batches);
float descriptors by L2 distance through one matrix product per batch. Every path gives the same words.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from fleetslam._imports import require
from fleetslam.errors import SlamError

DescriptorKind = Literal["binary", "float"]
BinarySearch = Literal["auto", "numba", "opencv", "numpy"]

_BATCH_ELEMENTS = 4_000_000
"""Query x word pairs evaluated per batch; bounds the temporary distance matrix to a few tens of MB."""


def pack_binary(descriptors: NDArray[np.uint8]) -> NDArray[np.uint64]:
    """Pack ``(N, B)`` uint8 binary descriptors into ``(N, ceil(B/8))`` uint64 lanes (zero padded)."""
    desc = np.ascontiguousarray(descriptors, dtype=np.uint8)
    n, nbytes = desc.shape
    lanes = (nbytes + 7) // 8
    if lanes * 8 != nbytes:
        padded = np.zeros((n, lanes * 8), dtype=np.uint8)
        padded[:, :nbytes] = desc
        desc = padded
    return desc.view(np.uint64).reshape(n, lanes)


def pack_binary_by_lane(descriptors: NDArray[np.uint8]) -> NDArray[np.uint64]:
    """:func:`pack_binary`'s lanes lane by lane, ``(lanes, N)``: each lane of all the descriptors contiguous, the
    layout the numba search reads (it vectorises over the words)."""
    return np.ascontiguousarray(pack_binary(descriptors).T)


def hamming_distances(queries: NDArray[np.uint64], words: NDArray[np.uint64]) -> NDArray[np.int32]:
    """All pairwise Hamming distances ``(Q, W)`` between packed descriptors."""
    dist = np.zeros((queries.shape[0], words.shape[0]), dtype=np.int32)
    for lane in range(queries.shape[1]):
        dist += np.bitwise_count(queries[:, lane, None] ^ words[None, :, lane])
    return dist


def l2_distances(queries: NDArray[np.float32], words: NDArray[np.float32]) -> NDArray[np.float32]:
    """All pairwise Euclidean distances ``(Q, W)``."""
    q2 = np.einsum("ij,ij->i", queries, queries)[:, None]
    w2 = np.einsum("ij,ij->i", words, words)[None, :]
    sq = q2 + w2 - 2.0 * (queries @ words.T)
    return np.sqrt(np.maximum(sq, 0.0)).astype(np.float32)


def _available(module: str) -> bool:
    try:
        __import__(module)
    except ImportError:
        return False
    return True


def _binary_search(requested: BinarySearch) -> Literal["numba", "opencv", "numpy"]:
    """The binary nearest-neighbour search to use: the requested one, or for "auto" the fastest installed (a
    requested one that is not installed falls back the same way)."""
    for candidate, module in (("numba", "numba"), ("opencv", "cv2")):
        if requested in ("auto", candidate) and _available(module):
            return candidate  # type: ignore[return-value]
    return "numpy"


class VisualVocabulary:
    """Incremental dictionary of visual words with an exact 2-NN index over active words."""

    def __init__(
        self,
        kind: DescriptorKind = "binary",
        nndr_ratio: float = 0.8,
        max_distance: float = 0.0,
        search: BinarySearch = "auto",
    ) -> None:
        """``max_distance`` bounds the nearest-word distance for a match (0 = NNDR test only); ``search`` picks the
        binary nearest-neighbour search ("auto": numba, else OpenCV, else NumPy; all give the same words)."""
        if kind not in ("binary", "float"):
            raise SlamError(f"vocabulary: descriptor kind {kind!r} is not 'binary' or 'float'")
        self.kind: DescriptorKind = kind
        self.nndr_ratio = float(nndr_ratio)
        self.max_distance = float(max_distance)
        self.search = _binary_search(search)
        """The binary search in use: "numba" (several times faster than OpenCV's top-2 ``batchDistance``),
        "opencv" or "numpy"."""
        self._descriptors: NDArray[Any] | None = None
        self._size = 0
        self._active = np.zeros(0, dtype=bool)
        self._references: dict[int, dict[int, int]] = {}
        self._index_ids: NDArray[np.int64] = np.zeros(0, dtype=np.int64)
        self._index_data: NDArray[Any] | None = None
        self._index_packed: NDArray[np.uint64] | None = None
        """The index's binary words for the numba search (:func:`pack_binary_by_lane`)."""
        self._index_dirty = True

    # ------------------------------------------------------------------ size and content
    def __len__(self) -> int:
        """Number of words ever created (active or not)."""
        return self._size

    @property
    def num_active(self) -> int:
        """Number of words in the nearest-neighbour index."""
        return int(self._active[: self._size].sum())

    @property
    def descriptor_size(self) -> int:
        """Bytes (binary) or floats (float) per descriptor; 0 before the first word."""
        return 0 if self._descriptors is None else int(self._descriptors.shape[1])

    def descriptors(self, word_ids: NDArray[np.int64] | None = None) -> NDArray[Any]:
        """Descriptors of the given words (all words if None)."""
        if self._descriptors is None:
            dtype = np.uint8 if self.kind == "binary" else np.float32
            return np.zeros((0, 0), dtype=dtype)
        if word_ids is None:
            return self._descriptors[: self._size].copy()
        return self._descriptors[np.asarray(word_ids, dtype=np.int64)]

    def is_active(self, word_id: int) -> bool:
        """Whether the word is in the nearest-neighbour index."""
        return bool(self._active[word_id])

    def active_mask(self) -> NDArray[np.bool_]:
        """Boolean mask of active words, indexed by word id."""
        return self._active[: self._size].copy()

    # ------------------------------------------------------------------ construction
    def _check(self, descriptors: NDArray[np.generic]) -> NDArray[Any]:
        desc = np.asarray(descriptors)
        if desc.ndim != 2:
            raise SlamError(f"vocabulary: descriptors must be (N, D), got shape {desc.shape}")
        if self.kind == "binary":
            if desc.dtype != np.uint8:
                raise SlamError(f"vocabulary: binary descriptors must be uint8, got {desc.dtype}")
            out: NDArray[Any] = np.ascontiguousarray(desc)
        else:
            out = np.ascontiguousarray(desc, dtype=np.float32)
        if self._descriptors is not None and desc.shape[0] and desc.shape[1] != self._descriptors.shape[1]:
            raise SlamError(
                f"vocabulary: descriptor size {desc.shape[1]} differs from the dictionary's "
                f"{self._descriptors.shape[1]}"
            )
        return out

    def add_words(self, descriptors: NDArray[np.generic]) -> NDArray[np.int64]:
        """Append descriptors as new active words; returns their ids."""
        desc = self._check(descriptors)
        n = desc.shape[0]
        if n == 0:
            return np.zeros(0, dtype=np.int64)
        if self._descriptors is None:
            self._descriptors = np.zeros((max(1024, n), desc.shape[1]), dtype=desc.dtype)
            self._active = np.zeros(self._descriptors.shape[0], dtype=bool)
        if self._size + n > self._descriptors.shape[0]:
            capacity = max(2 * self._descriptors.shape[0], self._size + n)
            grown = np.zeros((capacity, desc.shape[1]), dtype=self._descriptors.dtype)
            grown[: self._size] = self._descriptors[: self._size]
            self._descriptors = grown
            active = np.zeros(capacity, dtype=bool)
            active[: self._size] = self._active[: self._size]
            self._active = active
        ids = np.arange(self._size, self._size + n, dtype=np.int64)
        self._descriptors[self._size : self._size + n] = desc
        self._active[self._size : self._size + n] = True
        self._size += n
        if not self._index_dirty and self._index_data is not None:
            # Appending keeps the cached index valid without a rebuild.
            self._index_data = np.concatenate([self._index_data, desc])
            self._index_ids = np.concatenate([self._index_ids, ids])
            if self._index_packed is not None:
                self._index_packed = np.concatenate([self._index_packed, pack_binary_by_lane(desc)], axis=1)
        else:
            self._index_dirty = True
        return ids

    def quantize(self, descriptors: NDArray[np.generic], add: bool = True) -> NDArray[np.int64]:
        """Word id of each descriptor; descriptors failing the NNDR test become new words (``add``) or -1."""
        desc = self._check(descriptors)
        n = desc.shape[0]
        word_ids = np.full(n, -1, dtype=np.int64)
        if n == 0:
            return word_ids
        if self.num_active > 0:
            nearest, d1, d2 = self.nearest2(desc)
            matched = d1 < self.nndr_ratio * d2
            if self.max_distance > 0:
                matched &= d1 <= self.max_distance
            word_ids[matched] = nearest[matched]
        if add:
            new = word_ids < 0
            if new.any():
                word_ids[new] = self.add_words(desc[new])
        return word_ids

    # ------------------------------------------------------------------ nearest neighbours
    def _index(self) -> tuple[NDArray[np.int64], NDArray[Any]]:
        if self._index_dirty or self._index_data is None:
            ids = np.flatnonzero(self._active[: self._size]).astype(np.int64)
            assert self._descriptors is not None
            words = self._descriptors[ids]
            self._index_data = np.ascontiguousarray(words)
            self._index_ids = ids
            numba_index = self.kind == "binary" and self.search == "numba"
            self._index_packed = pack_binary_by_lane(words) if numba_index else None
            self._index_dirty = False
        return self._index_ids, self._index_data

    def nearest2(
        self, descriptors: NDArray[np.generic]
    ) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
        """Nearest active word of each descriptor with the distances to the first and second nearest.

        ``d2`` is +inf when only one word is active. Ties resolve to the lowest word id.
        """
        desc = self._check(descriptors)
        ids, data = self._index()
        n = desc.shape[0]
        nearest = np.full(n, -1, dtype=np.int64)
        d1 = np.full(n, np.inf)
        d2 = np.full(n, np.inf)
        if ids.size == 0 or n == 0:
            return nearest, d1, d2
        if self.kind == "binary" and self.search == "numba":
            return self._nearest2_numba(desc, ids)
        if self.kind == "binary" and self.search == "opencv" and ids.size >= 2:
            return self._nearest2_opencv(desc, ids, data)
        queries: NDArray[Any] = pack_binary(desc) if self.kind == "binary" else desc
        if self.kind == "binary":
            data = pack_binary(data)
        batch = max(1, _BATCH_ELEMENTS // ids.size)
        for start in range(0, n, batch):
            stop = min(n, start + batch)
            if self.kind == "binary":
                dist: NDArray[np.generic] = hamming_distances(queries[start:stop], data)
            else:
                dist = l2_distances(queries[start:stop], data)
            rows = np.arange(stop - start)
            first = np.argmin(dist, axis=1)
            nearest[start:stop] = ids[first]
            d1[start:stop] = dist[rows, first]
            if ids.size > 1:
                masked = dist.astype(np.float64)
                masked[rows, first] = np.inf
                d2[start:stop] = masked.min(axis=1)
        return nearest, d1, d2

    def _nearest2_numba(
        self, desc: NDArray[Any], ids: NDArray[np.int64]
    ) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
        from fleetslam.slam._hamming_kernels import NO_SECOND, nearest2_packed

        assert self._index_packed is not None
        rows, first, second = nearest2_packed(pack_binary(desc), self._index_packed)
        d2 = second.astype(np.float64)
        d2[second == NO_SECOND] = np.inf
        return ids[rows], first.astype(np.float64), d2

    @staticmethod
    def _nearest2_opencv(
        desc: NDArray[Any], ids: NDArray[np.int64], data: NDArray[Any]
    ) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
        cv2 = require("cv2", "slam")
        dist, index = cv2.batchDistance(desc, data, cv2.CV_32S, normType=cv2.NORM_HAMMING, K=2)
        distances = np.asarray(dist, dtype=np.float64)
        nearest = np.asarray(ids[np.asarray(index)[:, 0]], dtype=np.int64)
        return nearest, distances[:, 0].copy(), distances[:, 1].copy()

    # ------------------------------------------------------------------ inverted index
    def add_references(self, location_id: int, word_ids: Iterable[int]) -> None:
        """Record that a location (in STM/WM) contains these words; reactivates inactive words."""
        reactivated = False
        for word, count in Counter(int(w) for w in word_ids if w >= 0).items():
            refs = self._references.setdefault(word, {})
            refs[location_id] = refs.get(location_id, 0) + count
            if not self._active[word]:
                self._active[word] = True
                reactivated = True
        if reactivated:
            self._index_dirty = True

    def remove_references(self, location_id: int, word_ids: Iterable[int]) -> list[int]:
        """Forget a location's references (it left RAM); words left without references are deactivated.

        Returns the ids of the deactivated words.
        """
        deactivated = []
        for word in sorted({int(w) for w in word_ids if w >= 0}):
            refs = self._references.get(word)
            if refs is None:
                continue
            refs.pop(location_id, None)
            if not refs:
                del self._references[word]
                if self._active[word]:
                    self._active[word] = False
                    deactivated.append(word)
        if deactivated:
            self._index_dirty = True
        return deactivated

    def references(self, word_id: int) -> dict[int, int]:
        """Locations referencing a word: location id -> occurrences (empty if none)."""
        return self._references.get(int(word_id), {})

    # ------------------------------------------------------------------ persistence helpers
    @classmethod
    def from_words(
        cls,
        descriptors: NDArray[np.generic],
        kind: DescriptorKind = "binary",
        nndr_ratio: float = 0.8,
        max_distance: float = 0.0,
    ) -> VisualVocabulary:
        """A dictionary holding these words (ids 0..N-1), all inactive until locations reference them."""
        vocabulary = cls(kind, nndr_ratio, max_distance)
        if len(descriptors):
            vocabulary.add_words(descriptors)
            vocabulary._active[: vocabulary._size] = False
            vocabulary._index_dirty = True
        return vocabulary
