"""The nodes' wire messages: CDR round trips, the schema version, malformed payloads, the .msg files."""

from __future__ import annotations

import dataclasses
import math
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capsule_mpc.nodes import messages as m

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
any_float = st.floats(width=64)
text = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=20)
u64 = st.integers(0, 2**64 - 1)
i64 = st.integers(-(2**63), 2**63 - 1)


def vec(n):
    return st.lists(any_float, min_size=n, max_size=n).map(np.array)


def floats(max_size=12):
    return st.lists(any_float, max_size=max_size).map(lambda v: np.array(v, dtype=float))


headers = st.builds(
    m.Header,
    schema_version=st.just(m.SCHEMA_VERSION),
    publisher_id=u64,
    seq=u64,
    rig_time_s=any_float,
    stamp_ns=st.integers(0, 2**32 * 10**9 - 1),
    frame_id=text,
    run_id=text,
)
names = st.lists(text, max_size=4).map(tuple)
#: The messages of every camera frame (hand-written codecs).
HOT = st.one_of(
    st.builds(
        m.CameraFrame,
        header=headers,
        frame_index=i64,
        capture_time_s=any_float,
        valid=st.booleans(),
        position_m=vec(2),
    ),
    st.builds(
        m.ArmState,
        header=headers,
        frame_index=i64,
        epm_position_m=vec(3),
        epm_velocity_mps=vec(3),
        epm_velocity_command_mps=vec(3),
        watchdog_active=st.booleans(),
        joint_names=names,
        joint_positions_rad=floats(6),
    ),
    st.builds(
        m.EpmCommand,
        header=headers,
        frame_seq=u64,
        frame_index=i64,
        velocity_mps=vec(3),
        outcome=text,
        status=text,
        phase=text,
        solve_ms=any_float,
        iterations=st.integers(-(2**31), 2**31 - 1),
        failed=st.booleans(),
        finished=st.booleans(),
        step_ms=any_float,
        extra_names=names,
        extra_values=floats(4),
        predicted_path_m=floats(40),
    ),
)
MESSAGES = st.one_of(
    HOT,
    st.builds(
        m.RunInfo,
        header=headers,
        state=text,
        config_name=text,
        config_hash=text,
        config_sections=names,
        config_section_hashes=names,
        seed=i64,
        plant_seed=i64,
        camera_rate_hz=any_float,
        first_frame_index=i64,
        path_waypoints_m=floats(20),
        path_closed=st.booleans(),
        path_speed_mps=any_float,
        start_epm_position_m=vec(3),
        epm_position_m=vec(3),
    ),
    st.builds(m.Event, header=headers, source=text, kind=text, detail=text, count=u64),
)


def _same(a, b) -> bool:
    if isinstance(a, np.ndarray):
        return a.shape == b.shape and bool(np.array_equal(a, b, equal_nan=True))
    if isinstance(a, float):
        return (math.isnan(a) and math.isnan(b)) or a == b
    if dataclasses.is_dataclass(a):
        return type(a) is type(b) and all(
            _same(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(a)
        )
    return a == b


@settings(max_examples=150, deadline=None)
@given(MESSAGES)
def test_every_message_round_trips_through_cdr(msg):
    payload = m.encode(msg)
    assert payload[:4] == b"\x00\x01\x00\x00"  # CDR little-endian encapsulation, as ROS 2 writes
    assert m.peek_version(payload) == m.SCHEMA_VERSION
    assert _same(m.decode(payload, type(msg)), msg)


def _identical(a, b) -> bool:
    """``a`` and ``b`` hold the same values of the same types (arrays: dtype, shape, bits)."""
    if dataclasses.is_dataclass(a):
        return type(a) is type(b) and all(
            _identical(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(a)
        )
    if isinstance(a, np.ndarray):
        return (
            isinstance(b, np.ndarray)
            and a.dtype == b.dtype
            and a.shape == b.shape
            and a.tobytes() == b.tobytes()
            and a.flags.writeable == b.flags.writeable
        )
    if isinstance(a, tuple):
        return type(b) is tuple and len(a) == len(b) and all(map(_identical, a, b))
    if isinstance(a, float):
        return type(b) is float and struct.pack("<d", a) == struct.pack("<d", b)
    return type(a) is type(b) and a == b


@settings(max_examples=300, deadline=None)
@given(HOT)
def test_the_hand_written_codecs_are_the_dynamic_ones_both_ways(msg):
    # the per-frame messages have their own codec; it must be the dynamic codec, byte for byte
    payload = m._encode_dynamic(msg)
    assert m.encode(msg) == payload
    assert _identical(m.decode(payload, type(msg)), m._decode_dynamic(payload, type(msg)))


@pytest.mark.parametrize(
    "msg",
    [
        m.CameraFrame(m.Header(frame_id="plate", run_id="run"), valid=True, position_m=np.ones(2)),
        m.ArmState(joint_names=("a", "bc"), joint_positions_rad=np.ones(2)),
        m.EpmCommand(
            status="x",
            phase="slide",
            extra_names=("n",),
            extra_values=np.ones(1),
            predicted_path_m=np.ones(4),
        ),
    ],
)
def test_every_truncation_of_a_per_frame_message_is_a_message_error(msg):
    payload = m.encode(msg)
    for cut in range(m._ENCAPSULATION + 1, len(payload)):
        with pytest.raises(m.MessageError):
            m.decode(payload[:cut], type(msg))


def test_a_known_frame_has_the_expected_bytes():
    # A byte-level check of the CDR layout (and of the encoder library the codec is built on).
    frame = m.CameraFrame(
        m.Header(publisher_id=7, seq=2, rig_time_s=0.5, stamp_ns=3_000_000_004, frame_id="plate", run_id="r"),
        frame_index=-1,
        capture_time_s=0.25,
        valid=True,
        position_m=np.array([1.0, -2.0]),
    )
    expected = b"".join(
        [
            b"\x00\x01\x00\x00",
            bytes([m.SCHEMA_VERSION]),
            b"\x00" * 7,
            struct.pack("<QQd", 7, 2, 0.5),
            struct.pack("<II", 3, 4),
            struct.pack("<I", 6),
            b"plate\x00",
            b"\x00\x00",
            struct.pack("<I", 2),
            b"r\x00",
            b"\x00" * 6,
            struct.pack("<qd", -1, 0.25),
            b"\x01",
            b"\x00" * 7,
            struct.pack("<dd", 1.0, -2.0),
        ]
    )
    assert m.encode(frame) == expected
    assert m._encode_dynamic(frame) == expected


def test_another_schema_version_is_refused_before_decoding():
    payload = bytearray(m.encode(m.Event(kind="x")))
    payload[4] = m.SCHEMA_VERSION + 1
    expected = f"schema_version: expected {m.SCHEMA_VERSION}, got {m.SCHEMA_VERSION + 1}"
    with pytest.raises(m.VersionError, match=expected):
        m.decode(bytes(payload), m.Event)


@pytest.mark.parametrize("cut", [0, 4, 20, -3])
def test_a_truncated_payload_is_a_message_error(cut):
    payload = m.encode(m.RunInfo(path_waypoints_m=np.zeros(8)))
    with pytest.raises(m.MessageError):
        m.decode(payload[:cut], m.RunInfo)


def test_a_fixed_array_of_the_wrong_length_is_refused():
    with pytest.raises(m.MessageError, match=r"CameraFrame.position_m: must have 2 values, got 3"):
        m.encode(m.CameraFrame(position_m=np.zeros(3)))
    with pytest.raises(m.MessageError, match=r"ArmState.epm_velocity_mps: must have 3 values, got 2"):
        m.encode(m.ArmState(epm_velocity_mps=np.zeros(2)))
    with pytest.raises(m.MessageError, match=r"EpmCommand.velocity_mps: must have 3 values, got 0"):
        m.encode(m.EpmCommand(velocity_mps=np.zeros(0)))
    with pytest.raises(m.MessageError, match=r"RunInfo.epm_position_m: must have 3 values, got 1"):
        m.encode(m.RunInfo(epm_position_m=np.zeros(1)))


def test_the_msg_files_are_the_dataclasses_and_parse_as_ros2_definitions():
    files = sorted(p.stem for p in m.MSG_DIR.glob("*.msg"))
    assert files == sorted([cls.TYPE for cls in m.message_types()] + ["Header"])
    for cls in m.message_types():
        text = m.schema_text(cls.TYPE)
        assert f"MSG: {m.PACKAGE}/Header" in text
        # every field is in the .msg file, with a comment giving its meaning
        for f in dataclasses.fields(cls):
            line = next(ln for ln in text.splitlines() if ln.split("#")[0].split()[-1:] == [f.name])
            assert "#" in line or f.name == "header"
