"""ROS 1 message and service types: rosbags' Noetic typestore plus what it lacks (tf2_msgs, our fleetslam_msgs, the
services of both sides), md5sums, definitions and the conversion between ROS 2 CDR and ROS 1 bytes.

Names: ROS 1 calls a type ``pkg/Name``; the fleet (ROS 2) calls it ``pkg/msg/Name`` (a service ``pkg/srv/Name``,
its request ``pkg/srv/Name_Request``, which ROS 1 calls ``pkg/NameRequest``). A service's md5sum is the md5 of
its request's and its response's md5 texts run together (genmsg's ``compute_md5``). Conversion goes through
a field-by-field copy between the two stores' dataclasses: same-named fields are copied (numeric arrays
shared, not copied; names that differ only in case, as CameraInfo's ``K``/``k``, are the same field), fields on
one side only are zeroed or dropped (Header.seq, Marker's ROS 2 additions).
"""

from __future__ import annotations

import hashlib
import threading
from dataclasses import dataclass
from importlib import resources
from typing import Any

from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from fleetslam.errors import MessageError
from fleetslam.msg import typesys

TF_MESSAGE = "geometry_msgs/TransformStamped[] transforms\n"

#: Services that exist in ROS 1 with the same definition as in the fleet: std_srvs' (Debian's python3-std-srvs)
#: and our own fleetslam_msgs services. The fleet's other services (example_interfaces, octomap_msgs) have no
#: ROS 1 counterpart here and are not bridged.
ROS1_SERVICES = ("std_srvs/srv/Empty", "std_srvs/srv/SetBool", "std_srvs/srv/Trigger")

_lock = threading.Lock()
_store: Typestore | None = None


@dataclass(frozen=True)
class Ros1Type:
    """What a TCPROS header needs to name a type."""

    ros1_name: str
    md5sum: str
    definition: str


@dataclass(frozen=True)
class Ros1ServiceType:
    """What a TCPROS service header names: the service type, its md5sum, and its request and response types."""

    name: str
    """The fleet's name, ``pkg/srv/Name``."""
    ros1_name: str
    md5sum: str
    request: Ros1Type
    response: Ros1Type

    @property
    def request_name(self) -> str:
        return f"{self.name}_Request"

    @property
    def response_name(self) -> str:
        return f"{self.name}_Response"


def ros1_name(ros2_name: str) -> str:
    """``pkg/msg/Name`` -> ``pkg/Name``."""
    pkg, _, name = ros2_name.rpartition("/")
    return f"{pkg.split('/')[0]}/{name}"


def ros2_name(name: str) -> str:
    """``pkg/Name`` (or already ``pkg/msg/Name``) -> ``pkg/msg/Name``."""
    parts = name.split("/")
    if len(parts) == 3:
        return name
    if len(parts) != 2 or not all(parts):
        raise MessageError(f"not a ROS 1 message type name: {name!r} (expected pkg/Name)")
    return f"{parts[0]}/msg/{parts[1]}"


def ros2_service_name(name: str) -> str:
    """``pkg/Name`` (or already ``pkg/srv/Name``) -> ``pkg/srv/Name``."""
    parts = name.split("/")
    if len(parts) == 3 and parts[1] == "srv" and all(parts):
        return name
    if len(parts) != 2 or not all(parts):
        raise MessageError(f"not a ROS 1 service type name: {name!r} (expected pkg/Name)")
    return f"{parts[0]}/srv/{parts[1]}"


def _service_texts() -> dict[str, str]:
    """``pkg/srv/Name`` -> .srv text of every service that ROS 1 knows as the fleet does."""
    texts = {name: typesys.STANDARD_SERVICES[name] for name in ROS1_SERVICES}
    for entry in resources.files("fleetslam.msg").iterdir():
        if entry.name.endswith(".srv"):
            texts[f"fleetslam_msgs/srv/{entry.name[:-4]}"] = entry.read_text(encoding="utf-8")
    return texts


def ros1_typestore() -> Typestore:
    """The shared Noetic typestore with tf2_msgs/TFMessage, fleetslam_msgs and the services registered."""
    global _store
    with _lock:
        if _store is None:
            store = get_typestore(Stores.ROS1_NOETIC)
            types = get_types_from_msg(TF_MESSAGE, "tf2_msgs/msg/TFMessage")
            for entry in resources.files("fleetslam.msg").iterdir():
                if entry.name.endswith(".msg"):
                    types.update(
                        get_types_from_msg(entry.read_text(encoding="utf-8"), f"fleetslam_msgs/msg/{entry.name[:-4]}")
                    )
            for name, text in _service_texts().items():
                request, response = typesys._split_service(text, name)
                types.update(typesys._parse_msg(request, f"{name}_Request"))
                types.update(typesys._parse_msg(response, f"{name}_Response"))
            store.register(types)
            _store = store
        return _store


def type_info(name: str) -> Ros1Type:
    """md5sum and full definition of a type (either naming), as ``rosmsg md5``/``gendeps --cat`` give them."""
    full = ros2_name(name)
    store = ros1_typestore()
    if full not in store.fielddefs:
        raise MessageError(f"type {full} is not known on the ROS 1 side")
    definition, md5sum = store.generate_msgdef(full, ros_version=1)
    return Ros1Type(ros1_name(full), md5sum, definition)


def _md5_text(store: Typestore, full: str) -> str:
    """genmsg's md5 text of a type: its definition's lines with every nested type replaced by that type's md5sum
    (rosbags computes it, but returns only its md5)."""
    subdefs: dict[str, tuple[str, str]] = {}
    definition, _ = store.gendefhash(full, subdefs, ros_version=1)
    md5_of = {ros1_name(sub): md5 for sub, (_, md5) in subdefs.items()}
    lines = []
    for line in definition.splitlines():
        type_name, _, rest = line.partition(" ")
        base = type_name.partition("[")[0]
        lines.append(f"{md5_of[base]} {rest}" if base in md5_of else line)
    return "\n".join(lines)


def service_info(name: str) -> Ros1ServiceType:
    """md5sum and request/response types of a service (either naming), as ``rossrv md5`` gives them; raises
    :class:`MessageError` for a service ROS 1 does not know (:data:`ROS1_SERVICES`, fleetslam_msgs)."""
    full = ros2_service_name(name)
    store = ros1_typestore()
    if f"{full}_Request" not in store.fielddefs:
        both = ", ".join(sorted(ros1_name(n) for n in _service_texts()))
        raise MessageError(
            f"service type {ros1_name(full)} is not one that ROS 1 and the fleet both define here ({both})"
        )
    texts = "".join(_md5_text(store, f"{full}{part}") for part in ("_Request", "_Response"))
    ros1 = ros1_name(full)
    parts = []
    for part in ("Request", "Response"):
        definition, md5sum = store.generate_msgdef(f"{full}_{part}", ros_version=1)
        parts.append(Ros1Type(f"{ros1}{part}", md5sum, definition))
    return Ros1ServiceType(full, ros1, hashlib.md5(texts.encode()).hexdigest(), parts[0], parts[1])


def _convert_value(value: Any, desc: Any, store: Typestore) -> Any:
    kind = desc[0]
    if kind == Nodetype.NAME:
        return _convert_struct(value, desc[1], store)
    if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE) and desc[1][0][0] == Nodetype.NAME:
        return [_convert_struct(item, desc[1][0][1], store) for item in value]
    return value  # base values and numeric arrays (numpy) are shared as they are


def _source_field(msg: Any, name: str) -> str | None:
    """The field of ``msg`` that fills ``name``: the same name, or the same letters in the other case (ROS 2
    lower-cased CameraInfo's ``D``, ``K``, ``R``, ``P`` and DisparityImage's ``T``); None when there is none."""
    if msg is None:
        return None
    for candidate in (name, name.upper(), name.lower()):
        if hasattr(msg, candidate):
            return candidate
    return None


def _convert_struct(msg: Any, type_name: str, store: Typestore) -> Any:
    """``msg`` (from the other store, or None) as ``type_name`` of ``store``: fields of the same name (up to case)
    are copied, fields that exist on one side only (Header.seq, ROS 2 additions) are dropped or zeroed."""
    kwargs = {}
    for name, desc in store.fielddefs[type_name][1]:
        source = _source_field(msg, name)
        kwargs[name] = (
            _convert_value(getattr(msg, source), desc, store)
            if source is not None
            else typesys._default_for(desc, store)  # the zero value ROS gives a missing field
        )
    return store.types[type_name](**kwargs)


def message_to_ros1(msg: Any, full: str) -> bytes:
    """A fleet message object (``pkg/msg/Name`` or a service's ``pkg/srv/Name_Request``) -> ROS 1 bytes."""
    store = ros1_typestore()
    try:
        return bytes(store.serialize_ros1(_convert_struct(msg, full, store), full))
    except MessageError:
        raise
    except Exception as err:  # rosbags raises assorted errors on values that do not fit the type
        raise MessageError(f"cannot convert a {full} to ROS 1: {err}") from err


def ros1_to_message(raw: bytes | memoryview, full: str) -> Any:
    """ROS 1 bytes -> a fleet message object of type ``full`` (as :func:`message_to_ros1` names it)."""
    try:
        msg = ros1_typestore().deserialize_ros1(bytes(raw), full)
        return _convert_struct(msg, full, typesys.get_typestore())
    except MessageError:
        raise
    except Exception as err:  # rosbags raises assorted errors on bytes that do not fit the type
        raise MessageError(f"cannot convert a {full} from ROS 1: {err}") from err


def cdr_to_ros1(cdr: bytes | memoryview, name: str) -> bytes:
    """ROS 2 CDR (with its encapsulation header) -> ROS 1 bytes."""
    full = ros2_name(name)
    store = ros1_typestore()
    try:
        msg = _convert_struct(typesys.deserialize(cdr, full), full, store)
        return bytes(store.serialize_ros1(msg, full))
    except MessageError:
        raise
    except Exception as err:  # rosbags raises assorted errors on values that do not fit the type
        raise MessageError(f"cannot convert a {full} from CDR to ROS 1: {err}") from err


def ros1_to_cdr(raw: bytes | memoryview, name: str) -> bytes:
    """ROS 1 bytes -> ROS 2 CDR (little-endian, with its encapsulation header)."""
    full = ros2_name(name)
    try:
        msg = ros1_typestore().deserialize_ros1(bytes(raw), full)
        return typesys.serialize(_convert_struct(msg, full, typesys.get_typestore()), full)
    except MessageError:
        raise
    except Exception as err:  # rosbags raises assorted errors on bytes that do not fit the type
        raise MessageError(f"cannot convert a {full} from ROS 1 to CDR: {err}") from err
