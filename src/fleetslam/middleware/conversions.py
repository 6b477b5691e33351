"""Moved to :mod:`fleetslam.msg.conversions` (usable without the middleware); this module re-exports what it held."""

from fleetslam.msg.conversions import pose_matrix, transform_matrix, transform_msg

__all__ = ["pose_matrix", "transform_matrix", "transform_msg"]
