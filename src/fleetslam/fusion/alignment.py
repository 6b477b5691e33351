"""The least-squares rigid transform between two point sets, the fitting every alignment here rests on.

Placing agents' map frames in the fleet frame is done by the agents' pairwise-consistent closures
(:mod:`fleetslam.fusion.consistency`, :mod:`fleetslam.fusion.collaboration`) and refined by the fleet back-end's
joint optimisation (:mod:`fleetslam.fusion.fleet_graph`); both fit frames with :func:`rigid_fit`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from fleetslam.geometry import make_pose

Pose = NDArray[np.float64]


def rigid_fit(source: NDArray[np.float64], target: NDArray[np.float64]) -> Pose:
    """Least-squares rigid transform (Kabsch/Umeyama without scale) with ``target ≈ T · source``."""
    if source.shape != target.shape or source.shape[0] < 3:
        raise ValueError(f"rigid_fit needs two (N>=3, 3) arrays of equal shape, got {source.shape}, {target.shape}")
    mu_s, mu_t = source.mean(axis=0), target.mean(axis=0)
    cov = (target - mu_t).T @ (source - mu_s)
    u, _, vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(u @ vt))
    rotation = u @ np.diag([1.0, 1.0, d]) @ vt
    return make_pose(rotation, mu_t - rotation @ mu_s)
