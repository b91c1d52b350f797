"""Codecs compiled once from the DBC (fsw/comm/can_codec.py; issue 15 item 2): bit for bit
what cantools gives, for every message of config/rover.dbc, and cantools' own codec where the
fast path does not apply."""

from __future__ import annotations

import random

import cantools
import pytest

from fsw.comm.can_codec import CompiledMessage, compile_messages
from fsw.comm.rover_can import DEFAULT_DBC

DB = cantools.database.load_file(str(DEFAULT_DBC))


def _value(sig: cantools.database.can.Signal, rng: random.Random) -> float:
    lo = sig.minimum if sig.minimum is not None else 0.0
    hi = sig.maximum if sig.maximum is not None else 1.0
    return lo + (hi - lo) * rng.random()


def test_every_rover_message_compiles() -> None:
    codecs = compile_messages(DB)
    assert set(codecs) == {m.name for m in DB.messages}
    assert all(c.compiled for c in codecs.values())


@pytest.mark.parametrize("msg", DB.messages, ids=lambda m: m.name)
def test_encode_and_decode_equal_cantools(msg: cantools.database.can.Message) -> None:
    rng = random.Random(msg.frame_id)
    c = CompiledMessage(msg)
    for _ in range(300):
        values = {s.name: _value(s, rng) for s in msg.signals}
        assert c.encode(values) == msg.encode(values, strict=False)
        data = bytes(rng.getrandbits(8) for _ in range(msg.length))
        want = msg.decode(data, decode_choices=False, scaling=True)
        got = c.decode(data)
        assert got == want and [type(v) for v in got.values()] == [type(v) for v in want.values()]
        names = tuple(reversed(want))  # any order, any subset
        picked = c.values(names)(data)
        assert picked == tuple(want[n] for n in names) and [type(v) for v in picked] == [type(want[n]) for n in names]
        assert c.values(names[:2])(data) == tuple(want[n] for n in names[:2])
    for s in msg.signals:  # the field's ends, exactly
        for v in (s.minimum, s.maximum):
            values = {t.name: (v if t is s else _value(t, rng)) for t in msg.signals}
            assert c.encode(values) == msg.encode(values, strict=False)


def test_out_of_field_and_missing_values_are_refused() -> None:
    c = CompiledMessage(DB.get_message_by_name("DRIVE_FL_CMD"))
    ok = {"VelocityCmd": 1.0, "Enable": 1, "ClearFaults": 0, "Counter": 0, "Checksum": 0}
    c.encode(ok)
    with pytest.raises(ValueError, match="VelocityCmd"):
        c.encode({**ok, "VelocityCmd": 40.0})
    with pytest.raises(ValueError, match="Enable"):
        c.encode({**ok, "Enable": 2})
    with pytest.raises(KeyError):
        c.encode({k: v for k, v in ok.items() if k != "Enable"})
    with pytest.raises(ValueError, match="bytes"):
        c.decode(b"\x00" * 3)
    with pytest.raises(ValueError, match="bytes"):
        c.values(("Enable",))(b"\x00" * 3)
    with pytest.raises(KeyError):
        c.values(("NoSuchSignal",))


def test_big_endian_and_float_messages_keep_cantools() -> None:
    db = cantools.database.load_string(
        'VERSION ""\nBS_:\nBU_: A\n'
        'BO_ 100 BE: 8 A\n SG_ Speed : 7|16@0- (0.01,0) [-300|300] "" A\n'
        ' SG_ Flag : 23|1@0+ (1,0) [0|1] "" A\n', database_format="dbc")
    msg = db.get_message_by_name("BE")
    c = CompiledMessage(msg)
    assert not c.compiled
    values = {"Speed": -12.34, "Flag": 1}
    assert c.encode(values) == msg.encode(values)
    assert c.decode(c.encode(values)) == msg.decode(msg.encode(values), decode_choices=False)
    assert c.values(("Flag", "Speed"))(c.encode(values)) == (1, -12.34)
