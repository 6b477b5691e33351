"""Loaned messages: an image's array written straight into the payload a publisher hands to Zenoh gives, once its
other fields are written around it, the bytes rosbags writes for the same message; a message that outgrew its loan
is published the usual way; types without a trailing byte array cannot be loaned."""

from collections.abc import Callable

import numpy as np
import pytest
import zenoh

from fleetslam.errors import MessageError
from fleetslam.middleware import Context, Node, QoSProfile
from fleetslam.msg.loan import fill_loan, loan_message
from fleetslam.msg.typesys import get_type, get_typestore, header, message_from_dict, serialize, trailing_array

from ..support import wait_until

IMAGE = "sensor_msgs/msg/Image"
LOANABLE = [
    (IMAGE, {"encoding": "rgb8", "height": 2, "width": 3, "step": 9, "is_bigendian": 1}),
    ("sensor_msgs/msg/PointCloud2", {"height": 1, "width": 9, "point_step": 2, "is_dense": True}),  # a field after
    ("std_msgs/msg/Int8MultiArray", {"layout": {"data_offset": 1}}),
]


def reference(msg: object, type_name: str) -> bytes:
    return bytes(get_typestore().serialize_cdr(msg, type_name))


@pytest.mark.parametrize(("type_name", "fields"), LOANABLE)
@pytest.mark.parametrize("frame_length", [1, 2, 3, 4, 5])  # every alignment of what follows the frame name
def test_a_loaned_array_filled_in_place_is_the_message_rosbags_writes(
    type_name: str, fields: dict, frame_length: int
) -> None:
    template = message_from_dict(type_name, fields)
    if hasattr(template, "header"):
        template.header = header("f" * frame_length, 1_700_000_000_000_000_001)
    trailing = trailing_array(type_name)
    assert trailing is not None
    loan = loan_message(template, type_name, 18 + frame_length)
    array = getattr(loan.message, trailing.field)
    assert array is loan.array and array.flags.writeable and not array.any()  # a new payload is zeroed
    assert np.shares_memory(array, np.frombuffer(loan.payload, np.uint8))  # it lies in the payload itself
    assert getattr(template, trailing.field).size == 0  # the template is left as it was
    for stamp_s in (5, 6):  # filled in place, fields changed, published again
        array[:] = np.arange(stamp_s, stamp_s + array.size) % 100
        if hasattr(loan.message, "header"):
            loan.message.header.stamp.sec = stamp_s
        assert fill_loan(loan, loan.message, type_name)
        same = message_from_dict(type_name, fields)
        same.__dict__.update({k: v for k, v in loan.message.__dict__.items() if k != trailing.field})
        setattr(same, trailing.field, array.copy())
        assert bytes(loan.payload) == reference(same, type_name)


def test_a_message_that_outgrew_its_loan_is_not_filled() -> None:
    template = message_from_dict(IMAGE, {"encoding": "mono8", "height": 1, "width": 4, "step": 4})
    template.header = header("cam", 0)
    loan = loan_message(template, IMAGE, 4)
    before = bytes(loan.payload)
    loan.message.header.frame_id = "camera_optical_frame"  # the array would have to move
    assert not fill_loan(loan, loan.message, IMAGE)
    loan.message.header.frame_id = "cam"
    loan.message.data = np.ones(4, np.uint8)  # another array than the loaned one
    assert not fill_loan(loan, loan.message, IMAGE)
    assert bytes(loan.payload) == before  # neither touched the payload
    other = message_from_dict(IMAGE, {"encoding": "mono8"})
    assert not fill_loan(loan, other, IMAGE)


def test_only_a_message_ending_in_a_byte_array_can_be_loaned() -> None:
    with pytest.raises(MessageError, match=r"std_msgs/msg/String.*does not end in a byte array"):
        loan_message(get_type("std_msgs/msg/String")(data="x"), "std_msgs/msg/String", 4)
    with pytest.raises(MessageError, match="not a sensor_msgs/msg/Image"):
        loan_message(message_from_dict("sensor_msgs/msg/CompressedImage", {}), IMAGE, 4)
    for count in (-1, 2.5, "4", True):
        with pytest.raises(MessageError, match=f"of {count!r} elements"):
            loan_message(message_from_dict(IMAGE, {}), IMAGE, count)  # type: ignore[arg-type]
    template = message_from_dict(IMAGE, {})
    template.width = -1  # a field rosbags cannot write
    with pytest.raises(MessageError, match="cannot serialize"):
        loan_message(template, IMAGE, 4)


def test_a_publisher_sends_its_loaned_frames_whole(
    make_context: Callable[..., Context], raw_session: zenoh.Session
) -> None:
    """Frames published through loans arrive as the CDR of what they held when published: the same loan published
    again with a new stamp, a second loan (the first's payload reused), and a loan that outgrew its payload (a
    longer frame name: published the usual way). A String publisher lends nothing."""
    node = Node("camera", context=make_context("c3po"), statistics_period_s=0)
    publisher = node.create_publisher(IMAGE, "image", QoSProfile(history="keep_all"))
    received: list[bytes] = []
    subscriber = raw_session.declare_subscriber(publisher.key, lambda s: received.append(s.payload.to_bytes()))
    try:
        wait_until(lambda: publisher._publisher.matching_status.matching, timeout_s=5.0)
        template = message_from_dict(IMAGE, {"encoding": "mono8", "height": 2, "width": 8, "step": 8})
        template.header = header("cam", 0)
        expected: list[bytes] = []

        def publish(msg: object) -> None:
            same = message_from_dict(IMAGE, {})
            same.__dict__.update(msg.__dict__)
            same.data = np.array(msg.data)  # type: ignore[attr-defined]
            expected.append(serialize(same, IMAGE))
            publisher.publish(msg)

        first = publisher.loan(template, 16)
        for second in (1, 2):
            first.data[:] = second
            first.header.stamp.sec = second
            publish(first)
        again = publisher.loan(template, 16)
        assert np.shares_memory(again.data, first.data)  # the published loan's payload, reused as it is
        again.data[:] = np.arange(16)
        publish(again)
        again.header = header("camera_optical_frame", 3)
        publish(again)
        wait_until(lambda: len(received) == len(expected), timeout_s=10.0)
        assert received == expected
    finally:
        subscriber.undeclare()
    strings = node.create_publisher("std_msgs/msg/String", "chatter", QoSProfile())
    with pytest.raises(MessageError, match="does not end in a byte array"):
        strings.loan(get_type("std_msgs/msg/String")(data="x"), 4)
