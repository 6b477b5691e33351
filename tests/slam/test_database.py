"""map.db round trip (write, close, reopen, compare everything) and multi-session continuation."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import numpy as np
import pytest

from fleetslam.errors import SlamError
from fleetslam.slam.database import MapDatabase
from fleetslam.slam.loop_closure import LoopClosureDetector, make_loop_closure_detector
from fleetslam.slam.loop_config import LoopClosureConfig, MemoryConfig
from fleetslam.slam.memory import Memory
from fleetslam.slam.signature import LinkType

from .loop_scene import CAMERA_MATRIX, Place, make_place, observe, place_pose, revisit_pose


def feed(detector: LoopClosureDetector, rng: np.random.Generator, place: Place, pose: np.ndarray, stamp: float):
    obs = observe(rng, place, pose)
    image = rng.integers(0, 256, size=64, dtype=np.uint8).tobytes()
    return detector.process(obs.keyframe(stamp, rgb_compressed=image, depth_compressed=image[:10]))


def first_session(rng: np.random.Generator) -> tuple[LoopClosureDetector, list[Place]]:
    # 20 places, revisited from the 4th: a short-term memory of 10 (RTAB-Map's) leaves them loop candidates.
    detector = make_loop_closure_detector(LoopClosureConfig(), MemoryConfig(max_wm_size=12, stm_size=10), CAMERA_MATRIX)
    places = [make_place(rng, place_pose(k)) for k in range(20)]
    for k, place in enumerate(places):
        feed(detector, rng, place, place.pose, float(k))
    for k in (3, 4, 5):
        feed(detector, rng, places[k], revisit_pose(places[k]), 50.0 + k)
    return detector, places


def assert_same_memory(a: Memory, b: Memory) -> None:
    assert sorted(a.signatures) == sorted(b.signatures)
    for i, sa in a.signatures.items():
        sb = b.signatures[i]
        assert (sa.id, sa.stamp, sa.weight, sa.map_id, sa.label) == (sb.id, sb.stamp, sb.weight, sb.map_id, sb.label)
        for name in ("pose", "keypoints", "points3d", "descriptors", "word_ids"):
            x, y = getattr(sa, name), getattr(sb, name)
            assert x.dtype == y.dtype, name
            np.testing.assert_array_equal(x, y, err_msg=name)
        assert sa.rgb_compressed == sb.rgb_compressed and sa.depth_compressed == sb.depth_compressed
        assert sorted(sa.links) == sorted(sb.links)
        for j, link in sa.links.items():
            other = sb.links[j]
            assert (link.from_id, link.to_id, link.type) == (other.from_id, other.to_id, other.type)
            np.testing.assert_array_equal(link.transform, other.transform)
            np.testing.assert_array_equal(link.information, other.information)
    np.testing.assert_array_equal(a.vocabulary.descriptors(), b.vocabulary.descriptors())
    np.testing.assert_array_equal(a.vocabulary.active_mask(), b.vocabulary.active_mask())
    assert a.vocabulary.kind == b.vocabulary.kind
    for word in range(len(a.vocabulary)):
        assert a.vocabulary.references(word) == b.vocabulary.references(word)


def test_round_trip_is_exact(tmp_path: Path) -> None:
    rng = np.random.default_rng(30)
    detector, _ = first_session(rng)
    memory = detector.memory
    assert memory.ltm, "the WM size limit should have moved locations to LTM"
    assert any(link.type == LinkType.LOOP for s in memory.signatures.values() for link in s.links.values())
    path = tmp_path / "map.db"
    with MapDatabase(path) as db:
        memory.save(db)
    with MapDatabase(path) as db:
        loaded = Memory.load(db, new_session=False, stm_size=memory.stm_size)
    assert_same_memory(memory, loaded)
    assert loaded.stm == memory.stm
    assert loaded.wm_ids() == memory.wm_ids()
    assert loaded.ltm == memory.ltm
    assert loaded.last_id == memory.last_id
    # Saving again over the same file replaces rows instead of duplicating them.
    with MapDatabase(path) as db:
        loaded.save(db)
    with MapDatabase(path) as db:
        assert_same_memory(memory, Memory.load(db, new_session=False))


def test_multi_session_continues_and_relocalises(tmp_path: Path) -> None:
    rng = np.random.default_rng(31)
    detector, places = first_session(rng)
    path = tmp_path / "map.db"
    with MapDatabase(path) as db:
        detector.memory.save(db)
    n_first = len(detector.memory.signatures)

    with MapDatabase(path) as db:
        memory = Memory.load(db, new_session=True)
    assert memory.map_id == 1
    assert not memory.stm and memory.last_id is None
    second = make_loop_closure_detector(LoopClosureConfig(), MemoryConfig(), CAMERA_MATRIX, existing_memory=memory)
    # The new session starts elsewhere, then drives through places of the first session still in WM.
    fresh = make_place(rng, place_pose(60))
    hyp = feed(second, rng, fresh, fresh.pose, 1000.0)
    assert hyp.query_id == n_first + 1 and not hyp.accepted
    assert not memory.signatures[hyp.query_id].links, "a new session is not linked to the old map"
    in_wm = [k for k in range(20) if (k + 1) in memory.wm and (k + 2) in memory.wm]
    assert in_wm, "some consecutive locations of the first session should be in WM"
    accepted = []
    for k in (in_wm[0], in_wm[0] + 1):
        h = feed(second, rng, places[k], revisit_pose(places[k]), 1001.0 + k)
        if h.accepted:
            accepted.append(h)
            assert h.match_id == k + 1
            assert memory.signatures[h.match_id].links[h.query_id].type == LinkType.INTER_SESSION
    assert accepted
    with MapDatabase(path) as db:
        memory.save(db)
    with MapDatabase(path) as db:
        reloaded = Memory.load(db, new_session=True)
    assert reloaded.map_id == 2
    assert {s.map_id for s in reloaded.signatures.values()} == {0, 1}
    assert len(reloaded.signatures) == len(memory.signatures)


def test_descriptor_kind_mismatch_and_corrupt_file_are_errors(tmp_path: Path) -> None:
    rng = np.random.default_rng(32)
    detector, _ = first_session(rng)
    path = tmp_path / "map.db"
    with MapDatabase(path) as db:
        detector.memory.save(db)
        memory = Memory.load(db)
    with pytest.raises(SlamError, match="descriptor_kind"):
        make_loop_closure_detector(
            LoopClosureConfig(descriptor_kind="float"), MemoryConfig(), CAMERA_MATRIX, existing_memory=memory
        )
    bad = tmp_path / "bad.db"
    bad.write_bytes(b"this is not a database" * 100)
    with pytest.raises(SlamError, match=r"bad\.db"):
        MapDatabase(bad)
    old = tmp_path / "old.db"
    with sqlite3.connect(old) as connection:
        connection.execute("CREATE TABLE info (key TEXT PRIMARY KEY, value TEXT NOT NULL)")
        connection.execute("INSERT INTO info VALUES ('version', '0')")
    with pytest.raises(SlamError, match="version"):
        MapDatabase(old)
