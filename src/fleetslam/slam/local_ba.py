"""RGB-D bundle adjustment over a window of keyframes (pure NumPy): poses and points jointly, Levenberg–Marquardt
on the Schur complement of the points.

Every observation of point j from keyframe k gives three residuals, each divided by its standard deviation:

    (u, v) − π(T_k·X_j)      σ = pixel_std of the keypoint (its pyramid level's pixel size)
    z − (T_k·X_j)_z          σ(z) = depth_noise·z² + depth_floor   (only where the keyframe measured depth)

The depth term is what a monocular BA lacks: it fixes each point's depth from a single view and the scale of the
whole window, so a window of a few keyframes is well posed without a gauge beyond one fixed pose. A Huber kernel
on the whitened 3-vector lets a few wrong matches pull only linearly. Poses are ``T_camera_world`` updated by left
perturbations ``exp(δ)·T`` (translation first); ``basis`` restricts δ to a subspace (a ground robot's x, y and yaw,
see :func:`~fleetslam.slam.pose_refinement.planar_basis`). Optional priors on the relative pose of two keyframes
(wheel odometry) join the normal equations as 6-vector residuals. A point seen without depth (beyond the sensor's
range) may carry an inverse-depth prior instead, (1/‖X − c‖ − ρ₀)/σ_ρ from the camera centre c it was first seen
from (Civera et al.'s inverse-depth parametrisation, as a weak prior): with little parallax its bearings hold the
poses' rotation while its distance stays where the prior and the parallax put it. Such a point steps in local
inverse-depth coordinates (across its ray, and its inverse distance), in which its reprojections are nearly linear.

With the points fixed the same code is motion-only pose refinement (tracking): one pose, no Schur complement.
The window is small (≤ a dozen keyframes), so the reduced camera system is dense: one (V·d)² matrix.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from fleetslam.geometry import invert, skew, so3_exp, so3_log

#: Huber threshold on the whitened residual's norm: √(χ²₃ at 95 %).
HUBER = float(np.sqrt(7.815))
#: Observations whose whitened χ² exceeds this after the optimisation are outliers (χ²₃ at 99.5 %).
OUTLIER_CHI2 = 12.84


@dataclass
class PosePrior:
    """A measured relative pose between two keyframes, ``T_ci_cj`` (camera j in camera i), e.g. from the wheels."""

    i: int
    j: int
    measured: NDArray[np.float64]
    """``T_ci_cj``: camera j's pose in camera i's frame."""
    information: NDArray[np.float64]
    """(6, 6) inverse covariance of the error (translation, rotation vector) of ``measured⁻¹·T_ci_cj``."""


@dataclass
class BundleProblem:
    """Keyframes, points and the observations between them."""

    poses: NDArray[np.float64]
    """(K, 4, 4) ``T_camera_world`` of each keyframe."""
    points: NDArray[np.float64]
    """(P, 3) world points."""
    obs_pose: NDArray[np.intp]
    """(M,) keyframe of each observation."""
    obs_point: NDArray[np.intp]
    """(M,) point of each observation."""
    pixels: NDArray[np.float64]
    """(M, 2) measured keypoint positions."""
    depths: NDArray[np.float64]
    """(M,) measured depth (metres) at the keypoint; 0 or NaN where the sensor gave none."""
    pixel_std: NDArray[np.float64]
    """(M,) standard deviation of each keypoint position (pixels)."""
    camera_matrix: NDArray[np.float64]
    fixed: NDArray[np.bool_]
    """(K,) keyframes held fixed (at least one, the gauge, unless the points are fixed)."""
    depth_noise: float = 1.5e-3
    """σ(z) = depth_noise·z² + depth_floor (metres): a Kinect's axial noise, quantisation included."""
    depth_floor: float = 1e-3
    basis: NDArray[np.float64] | None = None
    """(6, d) allowed pose perturbations (None: all six)."""
    priors: list[PosePrior] = field(default_factory=list)
    points_fixed: bool = False
    """Optimise the poses only (motion-only refinement against a map)."""
    point_anchors: NDArray[np.float64] | None = None
    """(P, 3+) the camera centre each point's inverse-depth prior is measured from; NaN rows (or None): no prior."""
    inverse_depth_prior: tuple[float, float] = (0.0, 1.0)
    """Mean and standard deviation (1/m) of the inverse distance of a point from its anchor."""


@dataclass
class BundleResult:
    poses: NDArray[np.float64]
    points: NDArray[np.float64]
    inliers: NDArray[np.bool_]
    """(M,) observations within the χ² bound at the solution."""
    chi2: NDArray[np.float64]
    """(M,) whitened squared residual of every observation at the solution."""
    initial_cost: float
    final_cost: float
    iterations: int
    hessian: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 0)))
    """The reduced (pose) system at the solution, (V·d)²: its inverse is the poses' covariance."""
    point_hessian: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3, 3)))
    """(P, 3, 3) each point's own block of the normal equations (its priors included) at the last linearisation:
    its inverse is the point's covariance with the poses held (empty when the points are fixed)."""


def _scatter(index: NDArray[np.intp], values: NDArray[np.float64], n: int) -> NDArray[np.float64]:
    """Sum of ``values`` rows (any trailing shape) into ``n`` bins by ``index`` (bincount per component: much faster
    than ``np.add.at``)."""
    flat = values.reshape(len(values), int(np.prod(values.shape[1:])))
    out = np.empty((n, flat.shape[1]))
    for c in range(flat.shape[1]):
        out[:, c] = np.bincount(index, weights=flat[:, c], minlength=n)
    return out.reshape((n, *values.shape[1:]))


def _exp(delta: NDArray[np.float64]) -> NDArray[np.float64]:
    update = np.eye(4)
    update[:3, :3] = so3_exp(delta[3:])
    update[:3, 3] = delta[:3]
    return update


def _pose_error(measured_inverse: NDArray[np.float64], relative: NDArray[np.float64]) -> NDArray[np.float64]:
    error = measured_inverse @ relative
    return np.concatenate([error[:3, 3], so3_log(error[:3, :3])])


class _Evaluation:
    """Residuals, robust weights and cost of every observation at one point; the whitened Jacobians only on
    demand (:meth:`linearize`), as a rejected trial step never needs them."""

    def __init__(self, problem: BundleProblem, poses: NDArray[np.float64], points: NDArray[np.float64]) -> None:
        k = problem.camera_matrix
        fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
        self.problem = problem
        self.rotation = poses[problem.obs_pose, :3, :3]
        p = (self.rotation @ points[problem.obs_point][:, :, None])[:, :, 0] + poses[problem.obs_pose, :3, 3]
        z = p[:, 2]
        in_front = z > 1e-3
        inv_z = 1.0 / np.where(in_front, z, 1.0)
        depth = np.nan_to_num(problem.depths, nan=0.0)
        has_depth = (depth > 0) & in_front
        sigma_z = problem.depth_noise * np.where(has_depth, depth, 1.0) ** 2 + problem.depth_floor
        residual = np.zeros((len(p), 3))
        residual[:, 0] = (fx * p[:, 0] * inv_z + cx - problem.pixels[:, 0]) / problem.pixel_std
        residual[:, 1] = (fy * p[:, 1] * inv_z + cy - problem.pixels[:, 1]) / problem.pixel_std
        residual[:, 2] = np.where(has_depth, (z - depth) / sigma_z, 0.0)
        residual[~in_front] = 0.0
        chi2 = np.einsum("mi,mi->m", residual, residual)
        norm = np.sqrt(chi2)
        self.weight = np.where(norm <= HUBER, 1.0, HUBER / np.maximum(norm, 1e-12))
        self.weight[~in_front] = 0.0
        # Huber's ρ(s) for s = ‖r‖²: s inside the threshold, 2δ‖r‖ − δ² outside (an outlier never counts more).
        self.cost = float(np.sum(np.where(norm <= HUBER, chi2, 2 * HUBER * norm - HUBER**2)))
        self.chi2 = np.where(in_front, chi2, np.inf)
        self.residual = residual
        self._p, self._inv_z, self._in_front = p, inv_z, in_front
        self._depth_weight = np.where(has_depth, 1.0 / sigma_z, 0.0)
        self.jacobian_pose = self.jacobian_point = np.zeros((0, 3, 3))

    def linearize(self) -> None:
        """Whitened Jacobians in the pose (left perturbation, through ``basis``) and in the point."""
        problem = self.problem
        k = problem.camera_matrix
        p, inv_z, std = self._p, self._inv_z, problem.pixel_std
        d_proj = np.zeros((len(p), 3, 3))
        d_proj[:, 0, 0] = k[0, 0] * inv_z / std
        d_proj[:, 0, 2] = -k[0, 0] * p[:, 0] * inv_z**2 / std
        d_proj[:, 1, 1] = k[1, 1] * inv_z / std
        d_proj[:, 1, 2] = -k[1, 1] * p[:, 1] * inv_z**2 / std
        d_proj[:, 2, 2] = self._depth_weight
        d_proj[~self._in_front] = 0.0
        # ∂p/∂δ = [I | −[p]×]; a row aᵀ times −[p]× is (p × a)ᵀ, written out.
        jacobian = np.empty((len(p), 3, 6))
        jacobian[:, :, :3] = d_proj
        a0, a1, a2 = d_proj[:, :, 0], d_proj[:, :, 1], d_proj[:, :, 2]
        px, py, pz = p[:, 0:1], p[:, 1:2], p[:, 2:3]
        jacobian[:, :, 3] = py * a2 - pz * a1
        jacobian[:, :, 4] = pz * a0 - px * a2
        jacobian[:, :, 5] = px * a1 - py * a0
        self.jacobian_pose = jacobian if problem.basis is None else jacobian @ problem.basis
        self.jacobian_point = d_proj @ self.rotation


def _adjoint(pose: NDArray[np.float64]) -> NDArray[np.float64]:
    """Adjoint of a pose for (translation, rotation) perturbations: exp(Ad(T)·δ)·T = T·exp(δ)."""
    rotation, translation = pose[:3, :3], pose[:3, 3]
    out = np.zeros((6, 6))
    out[:3, :3] = out[3:, 3:] = rotation
    out[:3, 3:] = skew(translation) @ rotation
    return out


def _prepare_priors(problem: BundleProblem) -> list[tuple[PosePrior, NDArray[np.float64], NDArray[np.float64]]]:
    """Per prior: itself, the square root of its information (information = rootᵀ·root) and M⁻¹."""
    return [
        (
            prior,
            np.asarray(np.linalg.cholesky(prior.information).T, np.float64),
            np.asarray(np.linalg.inv(prior.measured), np.float64),
        )
        for prior in problem.priors
    ]


def _prior_terms(
    prepared: list[tuple[PosePrior, NDArray[np.float64], NDArray[np.float64]]],
    poses: NDArray[np.float64],
    basis: NDArray[np.float64],
    *,
    jacobians: bool = True,
) -> tuple[float, list[tuple[int, int, NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]]]:
    """Cost of the pose priors and, per prior, (i, j, whitened residual, its Jacobians in i's and j's δ).

    With ``R = T_i·T_j⁻¹`` the residual is e = Log(M⁻¹·R); perturbing, M⁻¹·exp(δ_i)·R·exp(−δ_j) =
    M⁻¹·R·exp(Ad(R⁻¹)·δ_i)·exp(−δ_j), so to first order ∂e/∂δ_i = Ad(R⁻¹) and ∂e/∂δ_j = −I (exact at e = 0,
    enough for Gauss–Newton near the solution)."""
    cost = 0.0
    terms = []
    for prior, root, measured_inverse in prepared:
        relative = poses[prior.i] @ invert(poses[prior.j])
        value = root @ _pose_error(measured_inverse, relative)
        cost += float(value @ value)
        if jacobians:
            jac_i = root @ _adjoint(invert(relative)) @ basis
            terms.append((prior.i, prior.j, value, jac_i, -root @ basis))
    return cost, terms


def _point_priors(
    problem: BundleProblem, points: NDArray[np.float64]
) -> tuple[float, NDArray[np.intp], NDArray[np.float64], NDArray[np.float64]]:
    """Cost of the points' inverse-depth priors and, per point that has one, its index, whitened residual and its
    Jacobian in the point (∂(1/d)/∂X = −(X − c)/d³)."""
    if problem.point_anchors is None or problem.points_fixed:
        return 0.0, np.zeros(0, np.intp), np.zeros(0), np.zeros((0, 3))
    index = np.flatnonzero(~np.isnan(problem.point_anchors[:, 0]))
    offset = points[index] - problem.point_anchors[index, :3]
    distance = np.maximum(np.linalg.norm(offset, axis=1), 1e-6)
    mean, std = problem.inverse_depth_prior
    residual = (1.0 / distance - mean) / std
    jacobian = -offset / (distance**3 * std)[:, None]
    return float(residual @ residual), index, residual, jacobian


def _observation_pairs(obs_point: NDArray[np.intp]) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Every ordered pair (a, b) of observations of the same point, itself included."""
    order = np.argsort(obs_point, kind="stable")
    sorted_points = obs_point[order]
    starts = np.searchsorted(sorted_points, sorted_points, side="left")
    ends = np.searchsorted(sorted_points, sorted_points, side="right")
    counts = ends - starts
    first_sorted = np.repeat(np.arange(len(order)), counts)
    offsets = np.concatenate([[0], np.cumsum(counts)[:-1]])
    second_sorted = starts[first_sorted] + (np.arange(len(first_sorted)) - offsets[first_sorted])
    return order[first_sorted], order[second_sorted]


def _inverse_depth_frames(
    points: NDArray[np.float64], anchors: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Per anchored point, its local inverse-depth coordinates q = (α, β, ρ) about its current place:
    X(q) = c + (u + α·e₁ + β·e₂)/ρ, with u the unit ray from its anchor c, e₁, e₂ across it and ρ = 1/‖X − c‖
    (q = (0, 0, ρ) here). Returns the distance 1/ρ, the basis (P, 3, 3) with columns e₁, e₂, u, and ∂X/∂q
    (P, 3, 3)."""
    offset = points - anchors
    distance = np.maximum(np.linalg.norm(offset, axis=1), 1e-9)
    ray = offset / distance[:, None]
    # Any vector not parallel to the ray, crossed with it, gives e₁ (the farther axis from the ray: well conditioned).
    helper = np.where((np.abs(ray[:, 0]) < 0.9)[:, None], [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = np.cross(ray, helper)
    e1 /= np.linalg.norm(e1, axis=1)[:, None]
    e2 = np.cross(ray, e1)
    jacobian = np.stack([e1 * distance[:, None], e2 * distance[:, None], -ray * (distance**2)[:, None]], axis=2)
    return distance, np.stack([e1, e2, ray], axis=2), jacobian


def bundle_adjust(problem: BundleProblem, iterations: int = 8, tolerance: float = 1e-6) -> BundleResult:
    """Optimise the problem's free poses (and points, unless fixed); see the module docstring."""
    poses = np.array(problem.poses, np.float64, copy=True)
    points = np.array(problem.points, np.float64, copy=True)
    n_poses, n_points = len(poses), len(points)
    basis = np.eye(6) if problem.basis is None else problem.basis
    dof = basis.shape[1]
    variable = np.flatnonzero(~np.asarray(problem.fixed, bool))
    var_of = np.full(n_poses, -1, np.intp)
    var_of[variable] = np.arange(len(variable))
    n_var = len(variable)
    evaluation = _Evaluation(problem, poses, points)
    evaluation.linearize()
    prepared = _prepare_priors(problem)
    prior_cost, prior_terms = _prior_terms(prepared, poses, basis)
    point_terms = _point_priors(problem, points)
    cost = evaluation.cost + prior_cost + point_terms[0]
    initial_cost = cost
    damping = 1e-4
    done = 0
    reduced = np.zeros((n_var * dof, n_var * dof))
    point_hessian = np.zeros((0, 3, 3))
    pairs = _observation_pairs(problem.obs_point[var_of[problem.obs_pose] >= 0])
    # Points with an inverse-depth prior (seen without depth, little parallax) take their steps in local
    # inverse-depth coordinates (see _inverse_depth_frames): the reprojections are nearly linear in those, not in
    # x, y, z, so a point that starts metres off along its ray reaches its distance in a step or two instead of
    # leaving its error to the poses (Civera et al.; measured: texture 2-4 m away started at 9 m, five iterations,
    # poses 78-92 mm off in x, y, z, 3-6 mm in inverse depth, as from the points' true distances).
    anchored = np.zeros(0, np.intp)
    anchor_centres = np.zeros((0, 3))
    if problem.point_anchors is not None and not problem.points_fixed:
        anchored = np.flatnonzero(~np.isnan(problem.point_anchors[:, 0]))
        anchor_centres = problem.point_anchors[anchored, :3]
    if n_var == 0 and problem.points_fixed:
        iterations = 0
    for done in range(1, iterations + 1):  # noqa: B007 (the count is reported)
        w = evaluation.weight
        jc, jp, r = evaluation.jacobian_pose, evaluation.jacobian_point, evaluation.residual
        obs_var = var_of[problem.obs_pose]
        on_var = obs_var >= 0
        wjc = jc * w[:, None, None]
        wjc_t = wjc[on_var].transpose(0, 2, 1)
        h_cc = _scatter(obs_var[on_var], wjc_t @ jc[on_var], n_var)
        g_c = _scatter(obs_var[on_var], (wjc_t @ r[on_var][:, :, None])[:, :, 0], n_var)
        reduced = np.zeros((n_var * dof, n_var * dof))
        gradient = np.zeros(n_var * dof)
        for v in range(n_var):
            reduced[v * dof : (v + 1) * dof, v * dof : (v + 1) * dof] = h_cc[v]
            gradient[v * dof : (v + 1) * dof] = g_c[v]
        for i, j, value, jac_i, jac_j in prior_terms:
            for a, jac_a in ((var_of[i], jac_i), (var_of[j], jac_j)):
                if a < 0:
                    continue
                gradient[a * dof : (a + 1) * dof] += jac_a.T @ value
                for b, jac_b in ((var_of[i], jac_i), (var_of[j], jac_j)):
                    if b >= 0:
                        reduced[a * dof : (a + 1) * dof, b * dof : (b + 1) * dof] += jac_a.T @ jac_b
        lhs = reduced.copy()
        rhs = -gradient
        if not problem.points_fixed:
            _, prior_index, prior_residual, prior_jacobian = point_terms
            if len(anchored):
                distance, frames, to_q = _inverse_depth_frames(points[anchored], anchor_centres)
                change = np.broadcast_to(np.eye(3), (n_points, 3, 3)).copy()
                change[anchored] = to_q
                jp = jp @ change[problem.obs_point]
                prior_jacobian = (prior_jacobian[:, None, :] @ change[prior_index])[:, 0, :]
            wjp_t = (jp * w[:, None, None]).transpose(0, 2, 1)
            h_pp = _scatter(problem.obs_point, wjp_t @ jp, n_points)
            g_p = _scatter(problem.obs_point, (wjp_t @ r[:, :, None])[:, :, 0], n_points)
            h_pp[prior_index] += prior_jacobian[:, :, None] * prior_jacobian[:, None, :]
            g_p[prior_index] += prior_jacobian * prior_residual[:, None]
            point_hessian = h_pp.copy()
            if len(anchored):  # reported in x, y, z as for every point: H_xyz = (∂X/∂q)⁻ᵀ·H_q·(∂X/∂q)⁻¹
                from_xyz = np.linalg.inv(to_q)
                point_hessian[anchored] = from_xyz.transpose(0, 2, 1) @ h_pp[anchored] @ from_xyz
            h_pp_damped = h_pp + (damping * np.maximum(np.einsum("pii->pi", h_pp), 1e-9))[:, :, None] * np.eye(3)
            h_pp_inverse = np.linalg.inv(h_pp_damped + 1e-12 * np.eye(3))
            # Schur complement, observation pair by pair: a point seen from poses a and b couples them by
            # −E_a·H_pp⁻¹·E_bᵀ, with E = Jcᵀ·W·Jp of each observation (a point has few observations in a window).
            coupled_point = problem.obs_point[on_var]
            cross = wjc_t @ jp[on_var]  # (n, d, 3)
            scaled = cross @ h_pp_inverse[coupled_point]
            first, second = pairs
            blocks = scaled[first] @ cross[second].transpose(0, 2, 1)
            pair_bin = obs_var[on_var][first] * n_var + obs_var[on_var][second]
            schur = _scatter(pair_bin, blocks, n_var * n_var).reshape(n_var, n_var, dof, dof)
            lhs -= schur.transpose(0, 2, 1, 3).reshape(n_var * dof, n_var * dof)
            rhs += _scatter(obs_var[on_var], (scaled @ g_p[coupled_point][:, :, None])[:, :, 0], n_var).reshape(-1)
        lhs[np.diag_indices_from(lhs)] += damping * np.maximum(np.diag(reduced), 1e-9)
        try:
            step_poses = np.linalg.solve(lhs, rhs) if n_var else np.zeros(0)
        except np.linalg.LinAlgError:
            break
        new_poses = poses.copy()
        for v, k in enumerate(variable):
            new_poses[k] = _exp(basis @ step_poses[v * dof : (v + 1) * dof]) @ poses[k]
        new_points = points
        if not problem.points_fixed:
            per_obs = cross.transpose(0, 2, 1) @ step_poses.reshape(n_var, dof)[obs_var[on_var]][:, :, None]
            back = g_p + _scatter(coupled_point, per_obs[:, :, 0], n_points)
            step_points = -(h_pp_inverse @ back[:, :, None])[:, :, 0]
            new_points = points + step_points
            if len(anchored):
                q = step_points[anchored]
                # ρ + δρ kept positive (in front of the anchor): a step past it is the linearisation's.
                rho = np.maximum(1.0 / distance + q[:, 2], 1e-3)
                direction = frames[:, :, 2] + frames[:, :, 0] * q[:, :1] + frames[:, :, 1] * q[:, 1:2]
                new_points[anchored] = anchor_centres + direction / rho[:, None]
        trial = _Evaluation(problem, new_poses, new_points)
        trial_point_terms = _point_priors(problem, new_points)
        trial_cost = trial.cost + _prior_terms(prepared, new_poses, basis, jacobians=False)[0] + trial_point_terms[0]
        if trial_cost < cost:
            improvement = (cost - trial_cost) / max(cost, 1e-12)
            poses, points, evaluation, cost = new_poses, new_points, trial, trial_cost
            evaluation.linearize()
            prior_terms = _prior_terms(prepared, poses, basis)[1]
            point_terms = trial_point_terms
            damping = max(damping / 3.0, 1e-7)
            if improvement < tolerance:
                break
        else:
            damping *= 6.0
            if damping > 1e4:
                break
    return BundleResult(
        poses=poses,
        points=points,
        inliers=evaluation.chi2 <= OUTLIER_CHI2,
        chi2=evaluation.chi2,
        initial_cost=initial_cost,
        final_cost=cost,
        iterations=done,
        hessian=reduced,
        point_hessian=point_hessian,
    )
