"""Live sensor drivers: what an RGB-D camera driver is (:mod:`~fleetslam.drivers.base`, pure) and the node that
publishes any driver's frames on the camera topics the SLAM node reads (:mod:`~fleetslam.drivers.node`)."""

from fleetslam.drivers.base import CameraDriver

__all__ = ["CameraDriver"]
