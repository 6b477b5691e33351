"""Offline SLAM pipeline: iterate an RGB-D source, track, detect loops, optimise, time, write results.

The algorithms (odometry, loop-closure detector, pose graph) do no I/O; this module owns the loop and the
files: ``trajectory.txt`` (every frame, TUM), ``keyframes.txt`` (TUM), ``map.db``, ``config.yaml`` and
``stats.json``. Non-keyframe poses are expressed relative to their keyframe, so the final optimisation
moves them with it.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from fleetslam.config import dump_config
from fleetslam.datasets.base import RGBDFrame, RGBDSource
from fleetslam.geometry import invert
from fleetslam.slam.backend import Constraint, PoseGraph, information_from_std, make_pose_graph
from fleetslam.slam.config import SlamConfig
from fleetslam.slam.frontend import (
    FRONT_ENDS,
    KeyframeObservation,
    OdometryFactory,
    OdometryFrontEnd,
    OdometryResult,
    make_odometry,
)
from fleetslam.slam.odometry import wheel_motion_std
from fleetslam.trajectory import Trajectory, write_tum

if TYPE_CHECKING:
    from fleetslam.slam.loop_closure import LoopClosureDetector
    from fleetslam.slam.peer_recognition import ClosureQuality, PeerPlaceRecognizer

logger = logging.getLogger(__name__)


@dataclass
class SlamResult:
    """What a run produced."""

    trajectory: Trajectory
    """Camera pose of every frame after the final optimisation."""
    keyframes: Trajectory
    odometry: Trajectory
    """Raw odometry poses (before the back-end)."""
    loops_accepted: list[tuple[int, int]] = field(default_factory=list)
    loops_rejected: list[tuple[int, int]] = field(default_factory=list)
    frame_ms: list[float] = field(default_factory=list)
    """Tracking time per frame (the odometry up to the frame's pose; local mapping and the graph not included,
    as they run after the pose is out: see ``stats["frames"]``' ``local_mapping_ms`` and ``keyframe_ms``)."""
    stats: dict[str, Any] = field(default_factory=dict)


@dataclass
class TrackedFrame:
    """A frame between :meth:`SlamPipeline.track` and :meth:`SlamPipeline.finish`."""

    stamp: float
    odometry: OdometryResult
    record: dict[str, Any]
    """The frame's entry in the run's statistics (``SlamResult.stats["frames"]``)."""
    relocalized: int | None
    """The location it was relocalised on, if any."""
    pose: NDArray[np.float64]
    """``T_map_camera`` from the odometry and the graph as they stood: before local mapping and loop closure."""


@dataclass
class StepResult:
    """What one frame produced."""

    pose: NDArray[np.float64]
    """Camera pose T_map_camera after the graph's latest optimisation."""
    odometry: OdometryResult
    """The odometry result (pose in the odometry frame, features of keyframes)."""
    keyframe_id: int | None
    """Graph node id when this frame became a keyframe."""
    loop_closed: bool
    """A loop closure was accepted on this frame (keyframe poses moved)."""
    relocalized: bool = False
    """Tracking was lost and this frame was put back on the map by verification against a keyframe."""


class SlamPipeline:
    """Odometry + loop closure + pose graph over a frame stream (pure; :func:`run_offline` writes files)."""

    def __init__(
        self,
        config: SlamConfig,
        source: RGBDSource | None = None,
        *,
        intrinsics: Any = None,
        base_camera: NDArray[np.float64] | None = None,
        front_ends: Mapping[str, OdometryFactory] = FRONT_ENDS,
    ) -> None:
        """``source`` for offline runs; a live node passes only the camera ``intrinsics`` and calls :meth:`step`.
        ``base_camera`` (T_base_camera; default: the source's, if it knows it) enables planar motion.
        ``front_ends``: the registry ``config.odometry.kind`` is looked up in (a new front-end is added there)."""
        if source is None and intrinsics is None:
            raise ValueError("SlamPipeline needs a source or the camera intrinsics")
        self.config = config
        self.source = source
        self.intrinsics = intrinsics if intrinsics is not None else source.intrinsics  # type: ignore[union-attr]
        if base_camera is None and source is not None:
            base_camera = getattr(source, "base_camera", None)
        self.odometry: OdometryFrontEnd = make_odometry(
            config.odometry, config.features, self.intrinsics, base_camera, front_ends=front_ends
        )
        self.graph: PoseGraph = make_pose_graph(config.backend)
        b = config.backend
        self.odometry_information = information_from_std(
            b.odometry_translation_std, np.radians(b.odometry_rotation_std_deg)
        )
        self.loop_information = information_from_std(b.loop_translation_std, np.radians(b.loop_rotation_std_deg))
        self._detector: LoopClosureDetector | None = None
        self._next_id = 1
        if config.loop_closure_enabled and not self.odometry.provides_features:
            logger.info("odometry.kind = %r gives no features: loop closure is off", config.odometry.kind)
        elif config.loop_closure_enabled:
            from fleetslam.slam.loop_closure import make_loop_closure_detector

            self._detector = make_loop_closure_detector(config.loop_closure, config.memory, self.intrinsics.K)
        self._stamps: list[float] = []
        self._odom_poses: list[NDArray[np.float64]] = []
        self._frame_keyframe: list[int] = []
        self.keyframe_odometry: dict[int, NDArray[np.float64]] = {}
        """Odometry pose of every keyframe (graph node id → T_world_camera before optimisation)."""
        self.keyframe_stamps: dict[int, float] = {}
        self._accepted: list[tuple[int, int]] = []
        self._rejected: list[tuple[int, int]] = []
        self._per_frame: list[dict[str, Any]] = []
        self._last_kf: int | None = None
        self.set_mounting(base_camera)

    def set_mounting(self, base_camera: NDArray[np.float64] | None) -> None:
        """The camera's mounting on a ground robot (T_base_camera): with ``odometry.planar_motion`` the odometry,
        loop closures and relocalisation then solve for the base's x, y and yaw only."""
        self.odometry.base_camera = base_camera
        if self._detector is not None:
            planar = self.config.odometry.planar_motion and base_camera is not None
            self._detector.set_planar_mounting(base_camera if planar else None)

    @property
    def loop_closure(self) -> bool:
        """Loop closure runs (configured on, and the front-end gives features)."""
        return self._detector is not None

    def save_map(self, path: str | Path) -> bool:
        """Write the loop-closure memory (locations, links, vocabulary) to ``path`` (a map.db, replaced if it
        exists; ``Memory.load`` reads it); False without loop closure."""
        if self._detector is None:
            return False
        from fleetslam.slam.database import MapDatabase

        path = Path(path)
        if path.exists():
            path.unlink()
        with MapDatabase(path) as db:
            self._detector.save(db)
        return True

    def bag_of_words(self, keyframe_id: int) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """Visual word ids and TF-IDF weights of a keyframe's location (empty without loop closure)."""
        if self._detector is None:
            return np.zeros(0, np.int64), np.zeros(0, np.float64)
        return self._detector.bag_of_words(keyframe_id)

    def peer_recognizer(
        self, *, max_verifications: int = 2, min_off_plane: int | None = None, quality: ClosureQuality | None = None
    ) -> PeerPlaceRecognizer | None:
        """A recognizer of other agents' keyframes in this pipeline's memory, verifying as its own loop closure does
        (None without loop closure); ``min_off_plane`` and ``quality``: see :func:`make_peer_recognizer` (None: their
        defaults; the quality's depth noise is this pipeline's ``odometry.depth_noise``). Call it, and use it, from
        the thread that steps the pipeline."""
        if self._detector is None:
            return None
        from fleetslam.slam.peer_recognition import MIN_OFF_PLANE_INLIERS, ClosureQuality, make_peer_recognizer

        quality = replace(quality or ClosureQuality(), depth_noise=self.config.odometry.depth_noise)
        return make_peer_recognizer(
            self.config.loop_closure, self._detector.memory, self.intrinsics.K, max_verifications=max_verifications,
            min_off_plane=MIN_OFF_PLANE_INLIERS if min_off_plane is None else min_off_plane, quality=quality,
        )  # fmt: skip

    def constraints(self) -> list[Constraint]:
        """Every odometry and loop constraint of the pose graph."""
        return self.graph.constraints()

    @property
    def loops_retracted(self) -> int:
        """Loop closures the back-end took back after optimisation (their error was too large)."""
        return len(self.graph.retracted)

    def step(self, frame: RGBDFrame) -> StepResult:
        """Process one frame: track it, and on a keyframe add it to the graph and look for a loop."""
        return self.finish(self.track(frame))

    def track(self, frame: RGBDFrame) -> TrackedFrame:
        """The frame's pose, as soon as the odometry has it (what a live node publishes); :meth:`finish` must
        follow before the next frame."""
        t0, cpu0 = time.perf_counter(), time.thread_time()
        result = self.odometry.track(frame.rgb, frame.depth, frame.stamp, frame.prior)
        t_odom, cpu_odom = (time.perf_counter() - t0) * 1e3, (time.thread_time() - cpu0) * 1e3
        relocalized = None
        if result.lost and self._detector is not None and self.config.relocalization_candidates > 0:
            relocalized = self._relocalize(frame.stamp, result)
        record: dict[str, Any] = {
            "index": frame.index,
            "stamp": frame.stamp,
            "odometry_ms": round(t_odom, 3),
            # This thread's CPU time: the cost on one core, whatever else the machine runs meanwhile.
            "odometry_cpu_ms": round(cpu_odom, 3),
            "inliers": result.inliers,
            "keyframe": result.is_keyframe,
            "lost": result.lost,
            "coasting": result.coasting,
        }
        if relocalized is not None:
            record["relocalized_on"] = relocalized
        pose = result.pose
        if self._last_kf is not None:
            anchor = self.graph.optimize()[self._last_kf]
            pose = anchor @ invert(self.keyframe_odometry[self._last_kf]) @ result.pose
        return TrackedFrame(frame.stamp, result, record, relocalized, pose)

    def finish(self, tracked: TrackedFrame) -> StepResult:
        """Local mapping (the odometry window's adjustment) and, on a keyframe, the graph and loop closure."""
        result, record = tracked.odometry, tracked.record
        t0 = time.perf_counter()
        adjusted = self.odometry.local_mapping()
        if adjusted is not None:
            result.pose = adjusted
            record["local_mapping_ms"] = round((time.perf_counter() - t0) * 1e3, 3)
        new_keyframe = None
        loops_before = len(self._accepted)
        if result.is_keyframe or self._last_kf is None:
            t1 = time.perf_counter()
            self._last_kf = self._add_keyframe(
                tracked.stamp, result, self._last_kf, self.keyframe_odometry, self._accepted, self._rejected, record
            )
            new_keyframe = self._last_kf
            self.keyframe_stamps[self._last_kf] = tracked.stamp
            record["keyframe_ms"] = round((time.perf_counter() - t1) * 1e3, 3)
        self._stamps.append(tracked.stamp)
        self._odom_poses.append(result.pose)
        self._frame_keyframe.append(self._last_kf)
        self._per_frame.append(record)
        keyframe_pose = self.graph.optimize()[self._last_kf]
        pose = keyframe_pose @ invert(self.keyframe_odometry[self._last_kf]) @ result.pose
        return StepResult(
            pose=pose,
            odometry=result,
            keyframe_id=new_keyframe,
            loop_closed=len(self._accepted) > loops_before,
            relocalized=tracked.relocalized is not None,
        )

    def _relocalize(self, stamp: float, result: OdometryResult) -> int | None:
        """Verify a lost frame against the most recent locations in memory (PnP, as a loop closure) and,
        on success, put the odometry back on the map there. Returns the location relocalised on, or None."""
        assert self._detector is not None
        if len(result.points3d) < self.config.loop_closure.min_inliers:
            return None
        candidates = [i for i in self._detector.locations() if i in self.keyframe_odometry]
        found = self._detector.relocalize(
            KeyframeObservation(stamp, result.pose, result.features()),
            candidates[: self.config.relocalization_candidates],
        )
        if found is None:
            return None
        location, verification = found
        assert verification.transform is not None
        self.odometry.relocalize(result, self.keyframe_odometry[location] @ verification.transform)
        logger.info("relocalised on location %d (%d inliers)", location, verification.inliers)
        return location

    def keyframe_poses(self) -> dict[int, NDArray[np.float64]]:
        """Current (optimised) pose of every keyframe."""
        return dict(self.graph.optimize())

    def result(self) -> SlamResult:
        """Final optimisation and the trajectory of every frame processed so far."""
        optimized = self.graph.optimize_full() if self._accepted else self.graph.optimize()
        kf_odom = self.keyframe_odometry
        poses = [
            optimized[k] @ invert(kf_odom[k]) @ p for k, p in zip(self._frame_keyframe, self._odom_poses, strict=True)
        ]
        kf_ids = sorted(kf_odom)
        stats = {
            "frames": self._per_frame,
            "loops_accepted": self._accepted,
            "loops_rejected": self._rejected,
            "keyframes": len(kf_ids),
        }
        return SlamResult(
            trajectory=Trajectory.from_lists(self._stamps, poses),
            keyframes=Trajectory.from_lists([self.keyframe_stamps[k] for k in kf_ids], [optimized[k] for k in kf_ids]),
            odometry=Trajectory.from_lists(self._stamps, self._odom_poses),
            loops_accepted=list(self._accepted),
            loops_rejected=list(self._rejected),
            frame_ms=[r["odometry_ms"] for r in self._per_frame],
            stats=stats,
        )

    def run(self, max_frames: int | None = None, progress: Callable[[int], None] | None = None) -> SlamResult:
        """Process every frame of the source (up to ``max_frames``) and return the final result."""
        if self.source is None:
            raise ValueError("run() needs a source; use step() for live frames")
        for frame in self.source:
            if max_frames is not None and frame.index >= max_frames:
                break
            self.step(frame)
            if progress is not None:
                progress(1)
        return self.result()

    def _add_keyframe(
        self,
        stamp: float,
        result: OdometryResult,
        last_kf: int | None,
        kf_odom: dict[int, NDArray[np.float64]],
        accepted: list[tuple[int, int]],
        rejected: list[tuple[int, int]],
        record: dict[str, Any],
    ) -> int:
        odometry_transform = None if last_kf is None else invert(kf_odom[last_kf]) @ result.pose
        hypothesis = None
        observation = KeyframeObservation(
            stamp,
            result.pose,
            result.features() if self.odometry.provides_features else None,
            odometry_transform=odometry_transform,
            odometry_information=self.odometry_information,
        )
        if self._detector is not None and observation.features is not None:
            hypothesis = self._detector.process(observation)
            node = int(hypothesis.query_id)
            record["memory"] = self._detector.memory_sizes()
            record["hypothesis"] = {
                "match": hypothesis.match_id,
                "probability": round(float(hypothesis.probability), 4),
                "inliers": int(hypothesis.inliers),
                "reason": hypothesis.reason,
            }
        else:
            node = self._next_id
            self._next_id += 1
        kf_odom[node] = result.pose.copy()
        if last_kf is None:
            self.graph.add_node(node, result.pose)
        else:
            assert odometry_transform is not None
            guess = self.graph.optimize()[last_kf] @ odometry_transform
            self.graph.add_node(node, guess)
            information = self._link_information(result, odometry_transform)
            self.graph.add_odometry(last_kf, node, odometry_transform, information)
        transform = hypothesis.transform if hypothesis is not None and hypothesis.accepted else None
        if transform is not None:
            transform = self.odometry.constrain(transform)
        if hypothesis is not None and transform is not None and hypothesis.match_id is not None:
            pair = (int(hypothesis.match_id), node)
            if self.graph.add_loop(pair[0], node, transform, self.loop_information):
                accepted.append(pair)
            else:
                rejected.append(pair)
            record["loop"] = {"match": pair[0], "accepted": pair in accepted}
        return node

    def _link_information(self, result: OdometryResult, transform: NDArray[np.float64]) -> NDArray[np.float64]:
        """How well the odometry knows a keyframe from the last one: as the visual odometry does, unless the map
        was restarted — after coasting, the wheels alone carried the pose there (their drift over that motion, as
        in the odometry's prediction); after losing track, nothing did (nearly free)."""
        if result.lost:
            return self.odometry_information * 0.01
        if not (result.coasting and result.map_restarted):
            return self.odometry_information
        backend = self.config.backend
        translation, rotation = wheel_motion_std(transform, self.config.odometry.wheel_drift)
        return information_from_std(
            float(np.hypot(backend.odometry_translation_std, translation)),
            float(np.hypot(np.radians(backend.odometry_rotation_std_deg), rotation)),
        )


def run_offline(
    source: RGBDSource,
    config: SlamConfig,
    out_dir: str | Path,
    *,
    max_frames: int | None = None,
    show_progress: bool = True,
    front_ends: Mapping[str, OdometryFactory] = FRONT_ENDS,
) -> SlamResult:
    """Run the pipeline over a source and write trajectory.txt, keyframes.txt, odometry.txt, map.db (with loop
    closure), config.yaml and stats.json; ``front_ends`` as :class:`SlamPipeline`'s."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.yaml").write_text(dump_config(config), encoding="utf-8")
    pipeline = SlamPipeline(config, source, front_ends=front_ends)
    total = len(source) if max_frames is None else min(len(source), max_frames)
    bar: Any = None
    if show_progress:
        try:
            from tqdm import tqdm

            bar = tqdm(total=total, unit="frame", desc=f"slam {source.name}")
        except ImportError:
            bar = None
    try:
        result = pipeline.run(max_frames, progress=bar.update if bar is not None else None)
    finally:
        if bar is not None:
            bar.close()
    write_tum(out / "trajectory.txt", result.trajectory)
    write_tum(out / "keyframes.txt", result.keyframes)
    write_tum(out / "odometry.txt", result.odometry)
    pipeline.save_map(out / "map.db")
    ms = np.asarray(result.frame_ms) if result.frame_ms else np.zeros(1)
    summary = {
        "dataset": source.name,
        "frames": len(result.trajectory),
        "keyframes": len(result.keyframes),
        "odometry_ms_median": float(np.median(ms)),
        "odometry_ms_p95": float(np.percentile(ms, 95)),
        "loops_accepted": len(result.loops_accepted),
        "loops_rejected": len(result.loops_rejected),
    }
    result.stats["summary"] = summary
    (out / "stats.json").write_text(json.dumps(result.stats, indent=1), encoding="utf-8")
    logger.info("slam: %s", summary)
    return result
