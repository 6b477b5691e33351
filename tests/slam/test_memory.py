"""Memory management: rehearsal weight update, STM -> WM, WM -> LTM transfer (size, time budget), retrieval."""

from __future__ import annotations

import numpy as np
import pytest

from fleetslam.errors import SlamError
from fleetslam.slam.loop_closure import make_loop_closure_detector
from fleetslam.slam.loop_config import LoopClosureConfig, MemoryConfig
from fleetslam.slam.memory import Memory
from fleetslam.slam.signature import LinkType
from fleetslam.slam.vocabulary import VisualVocabulary

from .loop_scene import CAMERA_MATRIX, Place, make_place, observe, place_pose


def add_place(memory: Memory, rng: np.random.Generator, place: Place, stamp: float = 0.0):
    obs = observe(rng, place, place.pose)
    return memory.add(obs.keyframe(stamp))


def filled_memory(n: int, stm_size: int = 2, **kwargs) -> tuple[Memory, list[Place]]:
    rng = np.random.default_rng(20)
    memory = Memory(VisualVocabulary(), stm_size=stm_size, **kwargs)
    places = [make_place(rng, place_pose(k)) for k in range(n)]
    for k, place in enumerate(places):
        add_place(memory, rng, place, float(k))
    return memory, places


def test_rehearsal_merges_similar_consecutive_locations() -> None:
    rng = np.random.default_rng(21)
    memory = Memory(VisualVocabulary(), stm_size=10, rehearsal_similarity=0.6)
    same = make_place(rng, place_pose(0))
    first = add_place(memory, rng, same)
    second = add_place(memory, rng, same)
    third = add_place(memory, rng, same)
    assert first.rehearsed_with is None
    assert second.rehearsed_with == 1 and second.similarity > 0.9
    assert third.rehearsed_with == 2
    weights = [memory.signatures[i].weight for i in (1, 2, 3)]
    assert weights == [0, 0, 2]
    # Both locations stay in the graph, linked by odometry (graph-SLAM rehearsal keeps the poses).
    assert memory.signatures[2].links[3].type == LinkType.ODOMETRY
    other = add_place(memory, rng, make_place(rng, place_pose(1)))
    assert other.rehearsed_with is None and other.similarity < 0.1
    assert other.signature.weight == 0
    assert memory.signatures[3].weight == 2


def test_stm_locations_are_not_candidates() -> None:
    memory, _ = filled_memory(5, stm_size=3)
    assert memory.stm == [3, 4, 5]
    assert memory.wm_ids() == [1, 2]
    assert set(memory.likelihood(memory.signatures[5])) == {1, 2}
    assert [memory.where(i) for i in (1, 3)] == ["wm", "stm"]
    np.testing.assert_allclose(
        memory.signatures[2].links[3].transform, np.linalg.inv(place_pose(1)) @ place_pose(2), atol=1e-12
    )


def test_tf_idf_likelihood_scores_the_shared_location() -> None:
    rng = np.random.default_rng(22)
    memory, places = filled_memory(8, stm_size=2)
    obs = observe(rng, places[3], places[3].pose)
    query = memory.add(obs.keyframe(99.0)).signature
    scores = memory.likelihood(query)
    assert max(scores, key=scores.__getitem__) == 4
    assert all(v == 0.0 for k, v in scores.items() if k != 4)


def test_transfer_lowest_weight_then_oldest_and_never_protected() -> None:
    memory, _ = filled_memory(10, stm_size=2)
    assert memory.wm_ids() == list(range(1, 9))
    for location_id, weight in {1: 3, 2: 0, 3: 1, 4: 0, 5: 0, 6: 2, 7: 0, 8: 5}.items():
        memory.signatures[location_id].weight = weight
    moved = memory.transfer_to_ltm(4, protected={4})
    assert moved == [2, 5, 7, 3]
    assert memory.ltm == {2, 3, 5, 7}
    assert memory.wm_ids() == [1, 4, 6, 8]


def test_transfer_by_working_memory_size() -> None:
    memory, _ = filled_memory(12, stm_size=2, max_wm_size=4)
    # enforce_limits is what the detector calls after each keyframe.
    moved = memory.enforce_limits(over_time_budget=False)
    assert moved == [1, 2, 3, 4, 5, 6]
    assert memory.wm_ids() == [7, 8, 9, 10]
    assert memory.enforce_limits(over_time_budget=False) == []


def test_transferred_words_leave_the_index_and_retrieval_restores_them() -> None:
    rng = np.random.default_rng(23)
    memory, places = filled_memory(10, stm_size=2)
    words_of_3 = memory.signatures[3].word_ids
    memory.transfer_to_ltm(3, protected=set())  # 1, 2, 3 (all weight 0, oldest first)
    assert memory.ltm == {1, 2, 3}
    assert not any(memory.vocabulary.is_active(int(w)) for w in words_of_3)
    revisit = observe(rng, places[2], places[2].pose)
    assert (memory.vocabulary.quantize(revisit.descriptors, add=False) == -1).all()
    # Retrieval around location 5: its LTM neighbours by link depth (4 is in WM, 3 then 2 are in LTM).
    assert memory.retrieval_candidates(5, 2) == [3, 2]
    assert memory.retrieval_candidates(5, 1) == [3]
    assert memory.retrieve([3]) == [3]
    assert memory.where(3) == "wm"
    assert all(memory.vocabulary.is_active(int(w)) for w in words_of_3)
    ids = memory.vocabulary.quantize(revisit.descriptors, add=False)
    assert (ids >= 0).mean() > 0.9
    assert set(ids[ids >= 0].tolist()) <= set(words_of_3.tolist())


class FakeClock:
    """Advances by a fixed step at every reading."""

    def __init__(self, step_s: float) -> None:
        self.now = 0.0
        self.step_s = step_s

    def __call__(self) -> float:
        self.now += self.step_s
        return self.now


def run_with_budget(time_threshold_ms: float) -> tuple[list[list[int]], list[int]]:
    rng = np.random.default_rng(24)
    detector = make_loop_closure_detector(
        LoopClosureConfig(),
        MemoryConfig(stm_size=2, time_threshold_ms=time_threshold_ms),
        CAMERA_MATRIX,
        clock=FakeClock(0.050),  # every keyframe "takes" 50 ms
    )
    transferred: list[list[int]] = []
    wm_sizes: list[int] = []
    for k in range(8):
        place = make_place(rng, place_pose(k))
        obs = observe(rng, place, place.pose)
        hyp = detector.process(obs.keyframe(float(k)))
        assert hyp.elapsed_ms == pytest.approx(50.0)
        transferred.append(hyp.transferred)
        wm_sizes.append(len(detector.memory.wm))
        assert hyp.match_id not in hyp.transferred
        assert not set(hyp.retrieved) & set(hyp.transferred)
    return transferred, wm_sizes


def test_transfer_by_time_budget_with_injected_clock() -> None:
    within, wm_within = run_with_budget(100.0)
    assert all(not t for t in within)
    assert wm_within == [0, 0, 1, 2, 3, 4, 5, 6]
    over, wm_over = run_with_budget(30.0)
    # Over budget, every keyframe with a transferable WM location transfers 1 + (locations retrieved).
    assert all(len(t) >= 1 for t in over[3:])
    assert max(wm_over) <= 3 < max(wm_within)


def test_bag_of_words_weights_are_tf_idf() -> None:
    memory, _ = filled_memory(6)
    words, weights = memory.bag_of_words(3)
    signature = memory.signatures[3]
    assert len(words) == len(np.unique(signature.word_ids)) and len(weights) == len(words)
    word = int(words[0])
    occurrences = int(np.count_nonzero(signature.word_ids == word))
    references = len(memory.vocabulary.references(word))
    expected = occurrences / signature.word_ids.size * np.log10(len(memory.signatures) / references)
    assert weights[0] == pytest.approx(expected)
    assert np.all(weights >= 0)
    assert memory.bag_of_words(999)[0].size == 0


def test_word_budget_quantises_the_strongest_keypoints_and_keeps_every_descriptor() -> None:
    rng = np.random.default_rng(23)
    memory = Memory(VisualVocabulary(), stm_size=2, max_words=40)
    places = [make_place(rng, place_pose(k)) for k in range(4)]
    for k, place in enumerate(places):
        obs = observe(rng, place, place.pose)
        responses = rng.uniform(0.0, 1.0, len(obs.descriptors))
        added = memory.add(obs.keyframe(float(k), responses=responses))
        signature = added.signature
        strongest = np.sort(np.argsort(-responses)[:40])
        assert signature.word_count == 40
        np.testing.assert_array_equal(np.flatnonzero(signature.word_ids >= 0), strongest)
        assert len(signature.descriptors) == len(obs.descriptors)  # verification still sees every keypoint
    assert len(memory.vocabulary) <= 4 * 40
    # Term frequencies are over the words a location has, not its keypoints: its weights sum to a weighted mean
    # of its words' idf (divided by every keypoint, they would fall well below the smallest).
    words, weights = memory.bag_of_words(1)
    idf = np.log10(len(memory.signatures) / np.array([len(memory.vocabulary.references(int(w))) for w in words]))
    assert len(words) > 0 and idf.min() - 1e-12 <= float(weights.sum()) <= idf.max() + 1e-12
    with pytest.raises(SlamError, match="3 responses for"):
        obs = observe(rng, places[0], places[0].pose)
        memory.add(obs.keyframe(9.0, responses=np.array([1.0, 2.0, 3.0])))
