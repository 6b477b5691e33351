"""fleetslam: distributed multi-robot SLAM and tele-operated 3D inspection."""

__version__ = "0.1.0"
