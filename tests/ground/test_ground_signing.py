"""Issue 7, item 2: MAVLink 2 signing - the key file and verification with replay protection."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest
from ground_demo import command_frame

from fsw.comm.mavlink_dialect import signing_timestamp
from fsw.comm.mavlink_signing import (
    KeyFileError,
    SignatureVerifier,
    Verdict,
    load_key,
    parse_key,
    signature_fields,
    write_key,
)

KEY = bytes(range(32))


def test_key_file_forms_and_errors(tmp_path: Path) -> None:
    """Issue 7, item 2: hex or raw 32-byte keys load; anything else is a clear error."""
    assert parse_key(KEY.hex().encode() + b"\n") == KEY
    assert parse_key(KEY) == KEY
    with pytest.raises(KeyFileError, match="64 hex digits"):
        parse_key(b"secret passphrase")
    with pytest.raises(KeyFileError, match="not found"):
        load_key(tmp_path / "none.key")
    with pytest.raises(KeyFileError, match="directory"):
        load_key(tmp_path)
    path = tmp_path / "k.key"
    key = write_key(path)
    assert load_key(path) == (key, True)
    assert oct(path.stat().st_mode & 0o777) == "0o600"
    with pytest.raises(FileExistsError):
        write_key(path)
    os.chmod(path, 0o644)
    assert load_key(path) == (key, False)  # loads, but the caller warns


def test_verdicts() -> None:
    """Issue 7, done-when 1: unsigned, wrong-key, replayed and stale frames are told apart."""
    now = signing_timestamp(time.time())
    v = SignatureVerifier(KEY)
    good = command_frame(KEY, 0x101, ts=now)
    assert signature_fields(good) == (1, now)
    assert v.verify(good, 255, 190, now) is Verdict.OK
    assert v.verify(good, 255, 190, now) is Verdict.REPLAY
    assert v.verify(command_frame(KEY, 0x101, ts=now - 5), 255, 190, now) is Verdict.REPLAY  # older on the stream
    assert v.verify(command_frame(KEY, 0x101, ts=now + 1), 255, 190, now) is Verdict.OK
    assert v.verify(command_frame(None, 0x101), 255, 190, now) is Verdict.UNSIGNED
    assert v.verify(command_frame(os.urandom(32), 0x101, link_id=7, ts=now), 255, 190, now) is Verdict.BAD_SIGNATURE
    stale = command_frame(KEY, 0x101, link_id=9, ts=now - 61 * 100_000)
    assert v.verify(stale, 255, 190, now) is Verdict.STALE
    assert v.verify(command_frame(KEY, 0x101, link_id=10, ts=now - 59 * 100_000), 255, 190, now) is Verdict.OK
    assert SignatureVerifier(None).verify(good, 255, 190, now) is Verdict.NO_KEY
    assert v.counts[Verdict.OK] == 3 and v.counts[Verdict.REPLAY] == 2


def test_forged_timestamp_does_not_lock_out_the_ground() -> None:
    """A frame with a bad signature and a far-future timestamp must not advance the stream
    (pymavlink's own check_signature would, locking out the real key holder)."""
    now = signing_timestamp(time.time())
    v = SignatureVerifier(KEY)
    forged = bytearray(command_frame(KEY, 0x101, ts=now + 10**12))
    forged[-1] ^= 0xFF
    assert v.verify(bytes(forged), 255, 190, now) is Verdict.BAD_SIGNATURE
    assert v.verify(command_frame(KEY, 0x101, ts=now), 255, 190, now) is Verdict.OK


def test_every_bit_of_a_signed_frame_is_protected() -> None:
    """Flipping any bit of a signed command makes it not OK (header, payload, CRC, signature)."""
    now = signing_timestamp(time.time())
    frame = command_frame(KEY, 0x101, params=(1.0, 2.0, 0, 0, 0, 0), ts=now)
    for i in range(len(frame)):
        for bit in (0x01, 0x80):
            bad = bytearray(frame)
            bad[i] ^= bit
            assert SignatureVerifier(KEY).verify(bytes(bad), 255, 190, now) is not Verdict.OK, (i, bit)


def test_stream_table_is_bounded() -> None:
    now = signing_timestamp(time.time())
    v = SignatureVerifier(KEY, max_streams=4)
    for link in range(10):
        assert v.verify(command_frame(KEY, 0x101, link_id=link, ts=now + link), 255, 190, now) is Verdict.OK
    assert len(v.streams) == 4


def test_downlink_signing_time_follows_the_clock() -> None:
    """Our frames carry the current signing time, so a ground station that verifies them
    (pymavlink with the key) accepts a new stream even an hour into the run."""
    from fsw.comm.mavlink_adapter import MavlinkAdapter, VehicleView
    from fsw.comm.mavlink_config import MavlinkConfig
    from fsw.comm.mavlink_dialect import new_codec

    t0 = signing_timestamp(1.7e9)
    a = MavlinkAdapter(MavlinkConfig(), KEY, t0)
    a.plan(VehicleView(0.0), t0)
    hour_later = t0 + 3600 * 100_000
    frames = a.plan(VehicleView(3600.0), hour_later)
    fields = signature_fields(frames[0])
    assert fields is not None and fields[1] >= hour_later
    ground = new_codec(255, 190)
    ground.signing.secret_key, ground.signing.timestamp = KEY, hour_later
    msgs = ground.parse_buffer(frames[0])
    assert msgs and msgs[0].get_type() == "HEARTBEAT" and msgs[0]._signed
