"""RTAB-Map memory management: short-term (STM), working (WM) and long-term (LTM) memory.

- A new location enters the STM (the ``stm_size`` most recent locations). STM locations are never loop
  candidates: they look like the current image only because the robot has just been there.
- **Rehearsal (weight update)**: the new location is compared with the previous one (RTAB-Map's
  ``Signature::compareTo``, common words over the larger word count). At or above ``rehearsal_similarity``
  they are merged the way RTAB-Map does it in graph-SLAM mode (locations have poses, so neither is deleted
  and the odometry link between them is kept): the new location takes ``weight = new + old + 1`` and the
  old one drops to weight 0, making it the first to go to LTM. (Without poses RTAB-Map deletes the old
  location entirely; fleetslam always has odometry, so that "full merge" is not implemented.)
- The oldest STM location moves to the WM when the STM is full. Loop closures are searched in the WM.
- **Transfer**: when the WM holds more than ``max_wm_size`` locations or the keyframe took longer than the
  time budget, locations move from WM to LTM: lowest weight first, then oldest (lowest id), never those the
  caller protects (the hypothesis just retrieved around, the last loop closure). Their words' references
  leave the inverted index; words nobody references any more leave the active vocabulary index.
- **Retrieval**: up to ``max_retrieved`` LTM locations nearest (in graph links) to the highest loop
  hypothesis come back to the WM, with their words.

Signatures stay in RAM in all three memories (LTM locations only leave the search structures); the whole
memory is persisted by :meth:`Memory.save` / :meth:`Memory.load` through :class:`MapDatabase`.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fleetslam.errors import SlamError
from fleetslam.geometry import relative
from fleetslam.slam.signature import Link, LinkType, Signature, word_set_similarity
from fleetslam.slam.vocabulary import VisualVocabulary

if TYPE_CHECKING:
    from fleetslam.slam.database import MapDatabase
    from fleetslam.slam.frontend import KeyframeObservation

logger = logging.getLogger(__name__)

MemoryKind = Literal["stm", "wm", "ltm"]


@dataclass
class AddResult:
    """Outcome of :meth:`Memory.add`."""

    signature: Signature
    """The new location (its ``id`` and ``word_ids`` are set)."""
    rehearsed_with: int | None
    """Id of the previous location it was merged with by rehearsal, or None."""
    similarity: float
    """Similarity with the previous location (0 when there was none)."""


class Memory:
    """Locations (signatures), their links, the vocabulary and the STM/WM/LTM bookkeeping."""

    def __init__(
        self,
        vocabulary: VisualVocabulary,
        stm_size: int = 10,
        rehearsal_similarity: float = 0.6,
        max_wm_size: int = 0,
        max_retrieved: int = 2,
        keep_images: bool = True,
        map_id: int = 0,
        max_words: int = 0,
    ) -> None:
        """``max_words``: keypoints of a location quantised to words, the strongest first (0: all)."""
        if stm_size < 1:
            raise SlamError(f"memory: stm_size={stm_size} must be >= 1")
        self.vocabulary = vocabulary
        self.stm_size = stm_size
        self.rehearsal_similarity = rehearsal_similarity
        self.max_wm_size = max_wm_size
        self.max_retrieved = max_retrieved
        self.keep_images = keep_images
        self.map_id = map_id
        self.max_words = max_words
        self.signatures: dict[int, Signature] = {}
        self.stm: list[int] = []
        """STM ids, oldest first."""
        self.wm: dict[int, None] = {}
        """WM ids in insertion order (an ordered set)."""
        self.ltm: set[int] = set()
        self._next_id = 1
        self.last_id: int | None = None
        """Id of the most recently added location."""

    def _word_keypoints(self, count: int, responses: ArrayLike | None) -> NDArray[np.intp]:
        # Every unmatched descriptor becomes a new word, and each keyframe's search is over every word in RAM:
        # words per location set both the growth of the vocabulary and the cost of the search (RTAB-Map
        # Kp/MaxFeatures, 500 by default).
        if self.max_words <= 0 or count <= self.max_words:
            return np.arange(count, dtype=np.intp)
        if responses is None:
            return np.arange(self.max_words, dtype=np.intp)
        strength = np.asarray(responses, dtype=np.float64).reshape(-1)
        if len(strength) != count:
            raise SlamError(f"memory: {len(strength)} responses for {count} descriptors")
        return np.sort(np.argsort(-strength, kind="stable")[: self.max_words])

    # ------------------------------------------------------------------ queries
    def where(self, location_id: int) -> MemoryKind:
        """Which memory holds the location."""
        if location_id in self.wm:
            return "wm"
        if location_id in self.ltm:
            return "ltm"
        if location_id in self.stm:
            return "stm"
        raise SlamError(f"memory: no location with id {location_id}")

    def wm_ids(self) -> list[int]:
        """Ids of the working memory (loop-closure candidates), ascending."""
        return sorted(self.wm)

    def neighbors(self, location_id: int) -> list[int]:
        """Ids linked to a location (odometry and loop links), whatever memory they are in."""
        signature = self.signatures.get(location_id)
        return sorted(signature.links) if signature is not None else []

    def __len__(self) -> int:
        return len(self.signatures)

    # ------------------------------------------------------------------ adding
    def add(self, observation: KeyframeObservation) -> AddResult:
        """Create a location, quantise its descriptors, link it to the previous one, rehearse, update STM/WM.

        The observation's ``odometry_transform`` is ``T_previous_new`` (computed from the poses when None). With
        ``max_words``, only that many keypoints become words: the strongest by detector ``responses`` (the first
        ones without them); the rest keep their descriptors for verification and carry word id -1.

        Raises:
            SlamError: the observation has no features, or their arrays differ in length.
        """
        features = observation.features
        if features is None:
            raise SlamError("memory: a location needs the keyframe's features (its front-end gives none)")
        descriptors = features.descriptors
        pose_arr = np.asarray(observation.pose, dtype=np.float64)
        keypoints_arr = np.asarray(features.keypoints, dtype=np.float32).reshape(-1, 2)
        points_arr = np.asarray(features.points3d, dtype=np.float32).reshape(-1, 3)
        if not (len(keypoints_arr) == len(points_arr) == len(descriptors)):
            raise SlamError(
                f"memory: {len(keypoints_arr)} keypoints, {len(points_arr)} points and {len(descriptors)} "
                "descriptors must have the same length"
            )
        word_ids = np.full(len(descriptors), -1, np.int64)
        chosen = self._word_keypoints(len(descriptors), features.responses)
        word_ids[chosen] = self.vocabulary.quantize(np.asarray(descriptors)[chosen], add=True)
        signature = Signature(
            id=self._next_id,
            stamp=float(observation.stamp),
            pose=pose_arr,
            keypoints=keypoints_arr,
            points3d=points_arr,
            descriptors=np.asarray(descriptors),
            word_ids=word_ids,
            map_id=self.map_id,
            rgb_compressed=observation.rgb_compressed if self.keep_images else None,
            depth_compressed=observation.depth_compressed if self.keep_images else None,
        )
        self._next_id += 1
        self.signatures[signature.id] = signature
        self.vocabulary.add_references(signature.id, word_ids)

        previous = self.signatures.get(self.last_id) if self.last_id is not None else None
        rehearsed_with = None
        similarity = 0.0
        if previous is not None and previous.map_id == signature.map_id:
            transform = (
                relative(previous.pose, pose_arr)
                if observation.odometry_transform is None
                else np.asarray(observation.odometry_transform, dtype=np.float64)
            )
            information = (
                np.eye(6)
                if observation.odometry_information is None
                else np.asarray(observation.odometry_information, float)
            )
            self.add_link(Link(previous.id, signature.id, LinkType.ODOMETRY, transform, information))
            if previous.id in self.stm:
                similarity = word_set_similarity(signature, previous)
                if similarity >= self.rehearsal_similarity:
                    signature.weight += previous.weight + 1
                    previous.weight = 0
                    rehearsed_with = previous.id
        self.last_id = signature.id
        self.stm.append(signature.id)
        while len(self.stm) > self.stm_size:
            self.wm[self.stm.pop(0)] = None
        return AddResult(signature, rehearsed_with, similarity)

    def add_link(self, link: Link, update_weights: bool = False) -> None:
        """Add a link and its inverse. ``update_weights`` (accepted loop closures): RTAB-Map moves the old
        location's weight to the new one (``to_id`` gets ``from + to``, ``from_id`` drops to 0)."""
        if link.from_id not in self.signatures or link.to_id not in self.signatures:
            raise SlamError(f"memory: link {link.from_id}->{link.to_id} names an unknown location")
        self.signatures[link.from_id].add_link(link)
        self.signatures[link.to_id].add_link(link.inverse())
        if update_weights:
            old, new = self.signatures[link.from_id], self.signatures[link.to_id]
            new.weight += old.weight
            old.weight = 0

    # ------------------------------------------------------------------ likelihood
    def likelihood(self, signature: Signature, tf_idf: bool = True) -> dict[int, float]:
        """Raw similarity of ``signature`` with every WM location (0 for those sharing no word).

        TF-IDF (RTAB-Map Kp/TfIdfLikelihoodUsed): ``Σ_w (n_wi / n_i) · log10(N / n_w)`` over the words w of
        the query, with n_wi the occurrences of w in location i, n_i its word count, N the number of
        locations in RAM (STM + WM) and n_w the number of those referencing w.
        """
        scores = dict.fromkeys(self.wm_ids(), 0.0)
        if not scores:
            return scores
        if not tf_idf:
            for location_id in scores:
                scores[location_id] = word_set_similarity(signature, self.signatures[location_id])
            return scores
        n_locations = len(self.wm) + len(self.stm)
        # A location's word count, once per location rather than once per shared word.
        word_count = {location_id: self.signatures[location_id].word_count for location_id in scores}
        for word in signature.word_counts():
            refs = self.vocabulary.references(word)
            if not refs:
                continue
            idf = math.log10(n_locations / len(refs))
            for location_id, occurrences in refs.items():
                if location_id in scores:
                    scores[location_id] += occurrences / word_count[location_id] * idf
        return scores

    def bag_of_words(self, location_id: int) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """A location's words and their TF-IDF weights ``(n_w / n) · log10(N / N_w)``: n_w its occurrences of
        w, n its word count, N every location in memory, N_w those referencing w. Empty when unknown."""
        signature = self.signatures.get(location_id)
        if signature is None or signature.word_count == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.float64)
        words, counts = np.unique(signature.word_ids[signature.word_ids >= 0], return_counts=True)
        locations = max(len(self.signatures), 1)
        idf = np.array([math.log10(locations / max(len(self.vocabulary.references(int(w))), 1)) for w in words])
        return words, counts / max(signature.word_count, 1) * idf

    # ------------------------------------------------------------------ transfer and retrieval
    def retrieval_candidates(self, around_id: int, max_count: int | None = None) -> list[int]:
        """LTM locations nearest to ``around_id`` through links (breadth first, then lowest id)."""
        limit = self.max_retrieved if max_count is None else max_count
        if limit <= 0 or around_id not in self.signatures:
            return []
        found: list[int] = []
        seen = {around_id}
        frontier = deque([around_id])
        while frontier and len(found) < limit:
            level = sorted(frontier)
            frontier.clear()
            for location_id in level:
                for other in self.neighbors(location_id):
                    if other in seen:
                        continue
                    seen.add(other)
                    frontier.append(other)
            for other in sorted(frontier):
                if other in self.ltm and len(found) < limit:
                    found.append(other)
        return found

    def retrieve(self, ids: Iterable[int]) -> list[int]:
        """Bring LTM locations back to the WM (with their words); returns the ids actually moved."""
        moved = []
        for location_id in ids:
            if location_id not in self.ltm:
                continue
            self.ltm.discard(location_id)
            self.wm[location_id] = None
            self.vocabulary.add_references(location_id, self.signatures[location_id].word_ids)
            moved.append(location_id)
        if moved:
            logger.debug("retrieved %s from LTM", moved)
        return moved

    def transfer_to_ltm(self, count: int, protected: Iterable[int] = ()) -> list[int]:
        """Move up to ``count`` WM locations to LTM: lowest weight first, then oldest; never ``protected``."""
        keep = set(protected)
        candidates = sorted((self.signatures[i].weight, i) for i in self.wm if i not in keep)
        moved = [i for _, i in candidates[: max(0, count)]]
        for location_id in moved:
            del self.wm[location_id]
            self.ltm.add(location_id)
            self.vocabulary.remove_references(location_id, self.signatures[location_id].word_ids)
        if moved:
            logger.debug("transferred %s to LTM", moved)
        return moved

    def enforce_limits(self, over_time_budget: bool, protected: Iterable[int] = (), retrieved: int = 0) -> list[int]:
        """Transfers after a keyframe: down to ``max_wm_size``, and when over the time budget at least
        ``1 + retrieved`` more (so the WM stops growing while the budget is exceeded)."""
        keep = set(protected)
        count = 0
        if self.max_wm_size > 0:
            count = max(0, len(self.wm) - self.max_wm_size)
        if over_time_budget:
            count = max(count, 1 + retrieved)
        return self.transfer_to_ltm(count, keep) if count else []

    # ------------------------------------------------------------------ persistence
    def save(self, database: MapDatabase) -> None:
        """Write every location, link, the vocabulary and the memory state to the database."""
        states: dict[int, MemoryKind] = {i: self.where(i) for i in self.signatures}
        database.save_vocabulary(self.vocabulary)
        database.save_signatures(self.signatures.values(), states)
        database.save_links([link for s in self.signatures.values() for link in s.links.values()])
        database.commit()

    @classmethod
    def load(
        cls,
        database: MapDatabase,
        nndr_ratio: float = 0.8,
        max_distance: float = 0.0,
        new_session: bool = True,
        *,
        stm_size: int = 10,
        rehearsal_similarity: float = 0.6,
        max_wm_size: int = 0,
        max_retrieved: int = 2,
        keep_images: bool = True,
        max_words: int = 0,
    ) -> Memory:
        """Rebuild a memory from a database.

        ``new_session`` (multi-session): the previous STM joins the WM, new locations get the next map id
        and ids continue after the largest stored one; the first new location is not linked to the old map
        (a loop closure will connect the sessions). Otherwise the saved STM/WM/LTM split is restored.
        """
        vocabulary = database.load_vocabulary(nndr_ratio=nndr_ratio, max_distance=max_distance)
        signatures, states = database.load_signatures()
        links = database.load_links()
        max_map = max((s.map_id for s in signatures.values()), default=-1)
        memory = cls(
            vocabulary,
            stm_size=stm_size,
            rehearsal_similarity=rehearsal_similarity,
            max_wm_size=max_wm_size,
            max_retrieved=max_retrieved,
            keep_images=keep_images,
            map_id=max_map + 1 if new_session else max(max_map, 0),
            max_words=max_words,
        )
        memory.signatures = signatures
        for link in links:
            if link.from_id in signatures:
                signatures[link.from_id].links[link.to_id] = link
        for location_id in sorted(signatures):
            state = states[location_id]
            if state == "ltm":
                memory.ltm.add(location_id)
                continue
            if state == "stm" and not new_session:
                memory.stm.append(location_id)
            else:
                memory.wm[location_id] = None
            vocabulary.add_references(location_id, signatures[location_id].word_ids)
        memory._next_id = max(signatures, default=0) + 1
        if not new_session and signatures:
            memory.last_id = max(signatures)
        return memory
