"""Fix packets on the radio link: round trip, integrity, refusal of anything else."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fsw.comm.link_packets import PacketError
from fsw.comm.team import fix_packets as fp


def _fix() -> fp.Fix:
    a = np.random.default_rng(1).normal(size=(6, 6))
    return fp.Fix(9, 123456, np.array([2.5, -3.25, -1.5]), np.array([0.0, 0.0, -1.2]), a @ a.T * 1e-4)


def test_round_trip_small_and_typed() -> None:
    f = _fix()
    data = fp.encode(f)
    assert len(data) <= 128 and fp.is_fix_packet(data)
    g = fp.decode(data)
    assert isinstance(g, fp.Fix) and g.seq == 9 and g.t_ms == 123456
    np.testing.assert_allclose(g.position, f.position, atol=1e-6)
    np.testing.assert_allclose(g.cov, f.cov, rtol=1e-6, atol=1e-12)
    assert np.allclose(g.cov, g.cov.T)
    assert g.yaw == pytest.approx(-1.2, abs=1e-6)
    r = fp.decode(fp.encode(fp.FixRequest(3, 1)))
    assert r == fp.FixRequest(3, 1)
    assert fp.decode(fp.encode(fp.NoFix(4, 0))) == fp.NoFix(4, 0)


@pytest.mark.parametrize("mangle", ["bit", "truncate", "magic", "empty"])
def test_damaged_packets_raise_a_one_line_packet_error(mangle: str) -> None:
    d = bytearray(fp.encode(_fix()))
    if mangle == "bit":
        d[20] ^= 0x04
    elif mangle == "truncate":
        d = d[:40]
    elif mangle == "magic":
        d[0] = 0x00
    else:
        d = bytearray()
    with pytest.raises(PacketError) as exc:
        fp.decode(bytes(d))
    assert "\n" not in str(exc.value)


def test_a_non_finite_fix_is_not_sent() -> None:
    f = _fix()
    bad = fp.Fix(f.seq, f.t_ms, np.array([math.nan, 0.0, 0.0]), f.rotvec, f.cov)
    with pytest.raises(ValueError):
        fp.encode(bad)


def test_a_request_carries_the_estimate_and_the_attitude_or_reads_without_them() -> None:
    """A request with the Cliff-bot's roll and pitch (the gravity its fix must agree with) round
    trips; the shorter forms still read, with NaN for what they lack; a request whose attitude is
    not finite or beyond a right angle is refused in one line, as the framing is."""
    full = fp.FixRequest(5, 2, 1.25, -0.5, 3.5, -71.25)
    assert fp.decode(fp.encode(full)) == full
    xy = fp.decode(fp.encode(fp.FixRequest(5, 2, 1.25, -0.5)))
    assert isinstance(xy, fp.FixRequest) and (xy.x, xy.y) == (1.25, -0.5) and math.isnan(xy.roll_deg)
    assert len(fp.encode(full)) == len(fp.encode(fp.FixRequest(5, 2, 1.25, -0.5))) + 8
    for roll, pitch in ((math.inf, 0.0), (0.0, 95.0), (-91.0, 0.0)):
        d = fp._frame(fp.FIX_REQUEST, fp._REQ_ATT.pack(5, 2, 1.25, -0.5, roll, pitch))
        with pytest.raises(PacketError) as exc:
            fp.decode(d)
        assert "\n" not in str(exc.value)
