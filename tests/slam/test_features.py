"""ORB keypoints bucketed on a grid from one detect-and-describe pass: the kept keypoints and their descriptors are
exactly what describing only the kept keypoints gives (the two-pass way the extractor used before), on a real
texture with far more corners than the budget."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from fleetslam.slam.features import FeatureExtractor, Features, SubpixelRefiner, bucket

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


def _squares(offset: tuple[float, float], side: int = 14, pitch: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """A 320×240 image of bright squares on a dark ground, anti-aliased (drawn 8× larger and averaged down), and
    their corners' exact positions (pixel centres at integers), at the sub-pixel ``offset``."""
    up, (w, h) = 8, (320, 240)
    big = np.full((h * up, w * up), 40, np.uint8)
    corners = []
    for y in range(24, h - 24 - side, pitch):
        for x in range(24, w - 24 - side, pitch):
            x0, y0 = x + offset[0], y + offset[1]
            rows = slice(round((y0 + 0.5) * up), round((y0 + side + 0.5) * up))
            big[rows, round((x0 + 0.5) * up) : round((x0 + side + 0.5) * up)] = 210
            corners += [(x0, y0), (x0 + side, y0), (x0, y0 + side), (x0 + side, y0 + side)]
    return cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA), np.array(corners, np.float32)


def test_subpixel_keypoints_sit_on_the_corners() -> None:
    # ORB's FAST keypoints lie on their level's pixel grid, about a pixel inside a corner; refined, on its apex.
    image, corners = _squares((0.3, 0.6))
    plain = FeatureExtractor(orb_patch_size=15).detect(image)
    refined = FeatureExtractor(orb_patch_size=15, subpixel_window=5).detect(image)
    # Describing is unchanged: the same keypoints in the same order, only their positions moved.
    np.testing.assert_array_equal(refined.descriptors, plain.descriptors)
    np.testing.assert_array_equal(refined.scales, plain.scales)
    assert 0.0 < np.abs(refined.keypoints - plain.keypoints).max() <= 5.0 * refined.scales.max()

    def error(features: Features) -> float:
        distance = np.linalg.norm(features.keypoints[:, None] - corners[None], axis=2)
        return float(np.median(distance.min(axis=0)))

    assert error(plain) > 1.0
    assert error(refined) < 0.1


def test_subpixel_refinement_keeps_points_without_a_corner() -> None:
    # A straight edge fixes only one direction and a flat patch none: those points keep their positions.
    image = np.full((60, 80), 50, np.uint8)
    image[:, 40:] = 200
    points = np.array([[39.0, 30.0], [40.0, 20.0], [10.0, 30.0]], np.float32)
    refiner = SubpixelRefiner(window=5)
    np.testing.assert_array_equal(refiner.refine(image, points, np.ones(3, np.float32)), points)
    # …while a corner's point moves to it, within the allowed shift only.
    image[:30, :] = 50
    near = points[:1] + 1.0
    np.testing.assert_allclose(refiner.refine(image, near, np.ones(1, np.float32)), [[39.5, 29.5]], atol=0.05)
    held = SubpixelRefiner(window=5, max_shift=0.5).refine(image, near, np.ones(1, np.float32))
    np.testing.assert_array_equal(held, near)
