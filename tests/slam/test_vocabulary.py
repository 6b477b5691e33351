"""Incremental vocabulary: growth, saturation, exact nearest neighbours, activation through references."""

from __future__ import annotations

import numpy as np
import pytest

from fleetslam.errors import SlamError
from fleetslam.slam.vocabulary import VisualVocabulary, hamming_distances, pack_binary

from .loop_scene import flip_bits, random_descriptors


def brute_force_hamming(queries: np.ndarray, words: np.ndarray) -> np.ndarray:
    q_bits = np.unpackbits(queries, axis=1).astype(np.int32)
    w_bits = np.unpackbits(words, axis=1).astype(np.int32)
    return np.abs(q_bits[:, None, :] - w_bits[None, :, :]).sum(axis=2)


def nearest_after_growth(
    vocabulary: VisualVocabulary, words: np.ndarray, built: int, queries: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The queries' nearest words in a vocabulary whose index was built on the first ``built`` words and then grew
    by appending the rest; asserts both distances against brute force. Returns the nearest words, the brute-force
    distances (queries × words) and those sorted per query."""
    vocabulary.add_words(words[:built])
    vocabulary.nearest2(queries)  # builds the index; the next words are appended to it
    vocabulary.add_words(words[built:])
    nearest, d1, d2 = vocabulary.nearest2(queries)
    expected = brute_force_hamming(queries, words)
    sorted_dist = np.sort(expected, axis=1)
    np.testing.assert_array_equal(d1, sorted_dist[:, 0])
    np.testing.assert_array_equal(d2, sorted_dist[:, 1])
    return nearest, expected, sorted_dist


def test_vocabulary_grows_then_saturates_on_repeated_descriptors() -> None:
    rng = np.random.default_rng(1)
    vocabulary = VisualVocabulary("binary", nndr_ratio=0.8)
    base = random_descriptors(rng, 300)
    first = vocabulary.quantize(base)
    assert len(vocabulary) == 300
    assert sorted(first.tolist()) == list(range(300))
    sizes = []
    for _ in range(5):
        again = vocabulary.quantize(flip_bits(rng, base, 10))
        sizes.append(len(vocabulary))
        np.testing.assert_array_equal(again, first)
    assert sizes == [300] * 5
    fresh = vocabulary.quantize(random_descriptors(rng, 50))
    assert len(vocabulary) == 350
    assert set(fresh.tolist()) == set(range(300, 350))


def test_quantize_without_adding_marks_unknown_descriptors() -> None:
    rng = np.random.default_rng(2)
    vocabulary = VisualVocabulary()
    base = random_descriptors(rng, 100)
    vocabulary.quantize(base)
    ids = vocabulary.quantize(np.vstack([base[:5], random_descriptors(rng, 5)]), add=False)
    assert ids[:5].tolist() == [0, 1, 2, 3, 4]
    assert (ids[5:] == -1).all()
    assert len(vocabulary) == 100


@pytest.mark.parametrize("search", ["numpy", "opencv", "numba"])
def test_binary_nearest_neighbours_match_brute_force(search: str) -> None:
    if search != "numpy":
        pytest.importorskip({"opencv": "cv2"}.get(search, search))
    rng = np.random.default_rng(3)
    words = random_descriptors(rng, 700)
    # Ties included: a query equal to two words (the lower id must win) and one word duplicated.
    words[650] = words[651]
    queries = np.vstack([flip_bits(rng, words[:100], 20), random_descriptors(rng, 100), words[650:651]])
    vocabulary = VisualVocabulary(search=search)  # type: ignore[arg-type]
    assert vocabulary.search == search
    nearest, expected, sorted_dist = nearest_after_growth(vocabulary, words, 300, queries)
    np.testing.assert_array_equal(expected[np.arange(len(queries)), nearest], sorted_dist[:, 0])
    np.testing.assert_array_equal(nearest[:100], np.arange(100))
    assert nearest[-1] == 650 and sorted_dist[-1, 0] == 0 and sorted_dist[-1, 1] == 0  # d1, d2: equal to these
    np.testing.assert_array_equal(hamming_distances(pack_binary(queries), pack_binary(words)), expected)


@pytest.mark.parametrize("width", [8, 16, 48, 61, 64])
def test_the_numba_search_agrees_with_brute_force_at_every_descriptor_width(width: int) -> None:
    """The kernel sums four 64-bit lanes per pass over the words, then the rest one by one: one lane (8 bytes),
    two, four and two (48), eight with padding (AKAZE's 61 bytes), eight (BRISK's 64)."""
    pytest.importorskip("numba")
    rng = np.random.default_rng(width)
    words = rng.integers(0, 256, size=(500, width), dtype=np.uint8)
    queries = np.vstack([flip_bits(rng, words[:40], max(1, width // 4)), rng.integers(0, 256, (40, width), np.uint8)])
    nearest, expected, sorted_dist = nearest_after_growth(VisualVocabulary(search="numba"), words, 200, queries)
    lowest_nearest = (expected == sorted_dist[:, :1]).argmax(axis=1)  # ties: the lowest id
    np.testing.assert_array_equal(nearest, lowest_nearest)


def test_float_nearest_neighbours_match_brute_force() -> None:
    rng = np.random.default_rng(4)
    words = rng.normal(size=(400, 128)).astype(np.float32)
    queries = rng.normal(size=(50, 128)).astype(np.float32)
    vocabulary = VisualVocabulary("float")
    vocabulary.add_words(words)
    nearest, d1, d2 = vocabulary.nearest2(queries)
    expected = np.linalg.norm(queries[:, None, :].astype(np.float64) - words[None, :, :], axis=2)
    np.testing.assert_array_equal(nearest, expected.argmin(axis=1))
    np.testing.assert_allclose(d1, np.sort(expected, axis=1)[:, 0], rtol=1e-4)
    np.testing.assert_allclose(d2, np.sort(expected, axis=1)[:, 1], rtol=1e-4)


def test_words_without_references_leave_the_index_and_come_back() -> None:
    rng = np.random.default_rng(5)
    vocabulary = VisualVocabulary()
    a, b = random_descriptors(rng, 50), random_descriptors(rng, 50)
    ids_a, ids_b = vocabulary.quantize(a), vocabulary.quantize(b)
    vocabulary.add_references(1, ids_a)
    vocabulary.add_references(2, ids_b)
    vocabulary.add_references(2, ids_a[:10])
    deactivated = vocabulary.remove_references(1, ids_a)
    assert sorted(deactivated) == sorted(ids_a[10:].tolist())
    assert vocabulary.num_active == 60
    # A descriptor of an inactive word no longer finds it: it would become a new word.
    assert (vocabulary.quantize(a[10:], add=False) == -1).all()
    assert vocabulary.references(int(ids_a[0])) == {2: 1}
    vocabulary.add_references(1, ids_a)
    assert vocabulary.num_active == 100
    np.testing.assert_array_equal(vocabulary.quantize(flip_bits(rng, a, 5), add=False), ids_a)


def test_wrong_descriptor_type_is_an_error() -> None:
    vocabulary = VisualVocabulary("binary")
    with pytest.raises(SlamError, match="uint8"):
        vocabulary.quantize(np.zeros((3, 32), dtype=np.float32))
    with pytest.raises(SlamError, match="kind"):
        VisualVocabulary("hamming")  # type: ignore[arg-type]


def test_real_orb_descriptors_reuse_words_of_the_same_scene_only() -> None:
    cv2 = pytest.importorskip("cv2")
    data = pytest.importorskip("skimage.data")
    orb = cv2.ORB_create(500)

    def orb_descriptors(image: np.ndarray) -> np.ndarray:
        gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
        return orb.detectAndCompute(gray, None)[1]

    astronaut = data.astronaut()
    warp = cv2.getRotationMatrix2D((256.0, 256.0), 5.0, 1.0)
    warp[:, 2] += (8.0, -5.0)
    moved = cv2.warpAffine(astronaut, warp, (512, 512))
    vocabulary = VisualVocabulary("binary", nndr_ratio=0.8)
    vocabulary.quantize(orb_descriptors(astronaut))
    n_words = len(vocabulary)
    same_scene = vocabulary.quantize(orb_descriptors(moved))
    assert (same_scene < n_words).mean() > 0.5
    n_words = len(vocabulary)
    other_scene = vocabulary.quantize(orb_descriptors(data.coffee()))
    assert (other_scene < n_words).mean() < 0.1
