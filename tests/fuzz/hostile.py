"""Hostile samples for every subscribed topic of running nodes (issue 18, item 4), and the replay over a router.

For each subscription of each node under test (found from the nodes themselves, so a new subscription is fuzzed
without being listed here) the payloads are made from a valid message of the topic's type: random bytes,
truncations, bit flips, CDR lengths that lie (a 4-byte length set huge or negative), a valid message of another type,
and valid messages with bad attachments (missing, short, garbage, forged GIDs, stamps far in the future or past).
Used by ``tests/fuzz`` (bounded count, CI) and ``benchmarks/fuzz_nodes.py`` (>= 100,000).
"""

from __future__ import annotations

import struct
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np
import zenoh

from fleetslam.middleware import Node
from fleetslam.middleware.wire import encode_attachment, topic_key
from fleetslam.msg.typesys import message_from_dict, serialize

OTHER_TYPES = ("std_msgs/msg/String", "geometry_msgs/msg/Twist", "sensor_msgs/msg/Image", "nav_msgs/msg/Odometry")
KINDS = ("random", "truncated", "bitflip", "length_lie", "wrong_type", "bad_attachment")


@dataclass(frozen=True)
class Target:
    """One subscribed topic: where samples go and a valid payload of its type to mutate."""

    topic: str
    type_name: str
    valid: bytes


def targets(nodes: Sequence[Node], domain_id: int = 0) -> list[Target]:
    """Every typed subscription of the nodes (one target per topic and type), /clock and /statistics included."""
    seen: dict[tuple[str, str], Target] = {}
    for node in nodes:
        for subscription in node._subscriptions:
            if subscription.any_type or (subscription.topic, subscription.type_name) in seen:
                continue
            valid = serialize(message_from_dict(subscription.type_name, {}), subscription.type_name)
            seen[(subscription.topic, subscription.type_name)] = Target(subscription.topic, subscription.type_name,
                                                                        bytes(valid))  # fmt: skip
    return list(seen.values())


def _mutate(kind: str, valid: bytes, rng: np.random.Generator) -> bytes:
    if kind == "random":
        return rng.bytes(int(rng.integers(0, 512)))
    if kind == "truncated":
        return valid[: int(rng.integers(0, max(1, len(valid))))]
    if kind == "bitflip":
        data = bytearray(valid)
        for _ in range(int(rng.integers(1, 9))):
            index = int(rng.integers(0, len(data)))
            data[index] ^= 1 << int(rng.integers(0, 8))
        return bytes(data)
    if kind == "length_lie":
        data = bytearray(valid + bytes(8))
        offset = 4 + 4 * int(rng.integers(0, max(1, (len(data) - 8) // 4)))
        lie = int(rng.choice([0x7FFFFFFF, 0xFFFFFFFF, 0x10000000, len(data) * 3]))
        struct.pack_into("<I", data, offset, lie)
        return bytes(data)
    other = OTHER_TYPES[int(rng.integers(0, len(OTHER_TYPES)))]
    return bytes(serialize(message_from_dict(other, {}), other))


def _attachment(kind: str, sequence: int, rng: np.random.Generator) -> bytes | None:
    gid = rng.bytes(16)
    if kind != "bad_attachment":
        return encode_attachment(sequence, time.time_ns(), gid)
    choice = int(rng.integers(0, 5))
    if choice == 0:
        return None
    if choice == 1:
        return rng.bytes(int(rng.integers(0, 40)))
    if choice == 2:
        return encode_attachment(sequence, 2**62, gid)  # stamped far in the future
    if choice == 3:
        return encode_attachment(int(rng.integers(0, 2**63)), 0, gid)  # random sequence, epoch stamp
    return encode_attachment(sequence, time.time_ns(), bytes(16))


@dataclass
class Campaign:
    """What was sent, by kind."""

    sent: dict[str, int] = field(default_factory=lambda: dict.fromkeys(KINDS, 0))

    @property
    def total(self) -> int:
        return sum(self.sent.values())


def samples(targets_: Sequence[Target], count: int, seed: int = 0) -> Iterator[tuple[str, str, bytes, bytes | None]]:
    """``count`` hostile (kind, key, payload, attachment) samples spread over the targets and kinds."""
    rng = np.random.default_rng(seed)
    for sequence in range(count):
        target = targets_[sequence % len(targets_)]
        kind = KINDS[int(rng.integers(0, len(KINDS)))]
        payload = target.valid if kind == "bad_attachment" else _mutate(kind, target.valid, rng)
        yield kind, topic_key(0, target.topic, target.type_name), payload, _attachment(kind, sequence + 1, rng)


def replay(session: zenoh.Session, targets_: Sequence[Target], count: int, *, seed: int = 0,
           rate_hz: float = 5000.0) -> Campaign:  # fmt: skip
    """Send ``count`` hostile samples through ``session``, at most ``rate_hz`` (the nodes' queues drop the excess
    like any flood; the point is what each sample does, not the flood)."""
    campaign = Campaign()
    period = 1.0 / rate_hz
    next_put = time.monotonic()
    for kind, key, payload, attachment in samples(targets_, count, seed):
        session.put(key, payload, attachment=attachment)
        campaign.sent[kind] += 1
        next_put += period
        delay = next_put - time.monotonic()
        if delay > 0:
            time.sleep(delay)
    return campaign
