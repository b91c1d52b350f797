"""Issue 7, done-when 4: random and mutated MAVLink frames into the uplink never crash the
flight software, never run a command, and leave the link working."""

from __future__ import annotations

import itertools
import random
from pathlib import Path
from typing import Any

import ground_demo
import pytest
from ground_demo import command_frame
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fsw.comm.mavlink_dialect import mavlink, new_codec
from fsw.drivers.resources import Resources


def _acks(link: Any) -> list[int]:
    parser = new_codec(255, 190)
    out = [m.result for batch in link.sent for f in batch for m in parser.parse_buffer(f) or []
           if m.get_type() == "COMMAND_ACK"]
    link.sent.clear()
    return out


_ROVERS = itertools.count()


def _rover(key_file: Path, link: Any) -> Any:
    """A fresh rover with its own replay window (hypothesis reuses the key file across examples;
    a window saved by an earlier example runs signing_reserve_s ahead and would refuse the
    liveness command as a replay)."""
    window = key_file.parent / f"window{next(_ROVERS)}.json"
    cfg = ground_demo.config("udpout:127.0.0.1:9", str(key_file), extra={"signing_state_file": str(window)})
    return ground_demo.build(cfg, Resources(mavlink_link=link))


def _assert_alive(exe: Any, link: Any, key: bytes) -> None:
    """No task raised; a fresh signed NOOP in its own datagram is still accepted."""
    assert all(t.exceptions == 0 for t in exe.tasks.values())
    assert sum(exe.events.count(f"{n}.EXCEPTION") for n in exe.tasks) == 0
    op = exe.commands.definitions()["demo.NOOP"][0]
    link.sent.clear()
    link.inbox.append(command_frame(key, op))
    exe.run_lockstep(2)
    assert _acks(link) == [mavlink.MAV_RESULT_ACCEPTED]


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(datagrams=st.lists(st.binary(max_size=400), max_size=12),
       stream=st.booleans())
def test_random_bytes(datagrams: list[bytes], stream: bool, key_file: Path, demo_kind: None) -> None:
    """Issue 7, done-when 4: arbitrary datagrams (or one serial byte stream) are refused and
    counted, never a crash."""
    link = ground_demo.MemoryLink(packetized=not stream)
    exe = _rover(key_file, link)
    seeded = [b"\xfd" + d for d in datagrams[::2]] + [b"\xfe" + d for d in datagrams[1::2]]  # look like frames
    link.inbox.extend(seeded)
    exe.run_lockstep(3)
    assert exe.tasks["demo"].cmd_count == 0
    if not stream:  # datagram boundaries resynchronise the parser at once
        _assert_alive(exe, link, bytes.fromhex(key_file.read_text()))


def _mutate(rng: random.Random, frame: bytes) -> bytes:
    b = bytearray(frame)
    for _ in range(rng.randint(1, 4)):
        op = rng.randrange(5)
        i = rng.randrange(len(b)) if b else 0
        if op == 0 and b:
            b[i] ^= 1 << rng.randrange(8)
        elif op == 1 and b:
            b[i] = rng.randrange(256)
        elif op == 2:
            b.insert(i, rng.randrange(256))
        elif op == 3 and b:
            del b[i]
        else:
            b = b[:i]
    return bytes(b)


@pytest.mark.parametrize("seed", [1, 2])
def test_mutated_frames(seed: int, key_file: Path, demo_kind: None, memory_link: Any) -> None:
    """Issue 7, done-when 4: 750 mutations of valid signed commands, heartbeats and
    telemetry: no crash; only the authentic command can be accepted, and only once (a
    mutation may leave it whole, e.g. by appending bytes); the link still works after."""
    key = bytes.fromhex(key_file.read_text())
    exe = _rover(key_file, memory_link)
    op = exe.commands.definitions()["mavlink.SET_BUDGET"][0]
    gcs = new_codec(255, 190)
    seeds = [command_frame(key, op, (300, 0, 0, 0, 0, 0)), command_frame(None, op, (300, 0, 0, 0, 0, 0)),
             bytes(mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(gcs)),
             bytes(mavlink.MAVLink_statustext_message(4, b"x" * 50, 7, 0).pack(gcs)),
             bytes(mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(gcs, force_mavlink1=True))]
    rng = random.Random(seed)
    for _ in range(50):
        batch = [_mutate(rng, rng.choice(seeds)) for _ in range(15)]
        batch = [b for b in batch if b not in seeds]
        memory_link.inbox.extend(batch)
        exe.run_lockstep(1)
    acks = _acks(memory_link)
    assert acks.count(mavlink.MAV_RESULT_ACCEPTED) == exe.telemetry.get("mavlink.cmds_accepted") <= 1
    assert len(acks) >= 2 and exe.telemetry.get("mavlink.rx_bad") > 100  # most mutations break the CRC
    assert exe.tasks["mavlink"].adapter.budget_bytes in (300, 600)  # type: ignore[attr-defined]
    _assert_alive(exe, memory_link, key)


def test_uplink_parser_fuzz_volume() -> None:
    """Issue 7, done-when 4: 20000 mutated frames straight into the sans-I/O uplink, as a byte
    stream and as datagrams: it never raises and authenticates nothing it should not."""
    import time

    from fsw.comm.mavlink_dialect import signing_timestamp
    from fsw.comm.mavlink_signing import SignatureVerifier, Verdict
    from fsw.comm.mavlink_uplink import Uplink

    key = bytes(range(32))
    now = signing_timestamp(time.time())
    good = command_frame(key, 0x101, ts=now)
    gcs = new_codec(255, 190)
    seeds = [good, bytes(mavlink.MAVLink_param_set_message(1, 1, b"X", 1.0, 9).pack(gcs)),
             bytes(mavlink.MAVLink_encapsulated_data_message(3, list(range(253))).pack(gcs))]
    rng = random.Random(7)
    for packet_end in (False, True):
        up = Uplink(SignatureVerifier(key), 1, 1)
        ok = 0
        for _ in range(10000):
            frame = _mutate(rng, rng.choice(seeds))
            batch = up.feed(frame, now, packet_end)
            ok += sum(c.verdict is Verdict.OK for c in batch.commands)
        assert ok <= 1  # the authentic command, once at most
        assert up.counters.bad_frames > 1000
