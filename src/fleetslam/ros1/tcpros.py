"""TCPROS framing (pure): connection headers and length-prefixed messages, with limits against hostile peers.

A connection header is a 4-byte little-endian length followed by fields, each a 4-byte length and
``key=value``. After the headers, every message is a 4-byte length and the ROS 1 serialised bytes.
"""

from __future__ import annotations

import socket
import struct

from fleetslam.errors import MiddlewareError

#: A header larger than this is refused (real ones are a few kB: the message definition dominates).
MAX_HEADER_BYTES = 1 << 20
#: A message larger than this closes the connection (a 4K RGB image is ~25 MB).
MAX_MESSAGE_BYTES = 256 << 20

_LEN = struct.Struct("<I")


class TcprosError(MiddlewareError):
    """A TCPROS peer sent something that is not TCPROS, or closed the connection."""


def encode_header(fields: dict[str, str]) -> bytes:
    body = b"".join(_LEN.pack(len(item)) + item for item in (f"{k}={v}".encode() for k, v in fields.items()))
    return _LEN.pack(len(body)) + body


def decode_header_body(body: bytes) -> dict[str, str]:
    """Fields of a header body (without its leading length); raises :class:`TcprosError` naming the fault."""
    fields: dict[str, str] = {}
    offset = 0
    while offset < len(body):
        if offset + 4 > len(body):
            raise TcprosError(f"TCPROS header truncated: field length at byte {offset} of {len(body)}")
        (size,) = _LEN.unpack_from(body, offset)
        offset += 4
        if offset + size > len(body):
            raise TcprosError(f"TCPROS header field of {size} bytes overruns the header ({len(body)} bytes)")
        item = body[offset : offset + size]
        offset += size
        key, sep, value = item.partition(b"=")
        if not sep:
            raise TcprosError(f"TCPROS header field without '=': {item[:40]!r}")
        try:
            fields[key.decode()] = value.decode()
        except UnicodeDecodeError as err:
            raise TcprosError(f"TCPROS header field is not UTF-8: {item[:40]!r}") from err
    return fields


def recv_exact(sock: socket.socket, size: int) -> bytes:
    buf = bytearray(size)
    view = memoryview(buf)
    got = 0
    while got < size:
        n = sock.recv_into(view[got:], size - got)
        if n == 0:
            raise TcprosError(f"TCPROS peer closed the connection ({got} of {size} bytes read)")
        got += n
    return bytes(buf)


def _recv_length(sock: socket.socket, limit: int, what: str) -> int:
    (size,) = _LEN.unpack(recv_exact(sock, 4))
    if size > limit:
        raise TcprosError(f"TCPROS {what} of {size} bytes exceeds the limit of {limit}")
    return int(size)


def recv_header(sock: socket.socket) -> dict[str, str]:
    return decode_header_body(recv_exact(sock, _recv_length(sock, MAX_HEADER_BYTES, "header")))


def recv_message(sock: socket.socket, limit: int = MAX_MESSAGE_BYTES) -> bytes:
    return recv_exact(sock, _recv_length(sock, limit, "message"))


def frame(payload: bytes | memoryview) -> bytes:
    return _LEN.pack(len(payload)) + bytes(payload)
