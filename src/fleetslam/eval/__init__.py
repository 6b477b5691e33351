"""Trajectory metrics (APE/RPE with TUM conventions, via evo) and plots."""

from fleetslam.eval.ape import ApeResult, ErrorStats, RpeResult, ape, fleet_ape, plot_ape, rpe

__all__ = ["ApeResult", "ErrorStats", "RpeResult", "ape", "fleet_ape", "plot_ape", "rpe"]
