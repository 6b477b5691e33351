"""One SLAM agent of ``test_collab_link_cut.py``, run inside its host's network namespace: a camera driving back and
forth along a route in the textured room (rendered frames, as ``test_collaborative_slam.py`` feeds them) and the
SLAM node, collaborating with one peer through the router on the other host. The camera and SLAM share one session,
so the agent keeps mapping while its link is down.

Prints one JSON line per half second (``"status"``: counts) and, after ``park`` (the camera stands still, so the
last keyframes reach the graph) and ``report`` on stdin, the full state (``"report"``): its
keyframe ids with the wall time each was made, its mirror of the peer's graph, the peer's keyframes whose
summaries arrived and those that came by catch-up, its placement in the fleet frame and its map frame in the world.
``stop`` ends it. Its stdout is a pipe, so the test still reads it while the link is down.

Usage: ``python -m tests.integration.collab_link_cut_agent AGENT PEER`` (the repository root on ``PYTHONPATH``).
"""

from __future__ import annotations

import json
import sys
import threading
import time
from collections.abc import Iterator

import numpy as np
from tests.drivers.test_node import BASE_CAMERA
from tests.integration.test_collaborative_slam import drive
from tests.slam.textured_room import make_textures, render

from fleetslam.datasets.base import Intrinsics, RGBDFrame
from fleetslam.drivers.node import CameraNode
from fleetslam.geometry import invert
from fleetslam.middleware import Context, Node
from fleetslam.slam.config import SlamConfig
from fleetslam.slam.node import SlamNode, SlamNodeConfig
from fleetslam.slam.pipeline import SlamPipeline

INTRINSICS = Intrinsics(262.5, 262.5, 159.5, 119.5, 320, 240)
ROUTES = {"c3po": (-1.6, 0.8, 0.0), "r2d2": (0.9, -1.5, 0.25)}
"""Each agent drives from (x0, y) x1 - x0 metres along its heading and back, its camera looking into the room's far
corner (two walls: a peer's view of one plane is not believed): the two routes overlap, as in
``test_collaborative_slam.py`` (whose ``drive`` makes the poses)."""
VIEWS = 25
RATE_HZ = 5.0


def route(agent: str) -> list[np.ndarray]:
    x0, x1, y = ROUTES[agent]
    return drive(x0, x1, y, VIEWS)


class BackAndForthCamera:
    """Rendered views along the route, there and back again until :meth:`close`; after ``park`` it repeats the
    view it is at (standing still). Frame ``i`` waits (up to 10 s) until SLAM processed frame ``i - 2``."""

    name = "back_and_forth"

    def __init__(self, views: list[tuple[np.ndarray, np.ndarray]], slam: SlamNode) -> None:
        self.intrinsics = INTRINSICS
        self.views = views
        self.slam = slam
        self.parked = threading.Event()
        self.closed = threading.Event()
        self.truth_index: dict[int, int] = {}
        """Frame stamp (ns) -> view index."""

    def __iter__(self) -> Iterator[RGBDFrame]:
        cycle = list(range(len(self.views))) + list(range(len(self.views) - 2, 0, -1))
        i, view = 0, 0
        while not self.closed.is_set():
            view = view if self.parked.is_set() else cycle[i % len(cycle)]
            deadline = time.monotonic() + 10.0
            while self.slam.frames < i - 1 and time.monotonic() < deadline and not self.closed.is_set():
                time.sleep(0.01)
            stamp = 5000.0 + i / RATE_HZ
            self.truth_index[round(stamp * 1e9)] = view
            yield RGBDFrame(i, stamp, *self.views[view])
            i += 1
            time.sleep(1.0 / RATE_HZ)

    def close(self) -> None:
        self.closed.set()


def main() -> None:
    agent, peer = sys.argv[1], sys.argv[2]
    truth = route(agent)
    textures = make_textures(np.random.default_rng(5))
    views = [render(pose, INTRINSICS, textures) for pose in truth]
    warm = SlamPipeline(SlamConfig(), intrinsics=INTRINSICS)  # compile the kernels before the node runs
    for k in range(3):
        warm.step(RGBDFrame(k, float(k), *views[k]))
    made: dict[int, float] = {}
    """Own keyframe id -> wall time (s) it was first seen."""
    with Context() as ctx:
        slam = SlamNode(Node("slam", context=ctx), SlamNodeConfig(peers=[peer], use_wheel_odometry=False))
        driver = BackAndForthCamera(views, slam)
        camera = CameraNode(Node("camera", context=ctx), driver, base_camera=BASE_CAMERA)
        camera.start()
        commands: list[str] = []
        threading.Thread(target=lambda: commands.extend(line.strip() for line in sys.stdin), daemon=True).start()
        print(json.dumps({"ready": True}), flush=True)
        while True:
            pipeline = slam.pipeline
            stamps = dict(pipeline.keyframe_stamps) if pipeline is not None else {}
            now = time.time()
            for keyframe_id in stamps:
                made.setdefault(int(keyframe_id), now)
            state = slam.linker.peer(peer)
            mirror = set(state.mirror.poses)
            status = {
                "status": agent, "t": now, "frames": slam.frames, "keyframes": len(stamps),
                "sent": slam.graph_writer.sent_keyframes,
                "mirror": len(mirror), "synced": state.mirror.synced,
                "missing": len(mirror - state.catch_up.received), "caught_up": len(state.catch_up.caught_up),
                "placed": slam.fleet_transform is not None, "queued": len(slam.linker.queue),
                "store": len(slam.summary_store), "store_bytes": slam.summary_store.nbytes, **slam.counts,
            }  # fmt: skip
            print(json.dumps(status), flush=True)
            if "park" in commands:
                driver.parked.set()
            if "report" in commands:
                commands.remove("report")
                assert pipeline is not None
                with slam._lock:
                    poses = pipeline.keyframe_poses()
                    keyframe_stamps = dict(pipeline.keyframe_stamps)
                first = min(keyframe_stamps)
                view = driver.truth_index[round(keyframe_stamps[first] * 1e9)]
                world_from_map = truth[view] @ invert(poses[first])
                report = {
                    "report": agent, "made": {str(k): t for k, t in made.items()},
                    "sent": sorted(int(i) for i in slam.graph_writer._sent_poses),
                    "mirror": sorted(int(i) for i in mirror), "received": sorted(state.catch_up.received),
                    "caught_up": sorted(state.catch_up.caught_up), "unavailable": sorted(state.catch_up.unavailable),
                    "world_from_map": world_from_map.tolist(),
                    "fleet_transform": None if slam.fleet_transform is None else slam.fleet_transform.tolist(),
                    "store": len(slam.summary_store), "store_bytes": slam.summary_store.nbytes,
                    "counts": slam.counts, "restarts": state.restarts,
                }  # fmt: skip
                print(json.dumps(report), flush=True)
            if "stop" in commands:
                break
            time.sleep(0.5)
        camera.close()


if __name__ == "__main__":
    main()
