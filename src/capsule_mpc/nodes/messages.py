"""The wire messages of the rig and controller nodes: ROS 2 message types, serialised as CDR.

Each message is a ROS 2 ``.msg`` definition of the package ``capsule_mpc_msgs``, shipped in
``capsule_mpc/nodes/msg/`` (:data:`MSG_DIR`), and a dataclass here with the same fields:

================  =========================  =================================================
dataclass         type                       key (under the prefix, :mod:`.transport`)
================  =========================  =================================================
:class:`CameraFrame`  ``capsule_mpc_msgs/msg/CameraFrame``  ``frame``
:class:`ArmState`     ``capsule_mpc_msgs/msg/ArmState``     ``arm_state``
:class:`EpmCommand`   ``capsule_mpc_msgs/msg/EpmCommand``   ``cmd``
:class:`RunInfo`      ``capsule_mpc_msgs/msg/RunInfo``      ``run``
:class:`Event`        ``capsule_mpc_msgs/msg/Event``        ``events``
================  =========================  =================================================

Every message starts with a :class:`Header` (schema version, publisher id, sequence number, rig
time, wall-clock stamp, coordinate frame, run id). Units are SI; positions are in the ``plate``
frame (x, y on the plate; for the EPM the third coordinate is its height above the capsule plane).

The payload is what a ROS 2 node publishes for these types: the 4-byte CDR encapsulation header
(little-endian CDR) and the CDR body, made and read by ``mcap_ros2``'s dynamic encoders built from
the ``.msg`` text; the messages of every camera frame (:class:`CameraFrame`, :class:`ArmState`,
:class:`EpmCommand`) by hand-written codecs that give the same bytes. The dynamic encoder
fills a field it is not given with its default and reads a dict key named like a dict method as
the method, so every message is converted here from its dataclass with every field present
(:func:`encode` checks the fixed array sizes), and the field names avoid dict method names. The
schema version is the first byte of the CDR body: :func:`decode` reads it before the rest and
refuses another version (:class:`VersionError`).
"""

from __future__ import annotations

import dataclasses
import math
import re
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, TypeVar

import numpy as np
from mcap_ros2._dynamic import generate_dynamic, serialize_dynamic

from ..errors import CapsuleMPCError

__all__ = [
    "MSG_DIR",
    "PACKAGE",
    "PLATE_FRAME",
    "SCHEMA_VERSION",
    "ArmState",
    "CameraFrame",
    "EpmCommand",
    "Event",
    "Header",
    "MessageError",
    "RunInfo",
    "VersionError",
    "decode",
    "encode",
    "message_types",
    "peek_version",
    "schema_text",
    "wall_ns",
]

#: Version of the message schemas; a node drops messages of another version.
SCHEMA_VERSION = 3
#: The ROS 2 package of the message types.
PACKAGE = "capsule_mpc_msgs"
#: Name of the coordinate frame of every position: x, y on the plate, m (the EPM: and its height).
PLATE_FRAME = "plate"
#: The folder of the ``.msg`` definitions.
MSG_DIR = Path(__file__).parent / "msg"
#: Bytes of the CDR encapsulation header before the body.
_ENCAPSULATION = 4
#: Separator between the definitions of a concatenated ROS 2 schema.
_SEPARATOR = "=" * 80
#: One field line of a ``.msg`` file: type, optional array size, name (constants have an ``=``).
_FIELD = re.compile(r"^\s*([\w/]+)(\[(\d*)\])?\s+(\w+)\s*(#.*)?$")

M = TypeVar("M")


class MessageError(CapsuleMPCError, ValueError):
    """A payload that is not a valid message of the expected type."""


class VersionError(MessageError):
    """A message of another schema version (:data:`SCHEMA_VERSION`)."""

    def __init__(self, version: int) -> None:
        super().__init__(f"schema_version: expected {SCHEMA_VERSION}, got {version}")
        self.version = version


def wall_ns() -> int:
    """The wall-clock time now, ns since the UNIX epoch (the headers' ``stamp``)."""
    return time.time_ns()


@dataclass
class Header:
    """The first field of every message (``Header.msg``).

    Attributes
    ----------
    schema_version : int
        :data:`SCHEMA_VERSION` of the publisher.
    publisher_id : int
        Random id of the publisher, [0, 2**64); sequence numbers count per publisher.
    seq : int
        Sequence number of the message from its publisher, from 0.
    rig_time_s : float
        Rig time, s (0 is the start of the path).
    stamp_ns : int
        Wall-clock time of publication, ns since the UNIX epoch (``stamp`` on the wire).
    frame_id : str
        Coordinate frame of the message's positions (:data:`PLATE_FRAME`), "" if none.
    run_id : str
        The rig's run.
    """

    schema_version: int = SCHEMA_VERSION
    publisher_id: int = 0
    seq: int = 0
    rig_time_s: float = 0.0
    stamp_ns: int = 0
    frame_id: str = ""
    run_id: str = ""


def _nan2() -> np.ndarray:
    return np.full(2, math.nan)


def _nan3() -> np.ndarray:
    return np.full(3, math.nan)


def _none() -> np.ndarray:
    return np.zeros(0)


@dataclass
class CameraFrame:
    """One camera frame (``CameraFrame.msg``); ``header.rig_time_s`` is the delivery time."""

    TYPE: ClassVar[str] = "CameraFrame"
    header: Header = field(default_factory=Header)
    frame_index: int = 0
    capture_time_s: float = math.nan
    valid: bool = False
    position_m: np.ndarray = field(default_factory=_nan2)


@dataclass
class ArmState:
    """The arm at a camera frame (``ArmState.msg``): EPM pose, velocity, command, joints."""

    TYPE: ClassVar[str] = "ArmState"
    header: Header = field(default_factory=Header)
    frame_index: int = 0
    epm_position_m: np.ndarray = field(default_factory=_nan3)
    epm_velocity_mps: np.ndarray = field(default_factory=_nan3)
    epm_velocity_command_mps: np.ndarray = field(default_factory=_nan3)
    watchdog_active: bool = False
    joint_names: tuple[str, ...] = ()
    joint_positions_rad: np.ndarray = field(default_factory=_none)


@dataclass
class EpmCommand:
    """The controller's answer to one camera frame (``EpmCommand.msg``)."""

    TYPE: ClassVar[str] = "EpmCommand"
    header: Header = field(default_factory=Header)
    frame_seq: int = 0
    frame_index: int = 0
    velocity_mps: np.ndarray = field(default_factory=_nan3)
    outcome: str = "ok"
    status: str = ""
    phase: str = ""
    solve_ms: float = math.nan
    iterations: int = 0
    failed: bool = False
    finished: bool = True
    step_ms: float = math.nan
    extra_names: tuple[str, ...] = ()
    extra_values: np.ndarray = field(default_factory=_none)
    predicted_path_m: np.ndarray = field(default_factory=_none)


@dataclass
class RunInfo:
    """What a controller node needs to (re)start on the rig's run (``RunInfo.msg``)."""

    TYPE: ClassVar[str] = "RunInfo"
    header: Header = field(default_factory=Header)
    state: str = "starting"
    config_name: str = ""
    config_hash: str = ""
    config_sections: tuple[str, ...] = ()
    config_section_hashes: tuple[str, ...] = ()
    seed: int = 0
    plant_seed: int = 0
    camera_rate_hz: float = math.nan
    first_frame_index: int = 0
    path_waypoints_m: np.ndarray = field(default_factory=_none)
    path_closed: bool = False
    path_speed_mps: float = math.nan
    start_epm_position_m: np.ndarray = field(default_factory=_nan3)
    epm_position_m: np.ndarray = field(default_factory=_nan3)
    controller_node: str = ""


@dataclass
class Event:
    """Something a node logged and counted (``Event.msg``)."""

    TYPE: ClassVar[str] = "Event"
    header: Header = field(default_factory=Header)
    source: str = ""
    kind: str = ""
    detail: str = ""
    count: int = 0


_TYPES: tuple[type, ...] = (CameraFrame, ArmState, EpmCommand, RunInfo, Event)


def message_types() -> tuple[type, ...]:
    """The message dataclasses (one per ``.msg`` file but the header)."""
    return _TYPES


def _msg_text(name: str) -> str:
    return (MSG_DIR / f"{name}.msg").read_text(encoding="utf-8")


def schema_text(name: str) -> str:
    """The concatenated ROS 2 definition of message ``name`` (e.g. ``"CameraFrame"``), with its
    header's, as a ROS 2 bag or an MCAP file stores it."""
    return f"{_msg_text(name)}\n{_SEPARATOR}\nMSG: {PACKAGE}/Header\n{_msg_text('Header')}"


def _fields(name: str) -> dict[str, int | None]:
    """The fields of ``name``'s ``.msg`` file: name -> fixed array size (-1: unbounded; None: scalar)."""
    out: dict[str, int | None] = {}
    for line in _msg_text(name).splitlines():
        match = _FIELD.match(line)
        if match is None or "=" in line.split("#", 1)[0]:
            continue
        out[match.group(4)] = None if match.group(2) is None else int(match.group(3) or -1)
    return out


class _Codec:
    """The CDR encoder and decoder of one message type."""

    def __init__(self, cls: type) -> None:
        name = cls.TYPE  # type: ignore[attr-defined]
        full = f"{PACKAGE}/msg/{name}"
        text = schema_text(name)
        self.cls = cls
        self.encoder: Callable[[Any], bytes] = serialize_dynamic(full, text)[full]
        self.decoder: Callable[[bytes], Any] = generate_dynamic(full, text)[full]
        self.fields = _fields(name)
        mine = [f.name for f in dataclasses.fields(cls)]
        if mine != list(self.fields):
            raise TypeError(f"{cls.__name__}: fields {mine} differ from {name}.msg's {list(self.fields)}")

    def to_wire(self, msg: Any) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for name, size in self.fields.items():
            value = getattr(msg, name)
            if isinstance(value, Header):
                out[name] = _header_to_wire(value)
            elif size is not None:
                items = list(np.asarray(value).ravel().tolist())
                if size >= 0 and len(items) != size:
                    raise MessageError(
                        f"{self.cls.__name__}.{name}: must have {size} values, got {len(items)}"
                    )
                out[name] = items
            else:
                out[name] = value
        return out

    def from_wire(self, wire: Any) -> Any:
        values: dict[str, Any] = {}
        for f in dataclasses.fields(self.cls):
            value = getattr(wire, f.name)
            if f.name == "header":
                value = _header_from_wire(value)
            elif self.fields[f.name] is not None:
                value = np.asarray(value, dtype=float) if "ndarray" in str(f.type) else tuple(value)
            values[f.name] = value
        return self.cls(**values)


def _header_to_wire(h: Header) -> dict[str, Any]:
    sec, nanosec = divmod(int(h.stamp_ns), 1_000_000_000)
    return {
        "schema_version": h.schema_version,
        "publisher_id": h.publisher_id,
        "seq": h.seq,
        "rig_time_s": float(h.rig_time_s),
        "stamp": {"sec": sec, "nanosec": nanosec},
        "frame_id": h.frame_id,
        "run_id": h.run_id,
    }


def _header_from_wire(w: Any) -> Header:
    stamp_ns = int(w.stamp.sec) * 1_000_000_000 + int(w.stamp.nanosec)
    return Header(w.schema_version, w.publisher_id, w.seq, w.rig_time_s, stamp_ns, w.frame_id, w.run_id)


_CODECS: dict[type, _Codec] = {cls: _Codec(cls) for cls in _TYPES}


# -- the per-frame messages, hand-written ---------------------------------------------------------
# A frame, the arm state and the command cross the transport at every camera frame, on the path
# from a frame to its command; the dynamic codec interprets the .msg definition field by field in
# Python for each message, so these three are packed and unpacked here with precompiled
# ``struct.Struct`` layouts instead. They give the same bytes as the dynamic codec and read its
# bytes the same way (tests/test_nodes_messages.py checks both over the fields' ranges); the other
# messages use the dynamic codec. Offsets: CDR aligns each value to its size counted from the end
# of the encapsulation header, and an empty sequence adds no padding after its count.

#: Encapsulation, schema_version, padding, publisher_id, seq, rig_time_s, stamp sec and nanosec.
_HEAD = struct.Struct("<4sB7xQQdII")
_U32 = struct.Struct("<I")
#: CameraFrame after its header (8-aligned): frame_index, capture_time_s, valid, position_m.
_FRAME_TAIL = struct.Struct("<qdB7x2d")
#: ArmState after its header (8-aligned): frame_index, the three 3-vectors, watchdog_active.
_ARM_BODY = struct.Struct("<q9dB")
#: EpmCommand after its header (8-aligned): frame_seq, frame_index, velocity_mps.
_CMD_HEAD = struct.Struct("<Qq3d")
#: EpmCommand after its three strings (8-aligned): solve_ms, iterations, failed, finished, step_ms.
_CMD_STATS = struct.Struct("<diBB2xd")
_CDR_LE = b"\x00\x01\x00\x00"
_ZEROS = tuple(bytes(n) for n in range(8))
_NS = 1_000_000_000


def _pad(buf: bytearray, size: int) -> None:
    buf += _ZEROS[-(len(buf) - _ENCAPSULATION) % size]


def _put_str(buf: bytearray, value: str) -> None:
    data = str(value).encode()
    _pad(buf, 4)
    buf += _U32.pack(len(data) + 1)
    buf += data
    buf += b"\0"


def _put_strs(buf: bytearray, values: tuple[str, ...]) -> None:
    _pad(buf, 4)
    buf += _U32.pack(len(values))
    for value in values:
        _put_str(buf, value)


def _floats(cls: type, name: str, value: Any, size: int) -> np.ndarray:
    """``value`` as little-endian float64s, checked to have ``size`` values (-1: any number)."""
    arr = np.ascontiguousarray(value, dtype="<f8").ravel()
    if size >= 0 and arr.size != size:
        raise MessageError(f"{cls.__name__}.{name}: must have {size} values, got {arr.size}")
    return arr


def _put_floats(buf: bytearray, values: np.ndarray) -> None:
    """A float64 sequence: its count, then (8-aligned) its values."""
    _pad(buf, 4)
    buf += _U32.pack(values.size)
    if values.size:
        _pad(buf, 8)
        buf += values.tobytes()


def _put_header(h: Header) -> bytearray:
    sec, nanosec = divmod(int(h.stamp_ns), _NS)
    buf = bytearray(_HEAD.pack(_CDR_LE, h.schema_version, h.publisher_id, h.seq, h.rig_time_s, sec, nanosec))
    _put_str(buf, h.frame_id)
    _put_str(buf, h.run_id)
    _pad(buf, 8)
    return buf


def _encode_frame(msg: CameraFrame) -> bytes:
    x, y = _floats(CameraFrame, "position_m", msg.position_m, 2).tolist()
    buf = _put_header(msg.header)
    buf += _FRAME_TAIL.pack(msg.frame_index, msg.capture_time_s, 1 if msg.valid else 0, x, y)
    return bytes(buf)


def _encode_arm(msg: ArmState) -> bytes:
    xyz = [
        v
        for name in ("epm_position_m", "epm_velocity_mps", "epm_velocity_command_mps")
        for v in _floats(ArmState, name, getattr(msg, name), 3).tolist()
    ]
    joints = _floats(ArmState, "joint_positions_rad", msg.joint_positions_rad, -1)
    buf = _put_header(msg.header)
    buf += _ARM_BODY.pack(msg.frame_index, *xyz, 1 if msg.watchdog_active else 0)
    _put_strs(buf, msg.joint_names)
    _put_floats(buf, joints)
    return bytes(buf)


def _encode_command(msg: EpmCommand) -> bytes:
    vx, vy, vz = _floats(EpmCommand, "velocity_mps", msg.velocity_mps, 3).tolist()
    extra = _floats(EpmCommand, "extra_values", msg.extra_values, -1)
    path = _floats(EpmCommand, "predicted_path_m", msg.predicted_path_m, -1)
    buf = _put_header(msg.header)
    buf += _CMD_HEAD.pack(msg.frame_seq, msg.frame_index, vx, vy, vz)
    _put_str(buf, msg.outcome)
    _put_str(buf, msg.status)
    _put_str(buf, msg.phase)
    _pad(buf, 8)
    failed, finished = 1 if msg.failed else 0, 1 if msg.finished else 0
    buf += _CMD_STATS.pack(msg.solve_ms, msg.iterations, failed, finished, msg.step_ms)
    _put_strs(buf, msg.extra_names)
    _put_floats(buf, extra)
    _put_floats(buf, path)
    return bytes(buf)


def _aligned(off: int, size: int) -> int:
    return off + (-(off - _ENCAPSULATION) % size)


def _get_str(data: bytes, off: int) -> tuple[str, int]:
    """The string at ``off`` (4-aligned first) and the offset after it."""
    off = _aligned(off, 4)
    (n,) = _U32.unpack_from(data, off)
    off += 4
    if off + n > len(data):
        raise MessageError(f"a string of {n} bytes runs past the payload's end ({len(data)} bytes)")
    return ("" if n <= 1 else data[off : off + n - 1].decode()), off + n


def _get_strs(data: bytes, off: int) -> tuple[tuple[str, ...], int]:
    (n,) = _U32.unpack_from(data, _aligned(off, 4))
    off = _aligned(off, 4) + 4
    out = []
    for _ in range(n):
        value, off = _get_str(data, off)
        out.append(value)
    return tuple(out), off


def _get_floats(data: bytes, off: int) -> tuple[np.ndarray, int]:
    (n,) = _U32.unpack_from(data, _aligned(off, 4))
    off = _aligned(off, 4) + 4
    if not n:
        return np.zeros(0), off
    off = _aligned(off, 8)
    return np.frombuffer(data, "<f8", n, off).astype(float), off + 8 * n


def _get_header(data: bytes) -> tuple[Header, int]:
    _encap, version, publisher_id, seq, rig_time_s, sec, nanosec = _HEAD.unpack_from(data)
    frame_id, off = _get_str(data, _HEAD.size)
    run_id, off = _get_str(data, off)
    header = Header(version, publisher_id, seq, rig_time_s, sec * _NS + nanosec, frame_id, run_id)
    return header, _aligned(off, 8)


def _decode_frame(data: bytes) -> CameraFrame:
    header, off = _get_header(data)
    index, capture, valid, x, y = _FRAME_TAIL.unpack_from(data, off)
    return CameraFrame(header, index, capture, valid != 0, np.array([x, y]))


def _decode_arm(data: bytes) -> ArmState:
    header, off = _get_header(data)
    index, *vectors, watchdog = _ARM_BODY.unpack_from(data, off)
    names, off = _get_strs(data, off + _ARM_BODY.size)
    joints, _ = _get_floats(data, off)
    xyz = np.array(vectors).reshape(3, 3)
    return ArmState(header, index, xyz[0].copy(), xyz[1].copy(), xyz[2].copy(), watchdog != 0, names, joints)


def _decode_command(data: bytes) -> EpmCommand:
    header, off = _get_header(data)
    frame_seq, index, vx, vy, vz = _CMD_HEAD.unpack_from(data, off)
    outcome, off = _get_str(data, off + _CMD_HEAD.size)
    status, off = _get_str(data, off)
    phase, off = _get_str(data, off)
    off = _aligned(off, 8)
    solve_ms, iterations, failed, finished, step_ms = _CMD_STATS.unpack_from(data, off)
    names, off = _get_strs(data, off + _CMD_STATS.size)
    extra, off = _get_floats(data, off)
    path, _ = _get_floats(data, off)
    return EpmCommand(
        header, frame_seq, index, np.array([vx, vy, vz]), outcome, status, phase, solve_ms, iterations,
        failed != 0, finished != 0, step_ms, names, extra, path,
    )  # fmt: skip


_FAST_ENCODERS: dict[type, Callable[[Any], bytes]] = {
    CameraFrame: _encode_frame,
    ArmState: _encode_arm,
    EpmCommand: _encode_command,
}
_FAST_DECODERS: dict[type, Callable[[bytes], Any]] = {
    CameraFrame: _decode_frame,
    ArmState: _decode_arm,
    EpmCommand: _decode_command,
}


def _encode_dynamic(msg: Any) -> bytes:
    """``msg``'s payload made by the dynamic encoder (every type has one)."""
    codec = _CODECS[type(msg)]
    return codec.encoder(codec.to_wire(msg))


def _decode_dynamic(payload: bytes, cls: type[M]) -> M:
    """The ``cls`` message in ``payload`` read by the dynamic decoder (every type has one)."""
    codec = _CODECS[cls]
    msg: M = codec.from_wire(codec.decoder(payload))
    return msg


def encode(msg: Any) -> bytes:
    """The CDR payload of ``msg`` (one of :func:`message_types`).

    Raises
    ------
    MessageError
        A fixed-size array field of the wrong length.
    """
    fast = _FAST_ENCODERS.get(type(msg))
    return fast(msg) if fast is not None else _encode_dynamic(msg)


def peek_version(payload: bytes) -> int:
    """The schema version of a payload (the first byte of its CDR body).

    Raises
    ------
    MessageError
        A payload too short to hold one.
    """
    if len(payload) <= _ENCAPSULATION:
        raise MessageError(f"payload: {len(payload)} bytes, too short for a message")
    return payload[_ENCAPSULATION]


def decode(payload: bytes, cls: type[M]) -> M:
    """The message of type ``cls`` in ``payload``.

    Raises
    ------
    VersionError
        The payload is of another schema version.
    MessageError
        The payload is not a valid ``cls`` message (truncated, garbled).
    """
    version = peek_version(payload)
    if version != SCHEMA_VERSION:
        raise VersionError(version)
    data = bytes(payload)
    fast = _FAST_DECODERS.get(cls)
    try:
        msg: M = fast(data) if fast is not None else _decode_dynamic(data, cls)
    except MessageError:
        raise
    except Exception as exc:  # the CDR readers raise struct.error, ValueError, UnicodeDecodeError, ...
        raise MessageError(f"{cls.__name__}: cannot decode {len(payload)} bytes: {exc}") from exc
    return msg
