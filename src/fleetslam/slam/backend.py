"""Pose-graph back-end on GTSAM: odometry and loop constraints, iSAM2 increments, LM on loop closures.

Information matrices are 6×6 over ``(x, y, z, roll, pitch, yaw)`` like :class:`fleetslam.slam.signature.Link`
(translation first); GTSAM's Pose3 tangent is rotation first, so blocks are swapped here.

A new loop is added to iSAM2; if afterwards any constraint's translational error exceeds ``optimize_max_error``
times its expected standard deviation, the loop is rejected and removed (RTAB-Map's RGBD/OptimizeMaxError) —
unless the constraint over the bound is an earlier loop and the new one agrees with the graph: then the earlier
loop is retracted if the graph without it is consistent. Loops are robust factors, so a slightly wrong one keeps
its residual near the bound instead of bending the graph; without retraction it would veto every later loop for
as long as the robot patrols.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fleetslam._imports import require
from fleetslam.errors import SlamError

logger = logging.getLogger(__name__)


def _gtsam() -> Any:
    return require("gtsam", "slam")


def information_from_std(translation_std: float, rotation_std_rad: float) -> NDArray[np.float64]:
    """Diagonal 6×6 information over (x, y, z, roll, pitch, yaw)."""
    return np.diag([1.0 / translation_std**2] * 3 + [1.0 / rotation_std_rad**2] * 3)


def _to_gtsam_information(information: NDArray[np.float64]) -> NDArray[np.float64]:
    perm = [3, 4, 5, 0, 1, 2]
    return np.asarray(information, dtype=np.float64)[np.ix_(perm, perm)]


@dataclass
class Constraint:
    """An edge ``T_ab`` (pose of b in a's frame)."""

    a: int
    b: int
    transform: NDArray[np.float64]
    information: NDArray[np.float64]
    kind: str
    """'odometry' or 'loop'."""


class PoseGraph:
    """Pose3 graph: nodes by integer id, odometry and loop constraints."""

    def __init__(
        self, robust_kernel: str = "huber", robust_parameter: float = 1.345, optimize_max_error: float = 3.0
    ) -> None:
        self._g = _gtsam()
        self.robust_kernel = robust_kernel
        self.robust_parameter = robust_parameter
        self.optimize_max_error = optimize_max_error
        self._graph = self._g.NonlinearFactorGraph()
        self._values = self._g.Values()
        self._constraints: list[Constraint] = []
        self._factor_index: dict[int, int] = {}
        """Index in ``_graph`` of each loop constraint's factor, by ``id()`` of the constraint."""
        self.retracted: list[Constraint] = []
        """Loops accepted earlier and retracted because later loops disputed them."""
        self._isam = self._new_isam()
        self._pending_graph = self._g.NonlinearFactorGraph()
        self._pending_values = self._g.Values()
        self._estimate: dict[int, NDArray[np.float64]] = {}
        self._anchored = False

    def __len__(self) -> int:
        return int(self._values.size())

    def _new_isam(self) -> Any:
        """iSAM2 relinearising whatever moved by more than a millimetre-sized step at every update (a loop closure
        moves many poses at once; the defaults wait ten updates)."""
        params = self._g.ISAM2Params()
        params.setRelinearizeThreshold(0.01)
        params.relinearizeSkip = 1
        return self._g.ISAM2(params)

    def _noise(self, information: NDArray[np.float64], robust: bool) -> Any:
        g = self._g
        model = g.noiseModel.Gaussian.Information(_to_gtsam_information(information))
        if not robust or self.robust_kernel == "none":
            return model
        kernel = (
            g.noiseModel.mEstimator.Huber.Create(self.robust_parameter)
            if self.robust_kernel == "huber"
            else g.noiseModel.mEstimator.Cauchy.Create(self.robust_parameter)
        )
        return g.noiseModel.Robust.Create(kernel, model)

    def add_node(self, node_id: int, pose_guess: NDArray[np.float64]) -> None:
        """Add a pose; the first node is anchored with a tight prior."""
        g = self._g
        if self._values.exists(node_id):
            raise SlamError(f"pose graph: node {node_id} already exists")
        pose = g.Pose3(np.asarray(pose_guess, dtype=np.float64))
        self._values.insert(node_id, pose)
        self._pending_values.insert(node_id, pose)
        self._estimate[node_id] = np.asarray(pose_guess, dtype=np.float64).copy()
        if not self._anchored:
            prior = g.PriorFactorPose3(node_id, pose, g.noiseModel.Isotropic.Sigma(6, 1e-6))
            self._graph.add(prior)
            self._pending_graph.add(prior)
            self._anchored = True

    def _check_nodes(self, a: int, b: int) -> None:
        for n in (a, b):
            if not self._values.exists(n):
                raise SlamError(f"pose graph: node {n} does not exist (add_node first)")

    def _factor(self, a: int, b: int, T_ab: NDArray[np.float64], information: NDArray[np.float64], robust: bool) -> Any:
        g = self._g
        return g.BetweenFactorPose3(a, b, g.Pose3(np.asarray(T_ab, dtype=np.float64)), self._noise(information, robust))

    def add_odometry(self, a: int, b: int, T_ab: NDArray[np.float64], information: NDArray[np.float64]) -> None:
        """Constraint between consecutive nodes (Gaussian, no kernel)."""
        self._check_nodes(a, b)
        factor = self._factor(a, b, T_ab, information, robust=False)
        self._graph.add(factor)
        self._pending_graph.add(factor)
        self._constraints.append(
            Constraint(a, b, np.asarray(T_ab, float).copy(), np.asarray(information, float), "odometry")
        )

    def add_loop(self, a: int, b: int, T_ab: NDArray[np.float64], information: NDArray[np.float64]) -> bool:
        """Add a loop closure to the incremental solution and keep it only if the result is consistent (every
        constraint within ``optimize_max_error`` standard deviations; RTAB-Map RGBD/OptimizeMaxError).

        Incremental: iSAM2 re-solves only the part of the graph the loop touches, and the check is one vectorised
        pass over the constraints. (A full Levenberg–Marquardt run per loop, as before, grew with the graph: a
        robot patrolling for minutes closes a loop every keyframe and spent seconds on each.)"""
        g = self._g
        self._check_nodes(a, b)
        self.flush()
        candidate = Constraint(a, b, np.asarray(T_ab, float).copy(), np.asarray(information, float), "loop")
        factor = self._factor(a, b, T_ab, information, robust=True)
        added = g.NonlinearFactorGraph()
        added.add(factor)
        index = list(self._isam.update(added, g.Values()).getNewFactorsIndices())
        for _ in range(2):  # a loop can move many poses: relinearise until the correction has settled
            self._isam.update()
        result = self._isam.calculateEstimate()
        if self.optimize_max_error > 0:
            worst, worst_constraint = self._worst_error([*self._constraints, candidate], result)
            if worst > self.optimize_max_error:
                # Not settled, or not consistent: a full optimisation tells which (rare: a large correction).
                graph = g.NonlinearFactorGraph(self._graph)
                graph.add(factor)
                params = g.LevenbergMarquardtParams()
                params.setMaxIterations(100)
                result = g.LevenbergMarquardtOptimizer(graph, result, params).optimize()
                worst, worst_constraint = self._worst_error([*self._constraints, candidate], result)
                if worst <= self.optimize_max_error:
                    self._isam = self._new_isam()
                    self._isam.update(graph, result)
            if worst > self.optimize_max_error and self._retract_disputed(candidate, factor, worst_constraint, result):
                return True
            if worst > self.optimize_max_error:
                logger.info(
                    "loop %d-%d rejected: constraint %d-%d error is %.1f std (max %.1f)",
                    a,
                    b,
                    worst_constraint.a,
                    worst_constraint.b,
                    worst,
                    self.optimize_max_error,
                )
                self._isam.update(g.NonlinearFactorGraph(), g.Values(), index)
                self._isam.update()
                self._store(self._isam.calculateEstimate())
                return False
        self._add_loop_factor(candidate, factor)
        self._store(result)
        return True

    def _add_loop_factor(self, loop: Constraint, factor: Any) -> None:
        self._factor_index[id(loop)] = int(self._graph.size())
        self._graph.add(factor)
        self._constraints.append(loop)

    def _retract_disputed(self, candidate: Constraint, factor: Any, disputed: Constraint, values: Any) -> bool:
        """Accept ``candidate`` in place of the earlier loop ``disputed`` when the candidate itself is within the
        bound, and the graph with the candidate and without ``disputed`` is consistent (optimised afresh). One
        loop at a time: a wrong candidate that pushes several loops over the bound stays rejected."""
        if disputed.kind != "loop" or disputed is candidate:
            return False
        own, _ = self._worst_error([candidate], values)
        if own > self.optimize_max_error:
            return False
        g = self._g
        skip = self._factor_index[id(disputed)]
        graph = g.NonlinearFactorGraph()
        for i in range(self._graph.size()):
            if i != skip:
                graph.add(self._graph.at(i))
        graph.add(factor)
        params = g.LevenbergMarquardtParams()
        params.setMaxIterations(100)
        result = g.LevenbergMarquardtOptimizer(graph, values, params).optimize()
        kept = [c for c in self._constraints if c is not disputed]
        worst, _ = self._worst_error([*kept, candidate], result)
        if worst > self.optimize_max_error:
            return False
        logger.info(
            "loop %d-%d retracted: the graph with loop %d-%d is consistent without it (worst error %.1f std)",
            disputed.a, disputed.b, candidate.a, candidate.b, worst,
        )  # fmt: skip
        self._graph = graph
        self._constraints = [*kept, candidate]
        del self._factor_index[id(disputed)]
        self._factor_index = {key: i - (i > skip) for key, i in self._factor_index.items()}
        self._factor_index[id(candidate)] = int(graph.size()) - 1
        self.retracted.append(disputed)
        self._isam = self._new_isam()
        self._isam.update(graph, result)
        self._store(result)
        return True

    def _worst_error(self, constraints: list[Constraint], values: Any) -> tuple[float, Constraint]:
        """The constraint with the largest translational error in units of its standard deviation (vectorised)."""
        ids = sorted({n for c in constraints for n in (c.a, c.b)})
        row = {n: k for k, n in enumerate(ids)}
        poses = np.stack([values.atPose3(n).matrix() for n in ids])
        pa = poses[[row[c.a] for c in constraints]]
        pb = poses[[row[c.b] for c in constraints]]
        measured = np.stack([c.transform for c in constraints])
        # Translation of measured⁻¹·Pa⁻¹·Pb: Rmᵀ·(Raᵀ·(tb − ta) − tm); the rotation is not checked (as RTAB-Map).
        t_rel = np.einsum("nji,nj->ni", pa[:, :3, :3], pb[:, :3, 3] - pa[:, :3, 3])
        error = np.einsum("nji,nj->ni", measured[:, :3, :3], t_rel - measured[:, :3, 3])
        info = np.stack([np.diag(c.information)[:3] for c in constraints])
        std = np.sqrt(1.0 / np.maximum(info.max(axis=1), 1e-12))
        ratio = np.linalg.norm(error, axis=1) / std
        worst = int(np.argmax(ratio))
        return float(ratio[worst]), constraints[worst]

    def _current_values(self) -> Any:
        values = self._g.Values()
        for node_id, pose in self._estimate.items():
            values.insert(node_id, self._g.Pose3(pose))
        return values

    def flush(self) -> None:
        """Apply pending nodes and constraints with one iSAM2 update."""
        if self._pending_values.size() == 0 and self._pending_graph.size() == 0:
            return
        self._isam.update(self._pending_graph, self._pending_values)
        self._pending_graph = self._g.NonlinearFactorGraph()
        self._pending_values = self._g.Values()
        self._store(self._isam.calculateEstimate())

    def _store(self, values: Any) -> None:
        for node_id in list(self._estimate):
            if values.exists(node_id):
                self._estimate[node_id] = values.atPose3(node_id).matrix()

    def optimize(self) -> dict[int, NDArray[np.float64]]:
        """Current optimised poses ``T_world_node`` by id (iSAM2 estimate)."""
        self.flush()
        return {k: v.copy() for k, v in self._estimate.items()}

    def optimize_full(self, max_iterations: int = 100) -> dict[int, NDArray[np.float64]]:
        """A full Levenberg–Marquardt optimisation of the whole graph from the current estimate."""
        g = self._g
        self.flush()
        params = g.LevenbergMarquardtParams()
        params.setMaxIterations(max_iterations)
        result = g.LevenbergMarquardtOptimizer(self._graph, self._current_values(), params).optimize()
        self._store(result)
        return {k: v.copy() for k, v in self._estimate.items()}

    def constraints(self) -> list[Constraint]:
        """Odometry and accepted loop constraints, in insertion order."""
        return list(self._constraints)


def make_pose_graph(config: Any) -> PoseGraph:
    """Build from a :class:`fleetslam.slam.config.BackendConfig`."""
    return PoseGraph(config.robust_kernel, config.robust_parameter, config.optimize_max_error)
