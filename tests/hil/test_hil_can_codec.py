"""The rover CAN database and its sans-I/O codec (issue 3, item 5 and 12)."""

from __future__ import annotations

import os

import cantools
from crccheck.crc import Crc8SaeJ1850
from hypothesis import given, settings
from hypothesis import strategies as st

from fsw.comm.rover_can import AXES, DEFAULT_DBC, AxisCommand, AxisStatus, Bad, RoverCan, crc8, wrap_position

CODEC = RoverCan()


def test_dbc_defines_every_frame_with_documented_node_ids() -> None:
    """Issue 3 item 5: per axis CMD/STATUS/HEARTBEAT, ESTOP, FSW heartbeat; ids = CANopen-style."""
    db = cantools.database.load_file(str(DEFAULT_DBC))
    names = {m.name for m in db.messages}
    assert {"ESTOP", "FSW_HEARTBEAT"} <= names
    nodes = {n.name: n.comment for n in db.nodes}
    for axis in AXES:
        node = CODEC.node_id[axis]
        assert nodes[axis] == f"node id 0x{node:02X}"
        assert db.get_message_by_name(f"{axis}_CMD").frame_id == 0x200 + node
        assert db.get_message_by_name(f"{axis}_STATUS").frame_id == 0x180 + node
        assert db.get_message_by_name(f"{axis}_HEARTBEAT").frame_id == 0x700 + node
        status = {s.name for s in db.get_message_by_name(f"{axis}_STATUS").signals}
        assert {"Position", "Velocity", "Current", "FaultTimeout", "FaultLimit", "FaultDriver"} <= status
    assert len(db.messages) == 3 * len(AXES) + 3  # + IMU_ATTITUDE (issue 13)


def test_crc8_matches_reference_implementation() -> None:
    """The table CRC-8/SAE-J1850 equals crccheck's (the E2E checksum of every frame)."""
    for n in range(64):
        data = os.urandom(n % 10)
        assert crc8(data) == Crc8SaeJ1850.calc(data)


@settings(max_examples=60, deadline=None)
@given(axis=st.sampled_from(AXES), sp=st.floats(-3.0, 3.0), en=st.booleans(), clr=st.booleans(), ctr=st.integers(0, 15))
def test_command_roundtrip(axis: str, sp: float, en: bool, clr: bool, ctr: int) -> None:
    fid, data = CODEC.encode_command(axis, sp, en, clr, ctr)
    d = CODEC.decode(fid, data)
    assert isinstance(d, AxisCommand) and d.axis == axis and (d.enable, d.clear_faults, d.counter) == (en, clr, ctr)
    scale = 0.001 if axis.startswith("DRIVE") else 0.0001
    assert abs(d.setpoint - sp) <= scale


@settings(max_examples=60, deadline=None)
@given(
    axis=st.sampled_from(AXES),
    pos=st.floats(-5000.0, 5000.0),
    vel=st.floats(-30.0, 30.0),
    cur=st.floats(-12.0, 12.0),
    faults=st.sets(st.sampled_from(["FaultTimeout", "FaultLimit", "FaultDriver"])),
)
def test_status_roundtrip_with_position_wrap(axis: str, pos: float, vel: float, cur: float, faults: set[str]) -> None:
    fid, data = CODEC.encode_status(axis, pos, vel, cur, True, faults, 7)
    d = CODEC.decode(fid, data)
    assert isinstance(d, AxisStatus) and d.faults == frozenset(faults)
    assert (
        abs(d.position_rad - wrap_position(pos)) <= 0.0011
        or abs(abs(d.position_rad - wrap_position(pos)) - 1048.576) < 0.002
    )
    assert abs(d.velocity_radps - vel) <= 0.0011 and abs(d.current_a - cur) <= 0.051


@settings(max_examples=80, deadline=None)
@given(fid=st.integers(0, 0x7FF), data=st.binary(max_size=8), ext=st.booleans())
def test_decode_never_raises_on_arbitrary_frames(fid: int, data: bytes, ext: bool) -> None:
    """Bad CAN frames are data (a reason), never an exception."""
    CODEC.decode(fid, data, ext)


def test_corrupted_or_truncated_frames_are_refused_with_a_reason() -> None:
    fid, data = CODEC.encode_status("STEER_FL", 0.3, 0.0, 0.5, True, set(), 3)
    flipped = bytes([data[0] ^ 0x04]) + data[1:]
    assert isinstance(bad := CODEC.decode(fid, flipped), Bad) and bad.reason == "checksum"
    assert CODEC.decode(fid, data[:6]).reason == "dlc"  # type: ignore[union-attr]
    assert CODEC.decode(0x555, data).reason == "unknown_id"  # type: ignore[union-attr]
