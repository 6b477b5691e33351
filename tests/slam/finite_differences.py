"""The finite-difference check of a dense term's Jacobian, shared by the surface and photometric tests."""

from __future__ import annotations

import numpy as np

from fleetslam.geometry import so3_exp
from fleetslam.slam.pose_refinement import DenseTerm


def jacobian_agreement(term: DenseTerm, T_camera_world: np.ndarray, rtol: float, atol: float) -> list[float]:
    """Per axis of the left perturbation (translation, rotation): the fraction of residuals whose numeric
    derivative (a 1e-6 step) agrees with the term's Jacobian within ``rtol``/``atol``. The same residuals must
    survive the step (no pair gained or lost)."""
    residual, jacobian = term.linearize(T_camera_world)
    fractions = []
    for axis in range(6):
        delta = np.zeros(6)
        delta[axis] = 1e-6
        update = np.eye(4)
        update[:3, :3] = so3_exp(delta[3:])
        update[:3, 3] = delta[:3]
        moved, _ = term.linearize(update @ T_camera_world)
        assert len(moved) == len(residual)
        numeric = (moved - residual) / 1e-6
        fractions.append(float(np.isclose(numeric, jacobian[:, axis], rtol=rtol, atol=atol).mean()))
    return fractions
