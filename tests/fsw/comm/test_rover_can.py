"""The rover CAN database and its sans-I/O codec (issue 3, item 5 and 12)."""

from __future__ import annotations

import os

import cantools
from crccheck.crc import Crc8Autosar, Crc16Dnp
from hypothesis import example, given, settings
from hypothesis import strategies as st

from fsw.comm.e2e import CRCS
from fsw.comm.rover_can import (
    AXES,
    DEFAULT_DBC,
    AxisCommand,
    AxisStatus,
    Bad,
    EStop,
    Heartbeat,
    RoverCan,
    wrap_position,
)

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


def test_e2e_crcs_match_reference_implementation() -> None:
    """The E2E CRCs (fastcrc) equal crccheck's CRC-8/AUTOSAR and CRC-16/DNP."""
    for n in range(64):
        data = os.urandom(n % 12)
        assert CRCS[8](data) == Crc8Autosar.calc(data) and CRCS[16](data) == Crc16Dnp.calc(data)


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


_VALID = [
    CODEC.encode_command("DRIVE_RL", -1.5, True, True, 9),
    CODEC.encode_status("STEER_FR", 3.0, 0.5, 1.0, True, {"FaultLimit"}, 2),
    CODEC.encode_heartbeat("FSW", 5, 15),
    CODEC.encode_estop(False, 0),
]


@settings(max_examples=300, deadline=None)
@example(fid=_VALID[0][0], data=_VALID[0][1], ext=False)
@example(fid=_VALID[1][0], data=_VALID[1][1], ext=False)
@example(fid=_VALID[2][0], data=_VALID[2][1], ext=False)
@example(fid=_VALID[3][0], data=_VALID[3][1], ext=False)
@given(fid=st.sampled_from(sorted(CODEC.e2e)) | st.integers(0, 0x7FF), data=st.binary(max_size=8), ext=st.booleans())
def test_arbitrary_frames_are_refused_unless_canonical(fid: int, data: bytes, ext: bool) -> None:
    """req(12.7): bad CAN frames are data (a reason), never an exception, and never accepted:
    a frame the decoder accepts re-encodes to exactly the same bytes (it is a genuine frame)."""
    d = CODEC.decode(fid, data, ext)
    if isinstance(d, Bad):
        return
    assert not ext and len(data) == CODEC.e2e[fid].length
    if isinstance(d, AxisCommand):
        again = CODEC.encode_command(d.axis, d.setpoint, d.enable, d.clear_faults, d.counter)
    elif isinstance(d, AxisStatus):
        again = CODEC.encode_status(
            d.axis, d.position_rad, d.velocity_radps, d.current_a, d.enabled, d.faults, d.counter
        )
    elif isinstance(d, Heartbeat):
        again = CODEC.encode_heartbeat(d.node, d.state, d.counter)
    else:
        assert isinstance(d, EStop)
        again = CODEC.encode_estop(d.engage, d.counter)
    assert again == (fid, data)


def test_corrupted_or_truncated_frames_are_refused_with_a_reason() -> None:
    fid, data = CODEC.encode_status("STEER_FL", 0.3, 0.0, 0.5, True, set(), 3)
    flipped = bytes([data[0] ^ 0x04]) + data[1:]
    assert isinstance(bad := CODEC.decode(fid, flipped), Bad) and bad.reason == "checksum"
    assert CODEC.decode(fid, data[:6]).reason == "dlc"  # type: ignore[union-attr]
    assert CODEC.decode(0x555, data).reason == "unknown_id"  # type: ignore[union-attr]
