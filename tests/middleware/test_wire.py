import pytest

from fleetslam.errors import MessageError, MiddlewareError
from fleetslam.middleware.wire import (
    Attachment,
    EntityKind,
    LivelinessToken,
    QoSProfile,
    decode_attachment,
    demangle,
    encode_attachment,
    gid_from_key,
    mangle,
    parse_topic_key,
    qos_from_token,
    qos_to_token,
    topic_key,
    topic_key_expr_any_type,
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


def test_spec_service_and_image_keys() -> None:
    assert topic_key(2, "/add_two_ints", "example_interfaces/srv/AddTwoInts") == (
        "2/add_two_ints/example_interfaces::srv::dds_::AddTwoInts_/"
        "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a"
    )
    assert topic_key(0, "/camera/image_raw", "sensor_msgs/msg/Image") == (
        "0/camera/image_raw/sensor_msgs::msg::dds_::Image_/"
        "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47"
    )
    assert topic_key_expr_any_type(0, "/c3po/odom") == "0/c3po/odom/*/*"
    with pytest.raises(MessageError):
        parse_topic_key("x/chatter")


def test_attachment_encoding_errors() -> None:
    with pytest.raises(MessageError, match="16 bytes"):
        encode_attachment(1, 0, b"\x00" * 15)
    with pytest.raises(MessageError, match="int64"):
        encode_attachment(2**63, 0, b"\x00" * 16)
    # Negative values are representable (rmw rejects them only for services).
    assert decode_attachment(encode_attachment(-1, -2, b"\x01" * 16)) == Attachment(-1, -2, b"\x01" * 16)


def test_truncated_labelled_attachment_is_rejected() -> None:
    data = bytes([15]) + b"sequence_number" + b"\x01\x00"
    with pytest.raises(MessageError):
        decode_attachment(data)


def test_mangling() -> None:
    assert mangle("/robot1/chatter") == "%robot1%chatter" and demangle("%robot1%chatter") == "/robot1/chatter"
    assert mangle("/") == "%"


@pytest.mark.parametrize("kind", [EntityKind.PUBLISHER, EntityKind.SUBSCRIBER, EntityKind.SERVICE, EntityKind.CLIENT])
def test_entity_tokens_round_trip(kind: EntityKind) -> None:
    from fleetslam.msg.typesys import type_hash

    type_name = "std_srvs/srv/Trigger" if kind in (EntityKind.SERVICE, EntityKind.CLIENT) else "sensor_msgs/msg/Image"
    token = LivelinessToken(
        domain_id=7, zid="aac3178e146ba6f1fc6e6a4085e77f21", nid=3, eid=9, kind=kind, namespace="/c3po",
        node_name="slam", topic="/c3po/camera/image", type_name=type_name, type_hash=type_hash(type_name),
        qos=QoSProfile(reliability="best_effort", durability="transient_local", depth=1),
    )  # fmt: skip
    key = token.key()
    assert key.startswith(
        f"@ros2_lv/7/aac3178e146ba6f1fc6e6a4085e77f21/3/9/{kind.value}/%/%c3po/slam/%c3po%camera%image/"
    )
    assert LivelinessToken.parse(key) == token
    assert token.gid == gid_from_key(key) and len(token.gid) == 16
    assert token.node_fq_name == "/c3po/slam"


def test_node_token_round_trip() -> None:
    node = LivelinessToken(
        domain_id=0, zid="ab12", nid=4, eid=4, kind=EntityKind.NODE, namespace="/r2d2", node_name="b"
    )
    assert node.key() == "@ros2_lv/0/ab12/4/4/NN/%/%r2d2/b"
    assert LivelinessToken.parse(node.key()) == node


@pytest.mark.parametrize(
    "key",
    [
        "@ros2_lv/0//0/0/NN/%/%/n",  # empty zid
        "@ros2_lv/0/z/x/0/NN/%/%/n",  # node id not a number
        "@ros2_lv/-1/z/0/0/NN/%/%/n",  # negative domain
        "@ros2_lv/0/z/0/0/NN/%/%/n/extra",  # a node token with entity chunks
        "@ros2_lv/0/z/0/1/MP/%/%/n/%chatter/std_msgs::msg::dds_::String_/RIHS01_x",  # no QoS chunk
        "@ros2_lv/0/z/0/1/MP/%/%/n/%chatter/std_msgs/String/RIHS01_x/::,10:,:,:,,",  # not a DDS type name
        "@ros2_lv/0/z/0/1/MP/%/%/n/%chatter/std_msgs::msg::dds_::String_/RIHS01_x/9::,10:,:,:,,",  # bad QoS
    ],
)
def test_malformed_tokens(key: str) -> None:
    with pytest.raises(MessageError):
        LivelinessToken.parse(key)


def test_token_with_empty_chunk_cannot_be_built() -> None:
    token = LivelinessToken(domain_id=0, zid="z", nid=0, eid=1, kind=EntityKind.PUBLISHER, namespace="/", node_name="n")
    with pytest.raises(MessageError):
        token.key()  # an entity token needs a topic, type and hash


@pytest.mark.parametrize("text", ["", "::,10:,:,:", "::,ten:,:,:,,", "::3,10:,:,:,,", "::,-1:,:,:,,", ":::,:,:,,"])
def test_malformed_qos_chunks(text: str) -> None:
    with pytest.raises(MessageError, match="QoS chunk"):
        qos_from_token(text)


def test_qos_defaults_and_validation() -> None:
    # rmw writes depth 0 as its default 42, and a default-valued field as empty.
    assert qos_to_token(QoSProfile(depth=0)) == "::,:,:,:,,"
    assert qos_from_token("::,:,:,:,,").depth == 42
    lease = QoSProfile(liveliness="manual_by_topic", liveliness_lease_ns=2_000_000_001, lifespan_ns=7)
    assert qos_to_token(lease) == "::,10:,:0,7:3,2,1"
    assert qos_from_token(qos_to_token(lease)) == lease
    for bad in ({"reliability": "sometimes"}, {"depth": -1}, {"deadline_ns": -5}, {"history": "all"}):
        with pytest.raises(MiddlewareError):
            QoSProfile(**bad)  # type: ignore[arg-type]
