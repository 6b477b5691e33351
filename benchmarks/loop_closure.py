"""Loop-closure throughput: the vocabulary's exact 2-NN (numpy popcount) vs OpenCV's brute-force Hamming
matcher on the same data, and the detector's time per keyframe on a synthetic sequence with revisits.

Prints one JSON line. Synthetic ORB-like data (random 256-bit descriptors, bit-flip noise).

    python benchmarks/loop_closure.py [--words 50000] [--queries 500] [--keyframes 300] [--features 500]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from fleetslam.geometry import pose_from_xyz_rpy
from fleetslam.slam.frontend import KeyframeFeatures, KeyframeObservation
from fleetslam.slam.loop_closure import make_loop_closure_detector
from fleetslam.slam.loop_config import LoopClosureConfig, MemoryConfig
from fleetslam.slam.vocabulary import VisualVocabulary

CAMERA_MATRIX = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])


def best_of(fn, repeats: int = 3) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def nn_benchmark(n_words: int, n_queries: int) -> dict[str, float]:
    import cv2

    rng = np.random.default_rng(0)
    words = rng.integers(0, 256, size=(n_words, 32), dtype=np.uint8)
    queries = rng.integers(0, 256, size=(n_queries, 32), dtype=np.uint8)
    vocabulary = VisualVocabulary()
    vocabulary.add_words(words)
    numpy_only = VisualVocabulary(search="numpy")
    numpy_only.add_words(words)
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
    ours = best_of(lambda: vocabulary.nearest2(queries))
    ours_numpy = best_of(lambda: numpy_only.nearest2(queries))
    peer = best_of(lambda: matcher.knnMatch(queries, words, k=2))
    _, d1, _ = vocabulary.nearest2(queries)
    peer_d1 = np.array([m[0].distance for m in matcher.knnMatch(queries, words, k=2)])
    return {
        "nn_words": n_words,
        "nn_queries": n_queries,
        "nn_ours_ms": ours * 1e3,
        "nn_ours_numpy_ms": ours_numpy * 1e3,
        "nn_opencv_bf_ms": peer * 1e3,
        "nn_ratio_ours_over_opencv": ours / peer,
        "nn_agree": float(np.array_equal(d1, peer_d1) and np.array_equal(numpy_only.nearest2(queries)[1], peer_d1)),
    }


def detector_benchmark(n_keyframes: int, n_features: int) -> dict[str, float]:
    rng = np.random.default_rng(1)
    detector = make_loop_closure_detector(LoopClosureConfig(), MemoryConfig(), CAMERA_MATRIX)
    n_places = n_keyframes * 2 // 3
    place_desc = [rng.integers(0, 256, size=(n_features, 32), dtype=np.uint8) for _ in range(n_places)]
    place_pts = [
        np.column_stack(
            [rng.uniform(-2, 2, n_features), rng.uniform(-1.5, 1.5, n_features), rng.uniform(2, 6, n_features)]
        )
        for _ in range(n_places)
    ]
    sequence = list(range(n_places)) + list(range(n_keyframes - n_places))
    times = []
    accepted = 0
    for step, k in enumerate(sequence):
        pts = place_pts[k]
        uv = (CAMERA_MATRIX @ pts.T).T
        uv = uv[:, :2] / uv[:, 2:3] + rng.normal(0, 0.3, (n_features, 2))
        desc = place_desc[k].copy()
        flips = rng.integers(0, 256, size=(n_features, 8))
        np.bitwise_xor.at(desc, (np.arange(n_features)[:, None], flips // 8), (1 << (flips % 8)).astype(np.uint8))
        start = time.perf_counter()
        observation = KeyframeObservation(
            float(step), pose_from_xyz_rpy(10.0 * k, 0, 0, 0, 0, 0), KeyframeFeatures(uv, pts, desc)
        )
        hyp = detector.process(observation)
        times.append(time.perf_counter() - start)
        accepted += hyp.accepted
    arr = np.array(times) * 1e3
    return {
        "keyframes": n_keyframes,
        "features": n_features,
        "vocabulary_words": len(detector.memory.vocabulary),
        "keyframe_mean_ms": float(arr.mean()),
        "keyframe_p95_ms": float(np.percentile(arr, 95)),
        "keyframe_last10_mean_ms": float(arr[-10:].mean()),
        "loops_accepted": accepted,
        "revisits": n_keyframes - n_places,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--words", type=int, default=50_000)
    parser.add_argument("--queries", type=int, default=500)
    parser.add_argument("--keyframes", type=int, default=300)
    parser.add_argument("--features", type=int, default=500)
    args = parser.parse_args()
    result = {"benchmark": "loop_closure"}
    result.update(nn_benchmark(args.words, args.queries))
    result.update(detector_benchmark(args.keyframes, args.features))
    print(json.dumps(result))


if __name__ == "__main__":
    main()
