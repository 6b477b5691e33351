"""Motion-only pose refinement: reprojection errors of matched map points plus a prior on the pose (pure).

PnP alone is ill-conditioned when few points match or they are far away (a Kinect's depth at 4 m is
quantised in ~3 cm steps), and one such frame's error becomes the next keyframe's map. A robot's motion over
one frame is very predictable (constant velocity, or wheel odometry), so the refinement minimises

    Σ ρ(‖π(T_cw·Xᵢ) − uᵢ‖² / σ_px²) + (T_cw ⊖ T_pred)ᵀ Σ_pred⁻¹ (T_cw ⊖ T_pred)

with a Huber ρ by Gauss–Newton on a left perturbation of ``T_cw`` (camera ← world). With many well-spread
points the reprojection term dominates and the prior changes nothing measurable; with a handful of far points
the prior keeps the estimate where the motion says it must be.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from fleetslam.geometry import skew, so3_exp, so3_log


class DenseTerm(Protocol):
    """Residuals of a frame's pixels against a keyframe (the point-to-plane and the photometric terms)."""

    @property
    def huber(self) -> float:
        """Huber threshold in standard deviations: a pixel wrongly associated pulls no harder than this."""
        ...

    def linearize(self, T_camera_world: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Whitened residuals (m,) and their Jacobian (m, 6) in the left perturbation of ``T_camera_world``."""
        ...


def _pose_error(pose: NDArray[np.float64], reference_inverse: NDArray[np.float64]) -> NDArray[np.float64]:
    """(translation, rotation vector) of ``pose · reference⁻¹``."""
    error = pose @ reference_inverse
    return np.concatenate([error[:3, 3], so3_log(error[:3, :3])])


def _gauss_newton(
    pose: NDArray[np.float64],
    points_world: NDArray[np.float64],
    pixels: NDArray[np.float64],
    camera_matrix: NDArray[np.float64],
    prior: tuple[NDArray[np.float64], NDArray[np.float64]] | None,
    pixel_std: float | NDArray[np.float64],
    huber_px: float,
    iterations: int,
    basis: NDArray[np.float64] | None = None,
    depth: tuple[NDArray[np.float64], float] | None = None,
    dense: Sequence[DenseTerm] = (),
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """Minimise the robust reprojection error (plus the prior ``(T_prior⁻¹, information)`` if given, and the depth
    residuals ``(measured depths, noise)`` where a depth is > 0: σ(z) = noise·z² + 1 mm); returns the pose, the
    reprojection term's Gauss–Newton Hessian at it (with the dense terms') and the a-posteriori variance factor of
    the reprojections (the weighted squared residuals per degree of freedom: about 1 when ``pixel_std`` is right).
    ``dense`` adds residuals of the frame's pixels against a keyframe: point-to-plane of its depth
    (:mod:`fleetslam.slam.surface_alignment`), intensity (:mod:`fleetslam.slam.photometric_alignment`)."""
    fx, fy, cx, cy = camera_matrix[0, 0], camera_matrix[1, 1], camera_matrix[0, 2], camera_matrix[1, 2]
    n = len(points_world)
    sigma = np.broadcast_to(np.asarray(pixel_std, np.float64), (n,))
    huber = huber_px / sigma  # the kernel's threshold in standard deviations, per point
    has_depth = np.zeros(n, bool)
    measured = sigma_z = np.ones(n)
    if depth is not None:
        measured = np.nan_to_num(np.asarray(depth[0], np.float64), nan=0.0)
        has_depth = measured > 0
        sigma_z = depth[1] * measured**2 + 1e-3
    hessian = np.eye(6)
    variance_factor = 1.0
    rows = 3 if depth is not None else 2
    for _ in range(iterations):
        p = points_world @ pose[:3, :3].T + pose[:3, 3]
        px, py, pz = p[:, 0], p[:, 1], p[:, 2]
        z = np.maximum(pz, 1e-6)
        inv_z = 1.0 / z
        residual = np.empty((n, rows))
        residual[:, 0] = (fx * px * inv_z + cx - pixels[:, 0]) / sigma
        residual[:, 1] = (fy * py * inv_z + cy - pixels[:, 1]) / sigma
        # Whitened Jacobian rows of (u, v[, z]) in p: u: (a0, 0, a2), v: (0, b1, b2), z: (0, 0, c); of the pose,
        # ∂p/∂δ = [I | −[p]×], where a row aᵀ times −[p]× is (p × a)ᵀ — written out for the zeros.
        a0, a2 = fx * inv_z / sigma, -fx * px * inv_z**2 / sigma
        b1, b2 = fy * inv_z / sigma, -fy * py * inv_z**2 / sigma
        jacobian = np.zeros((n, rows, 6))
        jacobian[:, 0, 0], jacobian[:, 0, 2] = a0, a2
        jacobian[:, 0, 3], jacobian[:, 0, 4], jacobian[:, 0, 5] = py * a2, pz * a0 - px * a2, -py * a0
        jacobian[:, 1, 1], jacobian[:, 1, 2] = b1, b2
        jacobian[:, 1, 3], jacobian[:, 1, 4], jacobian[:, 1, 5] = py * b2 - pz * b1, -px * b2, px * b1
        if depth is not None:
            c = np.where(has_depth, 1.0 / sigma_z, 0.0)
            residual[:, 2] = (pz - measured) * c
            jacobian[:, 2, 2], jacobian[:, 2, 3], jacobian[:, 2, 4] = c, py * c, -px * c
        norm = np.sqrt(np.einsum("nk,nk->n", residual, residual))
        weight = np.where(norm <= huber, 1.0, huber / np.maximum(norm, 1e-12)) * (pz > 1e-6)
        flat = jacobian.reshape(n * rows, 6)
        if basis is not None:
            flat = flat @ basis  # only the allowed motions
        weighted = flat * np.repeat(weight, rows)[:, None]
        hessian = weighted.T @ flat
        gradient = weighted.T @ residual.reshape(-1)
        variance_factor = float(np.sum(weight * norm**2) / max(rows * n - 6, 1))
        for term in dense:
            term_residual, term_jacobian = term.linearize(pose)
            if basis is not None:
                term_jacobian = term_jacobian @ basis
            size = np.abs(term_residual)
            term_weight = np.where(size <= term.huber, 1.0, term.huber / np.maximum(size, 1e-12))
            weighted_term = term_jacobian * term_weight[:, None]
            hessian = hessian + weighted_term.T @ term_jacobian
            gradient = gradient + weighted_term.T @ term_residual
        system = hessian
        if prior is not None:
            prior_inverse, information = prior
            reduced = information if basis is None else basis.T @ information @ basis
            prior_gradient = information @ _pose_error(pose, prior_inverse)
            system = hessian + reduced
            gradient = gradient + (prior_gradient if basis is None else basis.T @ prior_gradient)
        try:
            step = -np.linalg.solve(system + 1e-9 * np.eye(len(system)), gradient)
        except np.linalg.LinAlgError:
            break
        if basis is not None:
            step = basis @ step
        update = np.eye(4)
        update[:3, :3] = so3_exp(step[3:])
        update[:3, 3] = step[:3]
        pose = update @ pose
        if np.linalg.norm(step) < 1e-6:  # a micrometre, a microradian
            break
    return pose, hessian, variance_factor


def refine_pose(
    T_camera_world: NDArray[np.float64],
    points_world: NDArray[np.float64],
    pixels: NDArray[np.float64],
    camera_matrix: NDArray[np.float64],
    *,
    pixel_std: float | NDArray[np.float64] = 1.0,
    huber_px: float = 2.0,
    iterations: int = 6,
    basis: NDArray[np.float64] | None = None,
    depth: tuple[NDArray[np.float64], float] | None = None,
    prior: tuple[NDArray[np.float64], tuple[float, float]] | None = None,
    dense: Sequence[DenseTerm] = (),
) -> NDArray[np.float64]:
    """``T_camera_world`` minimising the robust reprojection (and depth) error, with ``prior`` = (prior
    ``T_camera_world``, (metres, radians) per axis) fused unconditionally when given; ``basis`` and ``depth`` as in
    :func:`refine_pose_with_prior` (which decides whether the prior may be fused)."""
    fused = None
    if prior is not None:
        std = prior[1]
        information = np.diag([1.0 / std[0] ** 2] * 3 + [1.0 / std[1] ** 2] * 3)
        fused = (np.linalg.inv(np.asarray(prior[0], np.float64)), information)
    pose, _, _ = _gauss_newton(
        np.asarray(T_camera_world, np.float64), points_world, pixels, camera_matrix, fused, pixel_std, huber_px,
        iterations, basis, depth, dense,
    )  # fmt: skip
    return pose


def refine_pose_information(
    T_camera_world: NDArray[np.float64],
    points_world: NDArray[np.float64],
    pixels: NDArray[np.float64],
    camera_matrix: NDArray[np.float64],
    *,
    pixel_std: float | NDArray[np.float64] = 1.0,
    huber_px: float = 2.0,
    iterations: int = 6,
    depth: tuple[NDArray[np.float64], float] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """As :func:`refine_pose` without a prior, and with what the solve knows of its precision: the refined
    ``T_camera_world``, the Gauss–Newton Hessian of the (whitened, robust) residuals in the left perturbation of
    ``T_camera_world`` (translation first; its inverse is the covariance when the noise is as stated) and the
    a-posteriori variance factor (about 1 when it is)."""
    return _gauss_newton(
        np.asarray(T_camera_world, np.float64), points_world, pixels, camera_matrix, None, pixel_std, huber_px,
        iterations, None, depth,
    )  # fmt: skip


def planar_basis(T_base_camera: NDArray[np.float64]) -> NDArray[np.float64]:
    """(6, 3) left perturbations of ``T_camera_world`` caused by moving the base by (dx, dy, dyaw) in its own
    frame: δ = −Ad(T_camera_base)·ξ_base (translation first)."""
    camera_base = np.linalg.inv(np.asarray(T_base_camera, np.float64))
    rotation, translation = camera_base[:3, :3], camera_base[:3, 3]
    adjoint = np.zeros((6, 6))
    adjoint[:3, :3] = rotation
    adjoint[:3, 3:] = skew(translation) @ rotation
    adjoint[3:, 3:] = rotation
    select = np.zeros((6, 3))
    select[0, 0] = select[1, 1] = select[5, 2] = 1.0
    return -adjoint @ select


def refine_pose_with_prior(
    T_camera_world: NDArray[np.float64],
    points_world: NDArray[np.float64],
    pixels: NDArray[np.float64],
    camera_matrix: NDArray[np.float64],
    prior_camera_world: NDArray[np.float64],
    prior_std: tuple[float, float],
    *,
    pixel_std: float | NDArray[np.float64] = 1.0,
    huber_px: float = 2.0,
    iterations: int = 6,
    gate: float = 1000.0,
    basis: NDArray[np.float64] | None = None,
    depth: tuple[NDArray[np.float64], float] | None = None,
    dense: Sequence[DenseTerm] = (),
) -> tuple[NDArray[np.float64], bool]:
    """Refined ``T_camera_world`` (see the module docstring) and whether the prior was used.

    ``basis`` (6, k) restricts the update to k motions (columns: left perturbations of ``T_camera_world`` as
    translation, rotation), e.g. a ground robot's x, y and yaw. ``prior_std`` is (metres, radians) per axis.
    ``pixel_std`` may differ per point (a keypoint's pyramid level); ``depth`` = (the frame's measured depth of
    each point, 0 where none; the sensor's noise coefficient) adds depth residuals (an RGB-D frame).
    The prior is dropped when the reprojection-only estimate and the prediction disagree grossly (squared
    Mahalanobis distance over their combined uncertainty above ``gate``): then the prediction is what is wrong
    (a collision, a slip, a hand-held jerk). The gate is far above χ²₆'s 22.5 because the reprojection
    covariance ignores the map points' own errors, which are correlated: on the simulated plant 5 % of
    well-tracked frames exceed 100 although fusing them is right. ``dense``: see :func:`_gauss_newton`.
    """
    information: NDArray[np.float64] = np.diag([1.0 / prior_std[0] ** 2] * 3 + [1.0 / prior_std[1] ** 2] * 3)
    prior_inverse: NDArray[np.float64] = np.linalg.inv(np.asarray(prior_camera_world, np.float64))
    args = (points_world, pixels, camera_matrix)
    alone, hessian, variance_factor = _gauss_newton(
        np.asarray(T_camera_world, np.float64), *args, None, pixel_std, huber_px, iterations, basis, depth, dense
    )
    # The points' real scatter (depth quantisation, keypoint noise) sets the weight of the reprojection term:
    # scale pixel_std by the observed residuals, never below the nominal value.
    pixel_std = np.asarray(pixel_std, np.float64) * math.sqrt(max(variance_factor, 1.0))
    innovation = _pose_error(alone, prior_inverse)
    if basis is not None:
        # Compare in the allowed motions' coordinates (least squares: the innovation's other part is 0).
        innovation = np.asarray(np.linalg.lstsq(basis, innovation, rcond=None)[0], np.float64)
        information_k = basis.T @ information @ basis
    else:
        information_k = information
    combined = np.linalg.pinv(hessian) * max(variance_factor, 1.0) + np.linalg.inv(information_k)
    if float(innovation @ np.linalg.solve(combined, innovation)) > gate:
        return alone, False
    fused, _, _ = _gauss_newton(
        alone, *args, (prior_inverse, information), pixel_std, huber_px, iterations, basis, depth, dense
    )
    return fused, True
