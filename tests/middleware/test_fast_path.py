"""The fast paths: std_msgs/String's own CDR coder gives rosbags' bytes, messages and errors; a large trailing byte
array (Image, PointCloud2) joined to the rest of its CDR gives rosbags' bytes; and publishers number their samples
without a lock (one atomic counter) when several threads publish at once."""

import random
import struct
import threading
import time
from collections.abc import Callable

import numpy as np
import pytest
import zenoh

from fleetslam.errors import MessageError
from fleetslam.middleware import Context, MessageInfo, Node, QoSProfile
from fleetslam.msg.typesys import (
    SPLICE_MIN_BYTES,
    deserialize,
    ends_in_byte_array,
    get_type,
    get_typestore,
    header,
    message_from_dict,
    message_to_dict,
    serialize,
    serialize_buffer,
    serialize_payload,
)

from ..support import wait_until

STRING = "std_msgs/msg/String"
TEXTS = ["", "a", "ab", "abc", "abcd", "x" * 56, "é", "中文", "\U0001f600 robot", "nul\0inside", "\0"]


def decode(data: bytes | bytearray) -> tuple[str, object]:
    """What deserialize makes of data: ("ok", message) or ("error", its message)."""
    try:
        return "ok", deserialize(data, STRING)
    except MessageError as err:
        return "error", str(err)


@pytest.mark.parametrize("text", TEXTS)
def test_string_fast_path_writes_and_reads_what_rosbags_does(text: str) -> None:
    store = get_typestore()
    msg = get_type(STRING)(data=text)
    reference = bytes(store.serialize_cdr(msg, STRING))
    buffer = serialize_buffer(msg, STRING)
    assert isinstance(buffer, bytearray) and bytes(buffer) == reference
    assert serialize_payload(msg, STRING) == serialize(msg, STRING) == reference  # what a publisher sends
    assert deserialize(reference, STRING) == store.deserialize_cdr(reference, STRING) == msg
    for padding in range(6):  # CDR allows up to 3 bytes of padding after the last field, no more
        padded = reference + b"\0" * padding
        assert decode(padded) == decode(bytearray(padded))  # a bytearray takes the general decoder


def test_string_fast_path_rejects_what_the_general_decoder_rejects() -> None:
    reference = serialize(get_type(STRING)(data="héllo wörld"), STRING)
    rng = random.Random(7)
    accepted = rejected = 0
    for _ in range(5000):
        data = bytearray(reference)
        for _ in range(rng.randrange(1, 4)):
            edit = rng.randrange(3)
            if edit == 0 and data:
                data[rng.randrange(len(data))] = rng.randrange(256)
            elif edit == 1:
                del data[rng.randrange(len(data) + 1) :]
            else:
                data += bytes([rng.randrange(256)]) * rng.randrange(1, 5)
        fast, general = decode(bytes(data)), decode(data)
        assert fast == general, bytes(data)
        accepted += fast[0] == "ok"
        rejected += fast[0] == "error"
    assert accepted > 100 and rejected > 100  # both outcomes were exercised


def test_string_fast_path_keeps_rosbags_errors_for_a_wrong_field() -> None:
    with pytest.raises(MessageError, match="cannot serialize"):
        serialize_buffer(get_type(STRING)(data=7), STRING)


SPLICED = [  # types whose trailing byte array is joined on, with fields of each kind before (and after) it
    ("sensor_msgs/msg/Image", {"encoding": "mono8", "height": 3, "width": 5, "step": 5, "is_bigendian": 1}),
    ("sensor_msgs/msg/CompressedImage", {"format": "jpeg"}),
    ("sensor_msgs/msg/PointCloud2", {"height": 1, "is_bigendian": True, "point_step": 3, "is_dense": True}),
    ("std_msgs/msg/UInt8MultiArray", {"layout": {"dim": [{"label": "x", "size": 1, "stride": 1}], "data_offset": 3}}),
    ("std_msgs/msg/Int8MultiArray", {"layout": {"data_offset": 1}}),
]


@pytest.mark.parametrize(("type_name", "fields"), SPLICED)
@pytest.mark.parametrize("extra", [0, 1, 2, 3, 5, 7])  # every remainder of the array's length modulo 8
def test_large_byte_array_is_joined_into_the_bytes_rosbags_writes(type_name: str, fields: dict, extra: int) -> None:
    store = get_typestore()
    frame = "f" * (extra + 1)  # strings of each length before the array: every alignment of its length field
    rng = np.random.default_rng(extra)
    dtype = np.int8 if type_name.startswith("std_msgs/msg/Int8") else np.uint8
    data = rng.integers(-128 if dtype is np.int8 else 0, 128, SPLICE_MIN_BYTES + extra).astype(dtype)
    msg = message_from_dict(type_name, {**fields, "data": data})
    data = msg.data
    if hasattr(msg, "header"):
        msg.header = header(frame, 1_700_000_000_123_456_789)
    reference = bytes(store.serialize_cdr(msg, type_name))
    payload = serialize_payload(msg, type_name)
    assert type(payload) is bytes and payload == reference == serialize(msg, type_name)
    assert serialize_buffer(msg, type_name) == reference
    for scratch in (bytearray(), bytearray(b"x" * (len(reference) + 9)), bytearray(b"y" * len(reference))):
        written = serialize_payload(msg, type_name, scratch)  # grown, shrunk, or the right size
        assert written is scratch and written == reference
    assert ends_in_byte_array(type_name)
    assert msg.data is data  # the message is left as it was
    decoded = deserialize(payload, type_name)
    assert np.array_equal(decoded.data, data)
    assert message_to_dict(decoded) == message_to_dict(store.deserialize_cdr(reference, type_name))


def test_byte_arrays_not_joined_are_serialized_as_before() -> None:
    image = "sensor_msgs/msg/Image"
    msg = message_from_dict(image, {"encoding": "mono8", "data": np.arange(SPLICE_MIN_BYTES - 1, dtype=np.uint8)})
    assert type(serialize_payload(msg, image)) is bytearray  # small: the serializer's own buffer
    scratch = bytearray(b"kept")
    assert serialize_payload(msg, image, scratch) is not scratch and scratch == b"kept"  # small: scratch untouched
    assert not ends_in_byte_array(STRING) and not ends_in_byte_array("nav_msgs/msg/Odometry")
    for data in (  # large, but not a contiguous one-dimensional array of the field's dtype
        np.zeros((256, 512), np.uint8),
        np.zeros(2 * SPLICE_MIN_BYTES, np.uint8)[::2],
        np.zeros(SPLICE_MIN_BYTES, np.int8),
    ):
        msg.data = data
        try:
            expected: object = bytes(get_typestore().serialize_cdr(msg, image))
        except Exception as err:  # whatever rosbags raises, serialize_payload reports
            expected = type(err)
        try:
            got: object = serialize_payload(msg, image)
            assert type(got) is bytearray
            got = bytes(got)
        except MessageError as err:
            got = type(err.__cause__)
        assert got == expected


def test_large_byte_array_keeps_rosbags_errors_for_a_wrong_field() -> None:
    image = "sensor_msgs/msg/Image"
    msg = message_from_dict(image, {"data": np.zeros(SPLICE_MIN_BYTES, np.uint8)})
    msg.width = -1
    with pytest.raises(MessageError, match="cannot serialize"):
        serialize_payload(msg, image)


def test_a_publisher_reusing_its_buffer_sends_every_frame_as_it_was(
    make_context: Callable[..., Context], raw_session: zenoh.Session
) -> None:
    """Images of changing sizes (the buffer grows and shrinks), from two threads at once (one of them serializes
    into a new buffer): every sample that arrives is the CDR of the frame it carries, whole."""
    image = "sensor_msgs/msg/Image"
    node = Node("camera", context=make_context("c3po"), statistics_period_s=0)
    publisher = node.create_publisher(image, "image", QoSProfile(history="keep_all"))
    received: list[bytes] = []
    lock = threading.Lock()

    def on_sample(sample: zenoh.Sample) -> None:
        with lock:
            received.append(sample.payload.to_bytes())

    subscriber = raw_session.declare_subscriber(publisher.key, on_sample)
    try:
        wait_until(lambda: publisher._publisher.matching_status.matching, timeout_s=5.0)
        sizes = [SPLICE_MIN_BYTES * k + k for k in (4, 1, 3, 3, 2, 5, 1)]

        def frames(seed: int) -> list[object]:
            return [
                message_from_dict(image, {"encoding": "mono8", "height": 1, "width": n, "step": n,
                                          "data": np.full(n, (seed * 16 + i) % 256, np.uint8)})
                for i, n in enumerate(sizes)
            ]  # fmt: skip

        def publish_all(seed: int) -> None:
            for msg in frames(seed):
                publisher.publish(msg)

        threads = [threading.Thread(target=publish_all, args=(seed,)) for seed in (1, 2)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        wait_until(lambda: len(received) == 2 * len(sizes), timeout_s=10.0)
        expected = sorted(serialize(msg, image) for seed in (1, 2) for msg in frames(seed))
        assert sorted(received) == expected
    finally:
        subscriber.undeclare()


def test_publishers_number_samples_uniquely_from_many_threads(
    make_context: Callable[..., Context], raw_session: zenoh.Session
) -> None:
    node = Node("talker", context=make_context("c3po"), statistics_period_s=0)
    publisher = node.create_publisher(STRING, "chatter", QoSProfile(history="keep_all"))
    sequence_numbers: list[int] = []
    lock = threading.Lock()

    def on_sample(sample: zenoh.Sample) -> None:
        seq = struct.unpack_from("<q", sample.attachment.to_bytes())[0]  # type: ignore[union-attr]
        with lock:
            sequence_numbers.append(seq)

    subscriber = raw_session.declare_subscriber(publisher.key, on_sample)
    time.sleep(0.5)
    threads, each = 4, 500
    workers = [
        threading.Thread(target=lambda: [publisher.publish(get_type(STRING)(data="x")) for _ in range(each)])
        for _ in range(threads)
    ]
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join()
    assert wait_until(lambda: len(sequence_numbers) == threads * each, 20.0), len(sequence_numbers)
    assert sorted(sequence_numbers) == list(range(1, threads * each + 1))
    subscriber.undeclare()


@pytest.mark.parametrize("inline", [False, True])
def test_strings_arrive_decoded_with_their_info(make_context: Callable[..., Context], inline: bool) -> None:
    talker = Node("talker", context=make_context("c3po"), statistics_period_s=0)
    listener = Node("listener", context=make_context("c3po"), statistics_period_s=0)
    publisher = talker.create_publisher(STRING, "chatter", QoSProfile(history="keep_all"))
    got: list[tuple[str, MessageInfo]] = []
    sub = listener.create_subscription(
        STRING,
        "chatter",
        lambda m, info: got.append((m.data, info)),
        QoSProfile(history="keep_all"),
        inline=inline,
    )
    assert wait_until(lambda: publisher.matched_subscriptions == 1, 10.0)
    time.sleep(0.3)
    for text in TEXTS:
        publisher.publish(get_type(STRING)(data=text))
    assert wait_until(lambda: len(got) == len(TEXTS), 10.0)
    assert [text for text, _ in got] == TEXTS
    infos = [info for _, info in got]
    assert [i.sequence_number for i in infos] == list(range(1, len(TEXTS) + 1))
    assert all(i.publisher_gid == publisher.gid and i.topic == "/c3po/chatter" for i in infos)
    assert all(i.type_name == STRING and i.received_timestamp_ns >= i.source_timestamp_ns for i in infos)
    assert [i.size for i in infos] == [len(serialize(get_type(STRING)(data=t), STRING)) for t in TEXTS]
    assert isinstance(infos[0], MessageInfo) and infos[0]._fields[0] == "source_timestamp_ns"
    assert sub.statistics.total_delivered == len(TEXTS) and sub.statistics.total_dropped == 0


IMAGE = "sensor_msgs/msg/Image"


def decode_image(data: bytes | bytearray) -> tuple[str, object]:
    """What deserialize makes of an Image's CDR: ("ok", its fields with the data as bytes) or ("error", message)."""
    try:
        msg = deserialize(data, IMAGE)
    except MessageError as err:
        return "error", str(err)
    fields = message_to_dict(msg)
    return "ok", ({**fields, "data": bytes(np.asarray(msg.data))}, type(msg).__name__, msg.data.dtype)


@pytest.mark.parametrize("frame", ["", "c", "ca", "cam", "came", "camera_optical_frame", "é"])
@pytest.mark.parametrize("encoding", ["", "8", "rgb8", "mono16", "bayer_rggb8"])
def test_image_fast_path_reads_what_rosbags_does(frame: str, encoding: str) -> None:
    """Every alignment of the fields after the two strings, data lengths 0–9 and 64 KiB, padding 0–5 bytes: the
    fast path (bytes) gives what the general decoder (a bytearray) gives, message or error; its data is a read-only
    view on the payload, no copy."""
    store = get_typestore()
    for size in (*range(10), 1 << 16):
        msg = message_from_dict(IMAGE, {"header": {"stamp": {"sec": -5, "nanosec": 999_999_999}, "frame_id": frame},
                                        "height": 7, "width": 2**32 - 1, "encoding": encoding, "is_bigendian": 1,
                                        "step": 3, "data": np.arange(size, dtype=np.uint8)})  # fmt: skip
        reference = bytes(store.serialize_cdr(msg, IMAGE))
        decoded = deserialize(reference, IMAGE)
        assert decoded.data.base is reference and not decoded.data.flags.writeable
        assert message_to_dict(decoded) == message_to_dict(store.deserialize_cdr(reference, IMAGE))
        for padding in range(6):
            padded = reference + b"\0" * padding
            assert decode_image(padded) == decode_image(bytearray(padded))


def test_image_fast_path_rejects_what_the_general_decoder_rejects() -> None:
    """Truncated, overlong, big-endian, unterminated and randomly damaged Images: the same message or the same
    error either way."""
    msg = message_from_dict(IMAGE, {"header": {"frame_id": "cam"}, "encoding": "rgb8", "data": np.ones(12, np.uint8)})
    reference = serialize(msg, IMAGE)
    cases = [reference[:cut] for cut in range(len(reference))]
    cases += [b"\x00\x00" + reference[2:], reference[:12] + b"\x07" + reference[13:]]  # big-endian; no terminator
    rng = random.Random(7)
    for _ in range(2000):
        damaged = bytearray(reference)
        for _ in range(rng.randint(1, 3)):
            damaged[rng.randrange(len(damaged))] = rng.randrange(256)
        cases.append(bytes(damaged))
    for case in cases:
        assert decode_image(case) == decode_image(bytearray(case)), case.hex()


@pytest.mark.parametrize(
    ("where", "value"),
    [("frame_id", 5), ("frame_id", None), ("sec", 1.5), ("sec", 2**31), ("nanosec", -1), ("height", 2**32),
     ("encoding", b"rgb8"), ("is_bigendian", 256), ("is_bigendian", True), ("step", np.uint32(7)), ("width", "9")],
)  # fmt: skip
def test_image_fast_writer_writes_or_refuses_what_rosbags_does(where: str, value: object) -> None:
    """An Image's fields up to its data are written by a writer of its own: for odd values too, the bytes rosbags
    writes, or rosbags' refusal as a MessageError."""
    msg = message_from_dict(IMAGE, {"header": {"frame_id": "cam"}, "encoding": "rgb8", "height": 2, "width": 3,
                                    "step": 9, "data": np.ones(SPLICE_MIN_BYTES, np.uint8)})  # fmt: skip
    owner = msg.header if where == "frame_id" else msg.header.stamp if where in ("sec", "nanosec") else msg
    setattr(owner, where, value)
    try:
        expected: object = bytes(get_typestore().serialize_cdr(msg, IMAGE))
    except Exception as err:  # whatever rosbags raises, serialize_payload reports
        expected = type(err)
    try:
        got: object = bytes(serialize_payload(msg, IMAGE))
    except MessageError as err:
        got = type(err.__cause__)
    assert got == expected
