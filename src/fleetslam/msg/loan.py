"""Loaned messages: a message whose trailing byte array (an Image's ``data``) already lies in its CDR payload, so
that publishing it copies none of the array's bytes before Zenoh's own copy (ROS 2's loaned messages, for the
arrays that make up a camera frame or a point cloud).

A producer that can write into a given array (a camera driver's capture buffer, ``cv2.imdecode(..., dst=)``,
``np.copyto``, a renderer with an output buffer) fills the loaned array in place; the other fields (header, sizes,
encoding) are written around it when the message is published. Pure: no I/O, no middleware.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from fleetslam.errors import MessageError
from fleetslam.msg import typesys


class Loan(NamedTuple):
    """A loaned message and the payload it lies in."""

    message: Any
    """The message: a copy of the template whose trailing array is :attr:`array`."""
    payload: bytearray
    """The message's whole CDR payload (with its 4-byte header), as handed to Zenoh."""
    array: np.ndarray
    """The trailing array: a writable view on :attr:`payload`."""
    field: str
    """The message's field that holds :attr:`array`."""
    cut: int
    """Where the array's bytes start in :attr:`payload`."""


def _write_around(payload: bytearray, around: Any, cut: int) -> None:
    """Write a message's CDR without its array's bytes (``around``, see :func:`typesys.cdr_around_array`) into
    ``payload`` around the array: what precedes it at the start, what follows it at the end."""
    with memoryview(payload) as out, memoryview(around) as fields:
        out[:cut] = fields[:cut]
        out[len(out) - (len(around) - cut) :] = fields[cut:]


def loan_message(template: object, type_name: str, count: int, payload: bytearray | None = None) -> Loan:
    """A copy of ``template`` whose trailing byte array (see :func:`typesys.trailing_array`) is an array of
    ``count`` elements lying in a CDR payload of its own: zeroed in a new payload; ``payload``, when given and of
    the size needed, is reused as it is (the array holds what it held: nothing is cleared, the caller fills it; it
    must not be in use). The template's own array is ignored.

    Raises MessageError for a type without a trailing byte array, a template of another class, a negative count or
    fields that cannot be serialized."""
    trailing = typesys.trailing_array(type_name)
    if trailing is None:
        raise MessageError(f"cannot loan a {type_name}: the type does not end in a byte array")
    if (type(count) is not int and not isinstance(count, np.integer)) or count < 0:
        raise MessageError(f"cannot loan a {type_name} of {count!r} elements: want a count >= 0")
    count = int(count)
    around, cut = typesys.cdr_around_array(template, type_name, count)
    size = len(around) + count * trailing.dtype.itemsize
    if payload is None or len(payload) != size:
        payload = bytearray(size)
    _write_around(payload, around, cut)
    array = np.frombuffer(payload, trailing.dtype, count, cut)
    message = object.__new__(type(template))
    message.__dict__.update(template.__dict__)
    message.__dict__[trailing.field] = array
    return Loan(message, payload, array, trailing.field, cut)


def fill_loan(loan: Loan, message: object, type_name: str) -> bool:
    """Write ``message``'s fields around the loaned array into the loan's payload (the array's bytes untouched);
    False when the message no longer fits the loan and must be serialized as usual: its trailing array is not the
    loaned one (replaced), or the fields before it changed their CDR length (a longer ``frame_id`` or
    ``encoding``). Raises MessageError for fields that cannot be serialized."""
    if getattr(message, loan.field, None) is not loan.array:
        return False
    around, cut = typesys.cdr_around_array(message, type_name, loan.array.size)
    if cut != loan.cut or len(around) + loan.array.nbytes != len(loan.payload):
        return False
    _write_around(loan.payload, around, cut)
    return True
