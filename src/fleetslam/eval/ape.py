"""Absolute and relative pose error via evo, with the TUM benchmark tools' conventions.

Conventions: poses are associated by timestamp within ``max_diff`` (0.02 s, like ``associate.py``);
the estimate is aligned to the ground truth with Umeyama/Horn SE(3) (``align=True``, no scale unless
``scale=True``), as ``evaluate_ate.py`` does; APE is the translational error in metres; RPE is the
translational error of relative motions over ``delta`` frames or metres.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from fleetslam._imports import require
from fleetslam.errors import DatasetError
from fleetslam.trajectory import Trajectory


def _evo() -> Any:
    require("evo.core.geometry", "eval")
    require("evo.core.metrics", "eval")
    require("evo.core.sync", "eval")
    require("evo.core.trajectory", "eval")
    return require("evo", "eval")


@dataclass
class ErrorStats:
    """Statistics of one metric, in metres."""

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    pairs: int
    """Associated pose pairs (APE) or relative pairs (RPE)."""
    conventions: str
    """How the figures were computed."""

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


ApeResult = ErrorStats
RpeResult = ErrorStats


def _to_evo(trajectory: Trajectory) -> Any:
    evo = _evo()
    return evo.core.trajectory.PoseTrajectory3D(poses_se3=list(trajectory.poses), timestamps=trajectory.stamps)


def _associate(gt: Trajectory, est: Trajectory, max_diff: float) -> tuple[Any, Any]:
    evo = _evo()
    try:
        ref, est_evo = evo.core.sync.associate_trajectories(_to_evo(gt), _to_evo(est), max_diff=max_diff)
    except evo.core.sync.SyncException as err:
        raise DatasetError(f"trajectories cannot be associated within {max_diff} s: {err}") from err
    return ref, est_evo


def _stats(metric: Any, pairs: int, conventions: str) -> ErrorStats:
    s = metric.get_all_statistics()
    return ErrorStats(
        float(s["rmse"]),
        float(s["mean"]),
        float(s["median"]),
        float(s["std"]),
        float(s["min"]),
        float(s["max"]),
        pairs,
        conventions,
    )


def ape(
    gt: Trajectory, est: Trajectory, *, align: bool = True, scale: bool = False, max_diff: float = 0.02
) -> ApeResult:
    """Absolute trajectory error (translation, metres) of ``est`` against ``gt``."""
    evo = _evo()
    ref, est_evo = _associate(gt, est, max_diff)
    if align or scale:
        try:
            est_evo.align(ref, correct_scale=scale, correct_only_scale=scale and not align)
        except evo.core.geometry.GeometryException as err:
            raise DatasetError(f"trajectories cannot be aligned (degenerate, e.g. a straight line): {err}") from err
    metric = evo.core.metrics.APE(evo.core.metrics.PoseRelation.translation_part)
    metric.process_data((ref, est_evo))
    conv = (
        f"APE translation [m]; timestamps associated within {max_diff} s; "
        f"alignment: {'Umeyama SE(3)' if align else 'none'}{' + scale (Sim(3))' if scale else ''}"
    )
    return _stats(metric, ref.num_poses, conv)


def fleet_ape(
    pairs: Mapping[str, tuple[Trajectory, Trajectory]], *, max_diff: float = 0.02
) -> tuple[ApeResult, NDArray[np.float64]]:
    """Absolute trajectory error of several robots' estimates, all in one (fleet) frame, against their ground truths
    in one (world) frame, with one SE(3) alignment over all of them (COVINS' convention: each robot's poses associated
    with its own ground truth, then concatenated and aligned once, so a robot misplaced in the fleet frame counts).

    ``pairs``: robot → (ground truth, estimate). Returns the statistics and ``T_world_fleet`` (the alignment)."""
    evo = _evo()
    if not pairs:
        raise DatasetError("fleet APE needs at least one robot's trajectory")
    refs, ests = [], []
    for robot, (gt, est) in pairs.items():
        try:
            ref, est_evo = _associate(gt, est, max_diff)
        except DatasetError as err:
            raise DatasetError(f"{robot}: {err}") from err
        refs += list(ref.poses_se3)
        ests += list(est_evo.poses_se3)
    ref_path = evo.core.trajectory.PosePath3D(poses_se3=refs)
    est_path = evo.core.trajectory.PosePath3D(poses_se3=ests)
    try:
        rotation, translation, _ = est_path.align(ref_path)
    except evo.core.geometry.GeometryException as err:
        raise DatasetError(f"trajectories cannot be aligned (degenerate, e.g. a straight line): {err}") from err
    metric = evo.core.metrics.APE(evo.core.metrics.PoseRelation.translation_part)
    metric.process_data((ref_path, est_path))
    conv = (
        f"APE translation [m] over {len(pairs)} robots' concatenated trajectories; timestamps associated within "
        f"{max_diff} s per robot; alignment: one Umeyama SE(3) for all"
    )
    alignment = np.eye(4)
    alignment[:3, :3], alignment[:3, 3] = rotation, translation
    return _stats(metric, len(refs), conv), alignment


def rpe(
    gt: Trajectory,
    est: Trajectory,
    *,
    delta: float = 1.0,
    delta_unit: Literal["f", "m"] = "f",
    max_diff: float = 0.02,
    all_pairs: bool = False,
) -> RpeResult:
    """Relative pose error (translation, metres) over ``delta`` frames (``f``) or metres (``m``)."""
    evo = _evo()
    ref, est_evo = _associate(gt, est, max_diff)
    unit = evo.core.metrics.Unit.frames if delta_unit == "f" else evo.core.metrics.Unit.meters
    metric = evo.core.metrics.RPE(
        evo.core.metrics.PoseRelation.translation_part, delta=delta, delta_unit=unit, all_pairs=all_pairs
    )
    try:
        metric.process_data((ref, est_evo))
    except evo.core.metrics.MetricsException as err:
        raise DatasetError(f"RPE with delta {delta} {delta_unit}: {err}") from err
    conv = (
        f"RPE translation [m] over {delta} {'frames' if delta_unit == 'f' else 'm'}; timestamps associated "
        f"within {max_diff} s; no alignment (relative)"
    )
    return _stats(metric, len(metric.error), conv)


def plot_ape(
    gt: Trajectory,
    est: Trajectory,
    path: str,
    *,
    align: bool = True,
    scale: bool = False,
    max_diff: float = 0.02,
    others: dict[str, Trajectory] | None = None,
    title: str = "",
) -> None:
    """PNG of the trajectories after association and alignment: top view (x-y) and the error over time.

    ``others`` adds more estimates by label (e.g. odometry only, a peer system), each aligned on its own.
    """
    require("matplotlib", "eval").use("Agg")
    plt = require("matplotlib.pyplot", "eval")
    fig, (top, errors) = plt.subplots(1, 2, figsize=(12, 5.5))
    drawn_truth = False
    styles = ["b-", "r-", "g-", "m-", "c-"]
    for k, (label, trajectory) in enumerate([("estimate", est), *(others or {}).items()]):
        ref, est_evo = _associate(gt, trajectory, max_diff)
        if align or scale:
            est_evo.align(ref, correct_scale=scale)
        if not drawn_truth:
            top.plot(ref.positions_xyz[:, 0], ref.positions_xyz[:, 1], "k--", label="ground truth")
            drawn_truth = True
        distances = np.linalg.norm(ref.positions_xyz - est_evo.positions_xyz, axis=1)
        rmse_cm = np.sqrt(np.mean(distances**2)) * 100
        style = styles[k % len(styles)]
        top.plot(
            est_evo.positions_xyz[:, 0], est_evo.positions_xyz[:, 1], style, lw=1, label=f"{label} ({rmse_cm:.2f} cm)"
        )
        errors.plot(ref.timestamps - ref.timestamps[0], distances * 100, style, lw=1, label=label)
    top.set_title(title or "APE (RMSE after alignment)")
    top.set_xlabel("x [m]")
    top.set_ylabel("y [m]")
    top.axis("equal")
    top.legend(fontsize=8)
    errors.set_xlabel("time [s]")
    errors.set_ylabel("position error [cm]")
    errors.set_title("error after alignment")
    errors.grid(alpha=0.3)
    errors.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
