"""Link packet formats: round trip, CRC-32, malformed datagrams (issue 6, item 5)."""

from __future__ import annotations

import contextlib
import struct
import zlib

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fsw.comm import link_packets as lp

SAMPLES = [
    lp.Offer(7, 42, 123456, 464, bytes(range(32))),
    lp.Accept(7, 42),
    lp.Reject(7, 42, lp.RejectReason.TOO_LARGE),
    lp.Data(7, 65535, 1234, b"\x00\xff" * 100),
    lp.Data(7, 0, 0, b""),
    lp.Status(7, 10, 20, 15, 999, b"\x0f\xf0"),
    lp.Status(7, 0, 0, 0, None, b""),
    lp.Ping(7, 65535, True),
    lp.Fin(7, 42, lp.FinStatus.HASH_MISMATCH),
    lp.FinAck(7, 42),
]


@pytest.mark.parametrize("pkt", SAMPLES, ids=lambda p: type(p).__name__)
def test_round_trip(pkt):
    """Issue 6, item 5: every packet type encodes and decodes to itself, CRC-32 at the end."""
    raw = lp.encode(pkt)
    assert lp.decode(raw) == pkt
    assert struct.unpack("<I", raw[-4:])[0] == zlib.crc32(raw[:-4])
    assert raw[0] == lp.MAGIC and raw[1] >> 4 == lp.VERSION


def test_data_overhead_is_twelve_bytes():
    """Issue 6, item 5: DATA = 4 header + seq + serial + 4 CRC."""
    assert len(lp.encode(lp.Data(1, 2, 3, b"x" * 464))) == 464 + lp.DATA_OVERHEAD == 476


@pytest.mark.parametrize("pkt", SAMPLES, ids=lambda p: type(p).__name__)
def test_any_single_bit_flip_is_rejected(pkt):
    """Issue 6, item 5: CRC-32 catches every single-bit error."""
    raw = lp.encode(pkt)
    for bit in range(8 * len(raw)):
        buf = bytearray(raw)
        buf[bit >> 3] ^= 1 << (bit & 7)
        with pytest.raises(lp.PacketError):
            lp.decode(bytes(buf))


def _sealed(body: bytes) -> bytes:
    return body + struct.pack("<I", zlib.crc32(body))


def test_malformed_but_crc_valid_packets_are_rejected():
    """Issue 6, item 5: right CRC, wrong content -> PacketError with a reason."""
    bad = [
        _sealed(b"\xa5\x21\x07\x00"),  # version 2
        _sealed(b"\xa5\x1f\x07\x00"),  # type 15
        _sealed(b"\xa5\x11\x07\x00" + b"\x00" * 5),  # OFFER too short
        _sealed(b"\xa5\x11\x07\x00" + struct.pack("<IIH32s", 1, 0, 464, bytes(32))),  # size 0
        _sealed(b"\xa5\x11\x07\x00" + struct.pack("<IIH32s", 1, 10**9, 1, bytes(32))),  # >65535 seg
        _sealed(b"\xa5\x15\x07\x00" + struct.pack("<HHHHBB", 5, 4, 0, 0, 0, 0)),  # cum > highest
        _sealed(b"\xa5\x15\x07\x00" + struct.pack("<HHHHBB", 0, 4, 0, 0, 0, 3) + b"\x00"),  # bitmap
        _sealed(b"\xa5\x16\x07\x00" + struct.pack("<HB", 1, 7)),  # PING flags
        _sealed(b"\xa5\x17\x07\x00" + struct.pack("<IB", 1, 9)),  # FIN status
        _sealed(b"\xa5\x13\x07\x00" + struct.pack("<IB", 1, 0)),  # REJECT reason
        b"\xa5\x14", b"", b"\x00" * 3,
    ]
    for raw in bad:
        with pytest.raises(lp.PacketError):
            lp.decode(raw)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=80), st.booleans())
def test_decode_never_raises_anything_else(blob, seal):
    """Issue 6, item 5: arbitrary bytes only ever raise PacketError."""
    raw = _sealed(b"\xa5" + blob) if seal else blob
    with contextlib.suppress(lp.PacketError):
        lp.decode(raw)
