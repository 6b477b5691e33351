"""ROS 2 messages without ROS and without the middleware: our ``fleetslam_msgs`` definitions (the ``.msg`` and
``.srv`` files of this package), the process-wide typestore (ROS 2 Jazzy plus ours, built on first use) with CDR
and type hashes in :mod:`~fleetslam.msg.typesys`, and the conversions between messages and arrays in
:mod:`~fleetslam.msg.conversions`. Importing it does not import Zenoh: datasets, recordings and tools use it as
the middleware does.
"""

from fleetslam.msg.typesys import (
    deserialize,
    get_type,
    get_typestore,
    header,
    message_from_dict,
    message_to_dict,
    ns_from_stamp,
    serialize,
    stamp_from_ns,
)

__all__ = [
    "deserialize",
    "get_type",
    "get_typestore",
    "header",
    "message_from_dict",
    "message_to_dict",
    "ns_from_stamp",
    "serialize",
    "stamp_from_ns",
]
