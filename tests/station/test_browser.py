"""The console in a real headless Chromium (Debian's), driven by Playwright: map, camera, deadman driving."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.station.protocol import VoxelDiff
from fleetslam.station.server import StationServer

from ..support import wait_until
from .conftest import RobotUnderTest, pointcloud2, save_screenshot


def test_console_in_chromium(
    browser_page,
    make_context: Callable[..., Context],
    test_robot: RobotUnderTest,
    tmp_path: Path,  # type: ignore[no-untyped-def]
) -> None:
    page, errors = browser_page
    with StationServer(make_context(), port=0) as server:
        page.goto(server.url)
        page.wait_for_function("window.fleetslam && window.fleetslam.voxelCount > 0", timeout=20000)
        first_frame = page.evaluate("window.fleetslam.lastFrameSeq")
        page.wait_for_function(f"window.fleetslam.lastFrameSeq > {first_frame}", timeout=10000)
        assert page.evaluate("window.fleetslam.selected") == "c3po"
        # The robot's whole block (20 × 10 × 3 voxels, sent growing as binary deltas) is drawn, voxel for voxel.
        page.wait_for_function("window.fleetslam.voxelCount === 600", timeout=20000)
        page.wait_for_function("document.getElementById('link-text').textContent.startsWith('link ok')", timeout=5000)
        # The test browser draws with SwiftShader (no GPU): the view must know it and spare the CPU.
        assert page.evaluate("window.fleetslam.softwareGL") is True
        # Hold the deadman (Space) and W: forward commands reach the robot.
        page.keyboard.down("Space")
        page.keyboard.down("w")
        assert wait_until(lambda: any(v > 0 for _, v, _ in test_robot.commands), 5.0)
        time.sleep(0.5)
        save_screenshot(page, tmp_path, "console-driving.png")
        page.keyboard.up("w")
        page.keyboard.up("Space")
        released = time.time()
        # The page sends the release on the key's release and the server publishes its zero at once (which may
        # land before `released` is read: −0.1 s); nothing moves after the 0.3 s command timeout plus a tick each side.
        assert wait_until(lambda: any(v == 0.0 and t >= released - 0.1 for t, v, _ in test_robot.commands), 2.0)
        time.sleep(0.6)
        assert not [c for c in test_robot.commands if c[0] > released + 0.5 and c[1] != 0.0]
        # Close the page while driving: the stream stops.
        page.keyboard.down("Space")
        page.keyboard.down("w")
        assert wait_until(lambda: any(v > 0 and t > released + 0.6 for t, v, _ in test_robot.commands), 5.0)
        page.close()
        closed = time.time()
        time.sleep(1.0)
        assert not [c for c in test_robot.commands if c[0] > closed + 0.5 and c[1] != 0.0]  # as after the release
    assert not errors, errors


# Releases the deadman and D, then keeps the page's main thread busy for 1.5 s (as software GL drawing can under
# load): no timer of the page runs meanwhile, so only the release itself can have sent the stop.
RELEASE_WHILE_BUSY = """() => {
  for (const key of [' ', 'd']) window.dispatchEvent(new KeyboardEvent('keyup', { key }));
  const start = performance.now();
  while (performance.now() - start < 1500) {}
}"""


def test_the_release_is_sent_at_once_while_the_page_is_busy(
    browser_page: Any, make_context: Callable[..., Context], test_robot: RobotUnderTest
) -> None:
    page, errors = browser_page
    with StationServer(make_context(), port=0, teleop_rate_hz=0.25) as server:  # the server ticks every 4 s
        page.goto(server.url)
        page.wait_for_function("window.fleetslam && window.fleetslam.selected === 'c3po'", timeout=20000)
        page.keyboard.down("Space")
        page.keyboard.down("d")
        start = time.time()
        assert wait_until(lambda: any(w < 0 and t >= start for t, _, w in test_robot.commands), 10.0)
        released = time.time()  # a few ms after a tick of the server: its next is ~4 s away
        page.evaluate(RELEASE_WHILE_BUSY)
        busy_until = time.time()
        zeros = [t for t, v, w in test_robot.commands if v == 0.0 and w == 0.0 and t >= released]
        assert zeros and zeros[0] < busy_until - 0.5, (released, busy_until, test_robot.commands[-3:])
    assert not errors, errors


def test_link_reads_lost_within_two_seconds_of_the_server_stopping(
    browser_page: Any, make_context: Callable[..., Context], test_robot: RobotUnderTest
) -> None:
    page, errors = browser_page
    server = StationServer(make_context(), port=0)
    with server:
        page.goto(server.url)
        page.wait_for_function("document.getElementById('link-text').textContent.startsWith('link ok')", timeout=20000)
    stopped = time.monotonic()
    page.wait_for_function("document.getElementById('link-text').textContent === 'link lost'", timeout=5000)
    assert time.monotonic() - stopped < 2.0
    assert not errors, errors


def test_the_page_draws_exactly_the_voxels_of_a_changing_map(
    browser_page: Any, make_context: Callable[..., Context]
) -> None:
    """Voxels arrive as deltas and are written into the point buffers slot by slot (a removed one's slot takes the
    last one, the buffers grow by doubling): after a map that grows, moves and shrinks, the page draws its voxels,
    no more and no fewer, at their centres."""
    page, errors = browser_page
    node = Node("mapper", context=make_context("c3po"))
    publisher = node.create_publisher("sensor_msgs/msg/PointCloud2", "map/occupied", QoSProfile(depth=1))
    rng = np.random.default_rng(5)

    def block(origin: tuple[int, int, int], n: tuple[int, int, int]) -> np.ndarray:
        grid = np.stack(np.meshgrid(*(np.arange(k) for k in n), indexing="ij"), -1).reshape(-1, 3) + origin
        return (grid * 0.05 + 0.025).astype(np.float64)

    clouds = [
        block((0, 0, 0), (10, 10, 3)),  # 300
        block((0, 0, 0), (40, 30, 3)),  # 3600: the buffers grow
        block((20, 5, 0), (40, 30, 2)),  # moved: most removed, most added
        block((25, 10, 1), (7, 9, 2))[rng.permutation(126)[:100]],  # shrunk to 100 scattered voxels
    ]
    try:
        with StationServer(make_context(), port=0) as server:
            page.goto(server.url)
            for cloud in clouds:
                expected = VoxelDiff(0.05)
                expected.update(cloud)
                want = _rows(expected.centres(expected.keys()))
                deadline = time.monotonic() + 20.0
                while True:
                    publisher.publish(pointcloud2(cloud))
                    time.sleep(0.5)
                    drawn = np.array(page.evaluate("window.fleetslam.voxelCentres('c3po')")).reshape(-1, 3)
                    drawn = _rows(drawn)
                    if (
                        drawn.shape == want.shape and np.allclose(drawn, want, atol=1e-4)
                    ) or time.monotonic() > deadline:
                        break
                assert drawn.shape == want.shape, (drawn.shape, want.shape)
                assert np.allclose(drawn, want, atol=1e-4)
                assert page.evaluate("window.fleetslam.voxelCount") == len(want)
    finally:
        node.destroy()
    assert not errors, errors


def _rows(points: np.ndarray) -> np.ndarray:
    """Points rounded to 0.1 mm, in row order (a set to compare)."""
    rounded = np.round(np.asarray(points, dtype=np.float64).reshape(-1, 3), 4)
    return rounded[np.lexsort(rounded.T[::-1])]
