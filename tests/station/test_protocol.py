import numpy as np

from fleetslam.station.protocol import TeleopGate, TeleopLimits, VoxelDiff, yaw_from_quaternion


def test_voxel_diff_sends_only_changes() -> None:
    diff = VoxelDiff(0.1)
    first = np.array([[0.05, 0.05, 0.05], [0.15, 0.05, 0.05]])
    added, removed = diff.update(first)
    assert len(added) == 2 and len(removed) == 0
    added, removed = diff.update(first + 1e-4)  # float noise inside the same voxels: nothing to send
    assert len(added) == 0 and len(removed) == 0
    added, removed = diff.update(np.array([[0.15, 0.05, 0.05], [0.25, 0.05, 0.05]]))
    np.testing.assert_allclose(added, [[0.25, 0.05, 0.05]])
    np.testing.assert_allclose(removed, [[0.05, 0.05, 0.05]])
    assert len(diff) == 2 and len(diff.snapshot()) == 2


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
