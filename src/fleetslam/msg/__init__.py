"""fleetslam's own ROS 2 interface definitions (``.msg`` and ``.srv`` files: Keyframe, KeyframeGraph,
TopicStatistics, ...), registered in the typestore from their text; no Python names yet."""

__all__: list[str] = []
