"""The team's CAN frames (config/team.dbc): typed round trips, E2E on every frame, bad frames refused."""

from __future__ import annotations

import math

import pytest

from fsw.comm.rover_can import Bad
from fsw.comm.team.team_can import WINCHES, TeamCan, WinchCommand, WinchStatus


@pytest.fixture(scope="module")
def codec() -> TeamCan:
    return TeamCan()


def test_every_frame_is_e2e_protected(codec: TeamCan) -> None:
    assert set(codec.e2e) == set(codec.names)  # a layout (Counter + Checksum) for every frame
    for layout in codec.e2e.values():
        assert layout.crc_bits in (8, 16)
    for w in WINCHES:  # frames that move something carry the 16-bit CRC
        assert codec.e2e[codec.frame_id(f"{w}_CMD")].crc_bits == 16


def test_winch_round_trip(codec: TeamCan) -> None:
    fid, data = codec.winch_command("WINCH_B", -0.1234, True, True, 7)
    d = codec.decode(fid, data)
    assert isinstance(d, WinchCommand) and d.winch == "WINCH_B" and d.counter == 7
    assert d.rate_mps == pytest.approx(-0.1234, abs=1e-4) and d.enable and d.clear_faults
    fid, data = codec.winch_status("WINCH_A", 7.25, 180.4, False, {"FaultStall", "FaultSpool"}, 3)
    s = codec.decode(fid, data)
    assert isinstance(s, WinchStatus) and s.faults == {"FaultStall", "FaultSpool"}
    assert s.paid_out_m == pytest.approx(7.25, abs=1e-4) and s.tension_n == pytest.approx(180.4, abs=0.1)


def test_non_finite_command_is_zero(codec: TeamCan) -> None:
    fid, data = codec.winch_command("WINCH_A", math.nan, True, False, 1)
    d = codec.decode(fid, data)
    assert isinstance(d, WinchCommand) and d.rate_mps == 0.0


@pytest.mark.parametrize("mangle", ["flip", "short", "unknown"])
def test_bad_frames_are_refused_not_raised(codec: TeamCan, mangle: str) -> None:
    fid, data = codec.attitude(1.0, -70.0, -90.0, 2)
    if mangle == "flip":
        data = bytes([data[0] ^ 0x10]) + data[1:]
    elif mangle == "short":
        data = data[:-1]
    else:
        fid = 0x7FF
    d = codec.decode(fid, data)
    assert isinstance(d, Bad) and d.reason == {"flip": "checksum", "short": "dlc", "unknown": "unknown_id"}[mangle]
