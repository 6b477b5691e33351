import pytest

from fleetslam.errors import MessageError
from fleetslam.middleware.wire import (
    EntityKind,
    LivelinessToken,
    QoSProfile,
    decode_attachment,
    encode_attachment,
    gid_from_key,
    parse_topic_key,
    qos_from_token,
    qos_to_token,
    topic_key,
)

STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
MS_TOKEN = (
    "@ros2_lv/0/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/"
    f"std_msgs::msg::dds_::String_/{STRING_HASH}/::,10:,:,:,,"
)


def test_spec_gid_and_attachment_vectors() -> None:
    gid = gid_from_key(MS_TOKEN)
    assert gid.hex() == "f15f21d2fafc22891bb0db868309bfcb"
    attachment = encode_attachment(1, 1700000000123456789, gid)
    assert attachment.hex() == "0100000000000000" + "15cd853dfe9c9717" + "10" + "f15f21d2fafc22891bb0db868309bfcb"
    decoded = decode_attachment(attachment)
    assert (decoded.sequence_number, decoded.source_timestamp_ns, decoded.gid) == (1, 1700000000123456789, gid)


def test_labelled_attachment_of_old_jazzy_is_accepted() -> None:
    def label(text: bytes) -> bytes:
        return bytes([len(text)]) + text

    gid = bytes(range(16))
    data = (
        label(b"sequence_number")
        + (5).to_bytes(8, "little")
        + label(b"source_timestamp")
        + (9).to_bytes(8, "little")
        + label(b"source_gid")
        + bytes([16])
        + gid
    )
    decoded = decode_attachment(data)
    assert (decoded.sequence_number, decoded.source_timestamp_ns, decoded.gid) == (5, 9, gid)


@pytest.mark.parametrize("data", [b"", b"\x01" * 32, b"\x01" * 16 + b"\x08" + b"\x00" * 16])
def test_bad_attachments(data: bytes) -> None:
    with pytest.raises(MessageError):
        decode_attachment(data)


def test_spec_keys() -> None:
    assert topic_key(0, "/chatter", "std_msgs/msg/String") == f"0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    assert topic_key(0, "/robot1/chatter", "std_msgs/msg/String").startswith("0/robot1/chatter/")
    assert parse_topic_key(topic_key(3, "/a/b/c", "sensor_msgs/msg/Image"))[:3] == (
        3,
        "/a/b/c",
        "sensor_msgs/msg/Image",
    )


def test_token_parse_and_key_round_trip() -> None:
    token = LivelinessToken.parse(MS_TOKEN)
    assert token.kind is EntityKind.SUBSCRIBER and token.topic == "/chatter" and token.qos.depth == 10
    assert token.key() == MS_TOKEN
    node = LivelinessToken(0, "aac3178e146ba6f1fc6e6a4085e77f21", 0, 0, EntityKind.NODE, "/", "listener")
    assert node.key() == "@ros2_lv/0/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
    nested = LivelinessToken(
        0, "ab", 1, 4, EntityKind.PUBLISHER, "/c3po", "slam", topic="/c3po/graph",
        type_name="fleetslam_msgs/msg/KeyframeGraph", type_hash="RIHS01_x", qos=QoSProfile(depth=5),
    )  # fmt: skip
    assert "/%c3po/slam/%c3po%graph/" in nested.key()
    assert LivelinessToken.parse(nested.key()) == nested
    assert LivelinessToken.parse(MS_TOKEN + "/backends:1:x").topic == "/chatter"


@pytest.mark.parametrize("key", ["@ros2_lv/0/z", "foo/0/z/0/0/NN/%/%/n", "@ros2_lv/0/z/0/0/XX/%/%/n"])
def test_bad_tokens(key: str) -> None:
    with pytest.raises(MessageError):
        LivelinessToken.parse(key)


@pytest.mark.parametrize(
    ("qos", "text"),
    [
        (QoSProfile(depth=10), "::,10:,:,:,,"),
        (QoSProfile(durability="transient_local", depth=1), ":1:,1:,:,:,,"),
        (QoSProfile(reliability="best_effort", depth=5), "2::,5:,:,:,,"),
        (QoSProfile(history="keep_all", depth=42), "::2,:,:,:,,"),
        (QoSProfile(depth=3, deadline_ns=1_500_000_000), "::,3:1,500000000:,:,,"),
    ],
)
def test_qos_strings(qos: QoSProfile, text: str) -> None:
    assert qos_to_token(qos) == text
    assert qos_from_token(text) == qos
