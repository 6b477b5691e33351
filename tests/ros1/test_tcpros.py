"""TCPROS framing: headers round-trip; malformed ones fail with a message naming the fault."""

from __future__ import annotations

import socket
import struct

import pytest

from fleetslam.ros1 import tcpros


def test_header_round_trip_keeps_equals_signs_in_values() -> None:
    fields = {"topic": "/chatter", "md5sum": "*", "message_definition": "int32 A=1\nstring data\n"}
    data = tcpros.encode_header(fields)
    assert struct.unpack_from("<I", data)[0] == len(data) - 4
    assert tcpros.decode_header_body(data[4:]) == fields


@pytest.mark.parametrize(
    ("body", "fault"),
    [
        (b"\x01\x00", "field length at byte 0"),
        (b"\xff\x00\x00\x00topic=/a", "overruns the header"),
        (b"\x05\x00\x00\x00topic", "without '='"),
        (b"\x03\x00\x00\x00a=\xff", "not UTF-8"),
    ],
)
def test_malformed_headers_name_their_fault(body: bytes, fault: str) -> None:
    with pytest.raises(tcpros.TcprosError, match=fault):
        tcpros.decode_header_body(body)


def test_oversized_and_truncated_frames_are_refused() -> None:
    a, b = socket.socketpair()
    with a, b:
        a.sendall(struct.pack("<I", tcpros.MAX_HEADER_BYTES + 1))
        with pytest.raises(tcpros.TcprosError, match="exceeds the limit"):
            tcpros.recv_header(b)
        a.sendall(struct.pack("<I", 10) + b"abc")
        a.shutdown(socket.SHUT_WR)
        with pytest.raises(tcpros.TcprosError, match="closed the connection"):
            tcpros.recv_message(b)
