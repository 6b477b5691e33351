"""ORB keypoints bucketed on a grid from one detect-and-describe pass: the kept keypoints and their descriptors are
exactly what describing only the kept keypoints gives (the two-pass way the extractor used before), on a real
texture with far more corners than the budget."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from fleetslam.slam.features import FeatureExtractor, bucket

from .textured_room import make_textures


@pytest.fixture(scope="module")
def texture() -> np.ndarray:
    return make_textures(np.random.default_rng(7))[0]


def test_orb_keeps_the_budget_evenly_and_describes_what_it_keeps(texture: np.ndarray) -> None:
    extractor = FeatureExtractor(max_features=300)
    features = extractor.detect(texture)
    assert len(features) == 300
    assert features.descriptors.shape == (300, 32) and features.descriptors.dtype == np.uint8
    # Every cell of the 4×4 grid has keypoints (the texture is busy everywhere).
    cells = {(int(y * 4 / texture.shape[0]), int(x * 4 / texture.shape[1])) for x, y in features.keypoints}
    assert len(cells) == 16

    # The same keypoints the two-pass way: detect, bucket, describe only the kept ones.
    detector = extractor._detector
    found = detector.detect(texture, None)
    points = cv2.KeyPoint_convert(found).astype(np.float32)
    responses = np.array([k.response for k in found], np.float32)
    kept = [found[i] for i in bucket(points, responses, texture.shape, 4, 4, 300)]
    described, descriptors = detector.compute(texture, kept)
    np.testing.assert_array_equal(features.descriptors, descriptors)
    np.testing.assert_array_equal(features.responses, [k.response for k in described])


def test_no_corners_gives_empty_features(texture: np.ndarray) -> None:
    features = FeatureExtractor().detect(np.full_like(texture, 90))
    assert len(features) == 0 and features.descriptors.shape == (0, 32)


@pytest.mark.skipif(hasattr(cv2, "AKAZE_create"), reason="this OpenCV has AKAZE")
def test_akaze_without_it_in_opencv_is_a_clear_error() -> None:
    with pytest.raises(ValueError, match=r"akaze.*OpenCV"):
        FeatureExtractor("akaze")
