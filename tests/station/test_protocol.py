import numpy as np

from fleetslam.station.protocol import (
    TeleopGate,
    TeleopLimits,
    VoxelDiff,
    VoxelUpdate,
    decode_voxels,
    pack_keys,
    unpack_keys,
    yaw_from_quaternion,
)


def test_voxel_diff_sends_only_changes() -> None:
    diff = VoxelDiff(0.1)
    first = np.array([[0.05, 0.05, 0.05], [0.15, 0.05, 0.05]])
    added, removed = diff.update(first)
    assert len(added) == 2 and len(removed) == 0
    added, removed = diff.update(first + 1e-4)  # float noise inside the same voxels: nothing to send
    assert len(added) == 0 and len(removed) == 0
    added, removed = diff.update(np.array([[0.15, 0.05, 0.05], [0.25, 0.05, 0.05]]))
    np.testing.assert_allclose(diff.centres(added), [[0.25, 0.05, 0.05]])
    np.testing.assert_allclose(diff.centres(removed), [[0.05, 0.05, 0.05]])
    assert len(diff) == 2 and len(diff.keys()) == 2


def test_voxel_keys_round_trip_negative_and_far_indices() -> None:
    indices = np.array([[0, 0, 0], [-1, 2, -3], [(1 << 20) - 1, -(1 << 20), 7], [-400, 12345, -99999]])
    np.testing.assert_array_equal(unpack_keys(pack_keys(indices)), indices)
    diff = VoxelDiff(0.05)
    points = np.array([[-0.01, -0.01, -0.01], [-0.051, 0.049, 0.0], [12.3, -4.56, 0.78]])
    centres = diff.centres(diff.update(points)[0])  # in key order
    expected = [[-0.025, -0.025, -0.025], [-0.075, 0.025, 0.025], [12.325, -4.575, 0.775]]
    assert sorted(map(tuple, np.round(centres, 6).tolist())) == sorted(map(tuple, expected))


def test_merged_voxel_updates_bring_a_busy_browser_to_the_same_map() -> None:
    """Deltas merged while a browser was busy, applied at once, give the map the deltas one by one give."""
    rng = np.random.default_rng(3)
    diff = VoxelDiff(0.1)
    browser_one_by_one: set[tuple[int, ...]] = set()
    merged: VoxelUpdate | None = None
    for _ in range(30):
        cloud = rng.integers(-20, 20, size=(rng.integers(0, 300), 3)) * 0.1 + 0.05
        added, removed = diff.update(cloud)
        update = VoxelUpdate("c3po", 0.1, added, removed, len(diff))
        header, add, remove = decode_voxels(update.encode())
        assert header["type"] == "voxels" and header["total"] == len(diff) and not header["reset"]
        assert not {tuple(r) for r in remove} - browser_one_by_one  # only what the browser has is removed
        browser_one_by_one -= {tuple(r) for r in remove}
        browser_one_by_one |= {tuple(a) for a in add}
        if merged is None:
            merged = update
        else:
            merged.merge(update)
    assert merged is not None
    _, add, remove = decode_voxels(merged.encode())
    assert {tuple(a) for a in add} == browser_one_by_one and len(remove) == 0  # from nothing: adds only
    assert browser_one_by_one == {tuple(k) for k in unpack_keys(diff.keys())}


def test_teleop_gate_streams_only_with_deadman_and_stops_once() -> None:
    gate = TeleopGate(TeleopLimits(max_linear=0.5, max_angular=1.0, command_timeout_s=0.3))
    assert gate.tick(0.0) == {}
    gate.drive("c3po", 2.0, -5.0, True, now=0.0)
    assert gate.tick(0.05) == {"c3po": (0.5, -1.0)}  # clamped to the limits
    gate.drive("c3po", 0.2, 0.0, False, now=0.1)  # deadman released
    assert gate.tick(0.15) == {"c3po": (0.0, 0.0)}
    assert gate.tick(0.2) == {}
    gate.drive("c3po", 0.2, 0.1, True, now=1.0)
    assert gate.tick(1.1) == {"c3po": (0.2, 0.1)}
    assert gate.tick(1.5) == {"c3po": (0.0, 0.0)}  # the browser went silent
    gate.drive("c3po", 0.2, 0.1, True, now=2.0)
    assert gate.tick(2.0) == {"c3po": (0.2, 0.1)}
    gate.release("c3po")  # the browser disconnected
    assert gate.tick(2.01) == {"c3po": (0.0, 0.0)}
    gate.drive("r2d2", float("nan"), 0.0, True, now=3.0)
    assert gate.tick(3.0)["r2d2"] == (0.0, 0.0)


def test_yaw() -> None:
    assert (
        yaw_from_quaternion(0, 0, np.sin(0.4), np.cos(0.4)) == np.float64(0.8)
        or abs(yaw_from_quaternion(0, 0, np.sin(0.4), np.cos(0.4)) - 0.8) < 1e-12  # float64 atan2 round-off
    )
