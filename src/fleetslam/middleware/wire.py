"""rmw_zenoh's wire format: key expressions, attachments, GIDs, liveliness tokens and the QoS string.

Pure functions, no Zenoh session. Follows rmw_zenoh Jazzy ≥ 0.2.4 / Kilted / Rolling
(see docs and `shared/specs/rmw_zenoh_wire.md`):

- data key ``<domain>/<name without leading/trailing '/'>/<pkg>::<msg|srv>::dds_::<Type>_/RIHS01_<hash>``;
- attachment: int64 LE sequence number (from 1), int64 LE source timestamp (ns since the epoch), the LEB128
  length 16, then the 16-byte GID; the GID is XXH3-128 of the entity's liveliness key (low64 LE, high64 LE);
- liveliness tokens ``@ros2_lv/<dom>/<zid>/<nid>/<eid>/<KIND>/<enclave>/<ns>/<node>[/<topic>/<type>/<hash>/<qos>]``
  with every ``/`` inside a chunk mangled to ``%``.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass, field
from typing import Literal

import xxhash

from fleetslam.errors import MessageError, MiddlewareError

ATTACHMENT_SIZE = 33
LIVELINESS_PREFIX = "@ros2_lv"

# rmw_zenoh's defaults: a QoS field equal to one of these is left empty in the token.
_DEFAULT_DEPTH = 42
_INFINITE_SEC = 9223372036
_INFINITE_NSEC = 854775807


# -- attachments -----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Attachment:
    """The metadata rmw_zenoh attaches to every sample, query and reply."""

    sequence_number: int
    source_timestamp_ns: int
    gid: bytes


def encode_attachment(sequence_number: int, source_timestamp_ns: int, gid: bytes) -> bytes:
    """The 33-byte attachment."""
    if len(gid) != 16:
        raise MessageError(f"attachment GID must be 16 bytes, got {len(gid)}")
    try:
        return struct.pack("<qqB", sequence_number, source_timestamp_ns, 16) + bytes(gid)
    except struct.error as err:
        raise MessageError(
            f"attachment sequence number {sequence_number} / timestamp {source_timestamp_ns} must fit int64: {err}"
        ) from err


_LABELS = (b"sequence_number", b"source_timestamp", b"source_gid")


def _read_leb128(data: bytes, offset: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        if offset >= len(data):
            raise MessageError("attachment truncated inside a length prefix")
        byte = data[offset]
        offset += 1
        value |= (byte & 0x7F) << shift
        if not byte & 0x80:
            return value, offset
        shift += 7


def _decode_labelled(data: bytes) -> Attachment:
    """Jazzy 0.2.0–0.2.3: each field is preceded by its zenoh-serialized string label."""
    offset = 0
    values: list[bytes] = []
    for label, size in zip(_LABELS, (8, 8, None), strict=True):
        length, offset = _read_leb128(data, offset)
        if data[offset : offset + length] != label:
            raise MessageError(f"labelled attachment: expected label {label.decode()!r} at byte {offset}")
        offset += length
        if size is None:
            size, offset = _read_leb128(data, offset)
        values.append(data[offset : offset + size])
        offset += size
    if len(values[2]) != 16 or offset != len(data):
        raise MessageError(f"labelled attachment of {len(data)} bytes is malformed")
    seq, stamp = struct.unpack("<q", values[0])[0], struct.unpack("<q", values[1])[0]
    return Attachment(seq, stamp, values[2])


def decode_attachment(data: bytes | memoryview) -> Attachment:
    """Parse an attachment; also accepts the labelled form of Jazzy 0.2.0–0.2.3."""
    raw = bytes(data)
    if len(raw) == ATTACHMENT_SIZE:
        seq, stamp, gid_len = struct.unpack_from("<qqB", raw)
        if gid_len != 16:
            raise MessageError(f"attachment GID length is {gid_len}, must be 16")
        return Attachment(seq, stamp, raw[17:])
    if raw[:1] == bytes([len(_LABELS[0])]) and raw[1 : 1 + len(_LABELS[0])] == _LABELS[0]:
        return _decode_labelled(raw)
    raise MessageError(f"attachment of {len(raw)} bytes, expected {ATTACHMENT_SIZE}")


def gid_from_key(liveliness_key: str) -> bytes:
    """GID of an entity: XXH3-128 (seed 0) of its liveliness key, low 64 bits first, little-endian."""
    return int(xxhash.xxh3_128_intdigest(liveliness_key.encode())).to_bytes(16, "little")


# -- names in keys ------------------------------------------------------------------------------------------
def mangle(name: str) -> str:
    """A name as one key chunk: every ``/`` becomes ``%``."""
    return name.replace("/", "%")


def demangle(chunk: str) -> str:
    """Inverse of :func:`mangle`."""
    return chunk.replace("%", "/")


def strip_name(fq_name: str) -> str:
    """A fully qualified name without its leading and trailing ``/`` (inner ones stay)."""
    return fq_name.strip("/")


def topic_key(domain_id: int, fq_name: str, type_name: str) -> str:
    """Data key expression of a topic or service, e.g. ``0/chatter/std_msgs::msg::dds_::String_/RIHS01_…``."""
    from fleetslam.msg.typesys import dds_type_name, type_hash

    return f"{domain_id}/{strip_name(fq_name)}/{dds_type_name(type_name)}/{type_hash(type_name)}"


def topic_key_expr_any_type(domain_id: int, fq_name: str) -> str:
    """Key expression matching a topic of any type (for tools that learn the type from the sample)."""
    return f"{domain_id}/{strip_name(fq_name)}/*/*"


topic_key_any_type = topic_key_expr_any_type


def parse_topic_key(key: str) -> tuple[int, str, str, str]:
    """``(domain_id, fq_name, type_name, type_hash)`` of a data key."""
    from fleetslam.msg.typesys import ros_type_name

    parts = key.split("/")
    if len(parts) < 4 or not parts[0].isdigit():
        raise MessageError(f"'{key}' is not an rmw_zenoh data key <domain>/<name>/<type>/<hash>")
    return int(parts[0]), "/" + "/".join(parts[1:-2]), ros_type_name(parts[-2]), parts[-1]


# -- QoS ------------------------------------------------------------------------------------------------------
Reliability = Literal["reliable", "best_effort"]
Durability = Literal["volatile", "transient_local"]
History = Literal["keep_last", "keep_all"]
LivelinessPolicy = Literal["automatic", "manual_by_topic"]


_REL = {"reliable": "1", "best_effort": "2"}
_DUR = {"transient_local": "1", "volatile": "2"}
_HIST = {"keep_last": "1", "keep_all": "2"}
_LIV = {"automatic": "1", "manual_by_topic": "3"}


@dataclass(frozen=True)
class QoSProfile:
    """ROS 2 quality of service, as far as rmw_zenoh uses it (durations in ns; None = infinite)."""

    reliability: Reliability = "reliable"
    durability: Durability = "volatile"
    history: History = "keep_last"
    depth: int = 10
    deadline_ns: int | None = None
    lifespan_ns: int | None = None
    liveliness: LivelinessPolicy = "automatic"
    liveliness_lease_ns: int | None = None

    def __post_init__(self) -> None:
        choices = {"reliability": _REL, "durability": _DUR, "history": _HIST, "liveliness": _LIV}
        for name, table in choices.items():
            if getattr(self, name) not in table:
                raise MiddlewareError(f"QoS {name} {getattr(self, name)!r}: expected one of {sorted(table)}")
        if not isinstance(self.depth, int) or self.depth < 0:
            raise MiddlewareError(f"QoS depth must be an integer >= 0, got {self.depth!r}")
        for name in ("deadline_ns", "lifespan_ns", "liveliness_lease_ns"):
            value = getattr(self, name)
            if value is not None and (not isinstance(value, int) or value < 0):
                raise MiddlewareError(f"QoS {name} must be None (infinite) or an integer >= 0, got {value!r}")


def _duration_chunk(ns: int | None) -> str:
    if ns is None or ns == 0:
        return ","
    sec, nsec = divmod(ns, 1_000_000_000)
    if (sec, nsec) == (_INFINITE_SEC, _INFINITE_NSEC):
        return ","
    return f"{sec},{nsec}"


def _duration_from_chunk(chunk: str) -> int | None:
    sec_text, _, nsec_text = chunk.partition(",")
    sec = int(sec_text) if sec_text else _INFINITE_SEC
    nsec = int(nsec_text) if nsec_text else _INFINITE_NSEC
    if (sec, nsec) == (_INFINITE_SEC, _INFINITE_NSEC):
        return None
    return sec * 1_000_000_000 + nsec


def qos_to_token(qos: QoSProfile) -> str:
    """The QoS chunk of a liveliness token, e.g. depth 10 → ``::,10:,:,:,,``."""

    def code(table: dict[str, str], value: str, default: str) -> str:
        return "" if value == default else table[value]

    depth = "" if qos.depth in (0, _DEFAULT_DEPTH) else str(qos.depth)
    return ":".join(
        [
            code(_REL, qos.reliability, "reliable"),
            code(_DUR, qos.durability, "volatile"),
            f"{code(_HIST, qos.history, 'keep_last')},{depth}",
            _duration_chunk(qos.deadline_ns),
            _duration_chunk(qos.lifespan_ns),
            f"{code(_LIV, qos.liveliness, 'automatic')},{_duration_chunk(qos.liveliness_lease_ns)}",
        ]
    )


def qos_from_token(text: str) -> QoSProfile:
    """Parse a token's QoS chunk; raises MessageError when malformed."""
    parts = text.split(":")
    # R : D : H,depth : DLs,DLns : LSs,LSns : LV,LLs,LLns
    if [p.count(",") for p in parts] != [0, 0, 1, 1, 1, 2]:
        raise MessageError(f"QoS chunk {text!r}: expected the form R:D:H,depth:s,ns:s,ns:LV,s,ns")

    def decode(table: dict[str, str], value: str, default: str) -> str:
        if not value:
            return default
        for name, code in table.items():
            if code == value:
                return name
        raise ValueError(f"unknown code {value!r}")

    try:
        history_code, _, depth_text = parts[2].partition(",")
        liveliness_code, _, lease = parts[5].partition(",")
        return QoSProfile(
            reliability=decode(_REL, parts[0], "reliable"),  # type: ignore[arg-type]
            durability=decode(_DUR, parts[1], "volatile"),  # type: ignore[arg-type]
            history=decode(_HIST, history_code, "keep_last"),  # type: ignore[arg-type]
            depth=int(depth_text) if depth_text else _DEFAULT_DEPTH,
            deadline_ns=_duration_from_chunk(parts[3]),
            lifespan_ns=_duration_from_chunk(parts[4]),
            liveliness=decode(_LIV, liveliness_code, "automatic"),  # type: ignore[arg-type]
            liveliness_lease_ns=_duration_from_chunk(lease),
        )
    except (ValueError, MiddlewareError) as err:
        raise MessageError(f"QoS chunk {text!r}: {err}") from err


# -- liveliness tokens -------------------------------------------------------------------------------------------
class EntityKind(enum.StrEnum):
    """Kinds of graph entities and their token codes."""

    NODE = "NN"
    PUBLISHER = "MP"
    SUBSCRIBER = "MS"
    SERVICE = "SS"
    CLIENT = "SC"


@dataclass(frozen=True)
class LivelinessToken:
    """A graph entity as announced by its liveliness token."""

    domain_id: int
    zid: str
    nid: int
    eid: int
    kind: EntityKind
    namespace: str
    node_name: str
    enclave: str = "/"
    topic: str = ""
    """Fully qualified topic or service name ('' for nodes)."""
    type_name: str = ""
    """ROS type name, e.g. std_msgs/msg/String ('' for nodes)."""
    type_hash: str = ""
    qos: QoSProfile = field(default_factory=QoSProfile)

    def key(self) -> str:
        """The token's key expression."""
        head = [LIVELINESS_PREFIX, str(self.domain_id), self.zid, str(self.nid), str(self.eid), self.kind.value]
        chunks = [*head, mangle(self.enclave), mangle(self.namespace), self.node_name]
        if self.kind is not EntityKind.NODE:
            from fleetslam.msg.typesys import dds_type_name

            chunks += [mangle(self.topic), dds_type_name(self.type_name), self.type_hash, qos_to_token(self.qos)]
        if any(not c for c in chunks):
            raise MessageError(f"liveliness token {chunks} has an empty chunk")
        return "/".join(chunks)

    @property
    def gid(self) -> bytes:
        """GID every observer computes from the key."""
        return gid_from_key(self.key())

    @property
    def node_fq_name(self) -> str:
        """The node's fully qualified name, e.g. ``/c3po/slam``."""
        return f"{self.namespace.rstrip('/')}/{self.node_name}"

    @classmethod
    def parse(cls, key: str) -> LivelinessToken:
        """Parse a token key; raises MessageError when it is not one."""
        from fleetslam.msg.typesys import ros_type_name

        parts = key.split("/")
        if len(parts) < 9 or parts[0] != LIVELINESS_PREFIX:
            raise MessageError(f"'{key}' is not an rmw_zenoh liveliness token")
        if not all(parts):
            raise MessageError(f"liveliness token '{key}' has an empty chunk")
        for index, what in ((1, "domain id"), (3, "node id"), (4, "entity id")):
            if not (parts[index].isascii() and parts[index].isdigit()):
                raise MessageError(f"liveliness token '{key}': {what} {parts[index]!r} is not a decimal number")
        try:
            kind = EntityKind(parts[5])
        except ValueError as err:
            raise MessageError(f"liveliness token '{key}': unknown entity kind {parts[5]!r}") from err
        domain_id, nid, eid = int(parts[1]), int(parts[3]), int(parts[4])
        common = {
            "domain_id": domain_id,
            "zid": parts[2],
            "nid": nid,
            "eid": eid,
            "kind": kind,
            "enclave": demangle(parts[6]),
            "namespace": demangle(parts[7]),
            "node_name": parts[8],
        }
        if kind is EntityKind.NODE:
            if len(parts) != 9:
                raise MessageError(f"node token '{key}' has {len(parts)} chunks, expected 9")
            return cls(**common)  # type: ignore[arg-type]
        if len(parts) not in (13, 14):  # 14: Lyrical/Rolling's optional backends chunk
            raise MessageError(f"entity token '{key}' has {len(parts)} chunks, expected 13")
        return cls(
            **common,  # type: ignore[arg-type]
            topic=demangle(parts[9]),
            type_name=ros_type_name(parts[10]),
            type_hash=parts[11],
            qos=qos_from_token(parts[12]),
        )
