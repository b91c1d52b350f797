"""Issue 12, item 6: future-dated signed commands are refused; the replay window survives a restart."""

from __future__ import annotations

import json
import time
from pathlib import Path

import ground_demo
from ground_demo import command_frame

from fsw.comm.mavlink_commands import Reason
from fsw.comm.mavlink_dialect import mavlink, new_codec, signing_timestamp
from fsw.comm.mavlink_signing import SignatureVerifier, Verdict
from fsw.drivers import signing_store
from fsw.drivers.resources import Resources

KEY = bytes(range(32))
HOUR = 3600 * 100_000  # signing time units (10 us)


def test_a_command_one_hour_ahead_is_refused_and_leaves_the_window_alone() -> None:
    """req(12.6): FUTURE beyond signing_max_future_s; the stream's correctly timed commands still pass."""
    now = signing_timestamp(time.time())
    v = SignatureVerifier(KEY, max_future_s=60.0)
    assert v.verify(command_frame(KEY, 0x101, ts=now + HOUR), 255, 190, now) is Verdict.FUTURE
    assert v.verify(command_frame(KEY, 0x101, ts=now + 11 * 24 * HOUR), 255, 190, now) is Verdict.FUTURE
    assert v.verify(command_frame(KEY, 0x101, ts=now + 59 * 100_000), 255, 190, now) is Verdict.OK  # within 60 s
    assert v.verify(command_frame(KEY, 0x101, ts=now + 59 * 100_000 + 1), 255, 190, now) is Verdict.OK
    assert v.counts[Verdict.FUTURE] == 2 and not any(ts > now + HOUR for ts in v.streams.values())


def _acks(exe, link, frames, n=2):  # type: ignore[no-untyped-def]
    link.inbox.extend(frames)
    exe.run_lockstep(n)
    parser, out = new_codec(255, 190), []
    for batch in link.sent:
        for f in batch:
            out += [(m.result, m.progress) for m in parser.parse_buffer(f) or [] if m.get_type() == "COMMAND_ACK"]
    link.sent.clear()
    return out


def test_future_command_through_the_flight_task_is_denied_counted_and_evented(
    key_file: Path, demo_kind: None, memory_link  # type: ignore[no-untyped-def]
) -> None:
    key = bytes.fromhex(key_file.read_text())
    exe = ground_demo.build(
        ground_demo.config("udpout:127.0.0.1:9", str(key_file)), Resources(mavlink_link=memory_link)
    )
    op = exe.commands.definitions()["demo.NOOP"][0]
    ahead = signing_timestamp(time.time()) + HOUR
    assert _acks(exe, memory_link, [command_frame(key, op, ts=ahead)]) == [(mavlink.MAV_RESULT_DENIED, Reason.FUTURE)]
    assert exe.telemetry.get("mavlink.auth_future") == 1 and exe.events.count("mavlink.AUTH_REJECTED") == 1
    assert exe.tasks["demo"].cmd_count == 0
    assert _acks(exe, memory_link, [command_frame(key, op)]) == [(mavlink.MAV_RESULT_ACCEPTED, 0)]


def test_replay_of_a_pre_restart_command_is_refused_after_the_restart(
    key_file: Path, demo_kind: None, memory_link, tmp_path: Path  # type: ignore[no-untyped-def]
) -> None:
    """req(12.6): the window is saved (atomically, next to the key) and restored at start-up."""
    key = bytes.fromhex(key_file.read_text())
    cfg = ground_demo.config("udpout:127.0.0.1:9", str(key_file))
    exe = ground_demo.build(cfg, Resources(mavlink_link=memory_link))
    op = exe.commands.definitions()["demo.NOOP"][0]
    recorded = command_frame(key, op)  # a command an eavesdropper records
    assert _acks(exe, memory_link, [recorded]) == [(mavlink.MAV_RESULT_ACCEPTED, 0)]
    window = signing_store.default_path(str(key_file))
    assert window.is_file() and oct(window.stat().st_mode & 0o777) == "0o600"
    assert not list(window.parent.glob(f".{window.name}.*.tmp"))  # no temporary left behind

    again = ground_demo.build(cfg, Resources(mavlink_link=memory_link))  # the restart
    assert again.events.count("mavlink.WINDOW_LOADED") == 1
    assert _acks(again, memory_link, [recorded]) == [(mavlink.MAV_RESULT_DENIED, Reason.REPLAY)]
    assert again.tasks["demo"].cmd_count == 0 and again.telemetry.get("mavlink.auth_replay") == 1
    # the window on disk runs signing_reserve_s ahead: the ground's next command past it is accepted
    past = signing_timestamp(time.time()) + int((cfg.mavlink.signing_reserve_s + 1) * 100_000)
    assert _acks(again, memory_link, [command_frame(key, op, ts=past)]) == [(mavlink.MAV_RESULT_ACCEPTED, 0)]

    fresh = ground_demo.build(  # without the saved window the same replay would have passed
        ground_demo.config("udpout:127.0.0.1:9", str(key_file), extra={"signing_state_file": str(tmp_path / "x")}),
        Resources(mavlink_link=memory_link),
    )
    assert _acks(fresh, memory_link, [recorded]) == [(mavlink.MAV_RESULT_ACCEPTED, 0)]


def test_a_damaged_window_file_is_reported_not_fatal(
    key_file: Path, demo_kind: None, memory_link  # type: ignore[no-untyped-def]
) -> None:
    window = signing_store.default_path(str(key_file))
    for junk in (b"\x00\xff garbage", json.dumps({"version": 1, "streams": [[1, 2, "x", 4]]}).encode()):
        window.write_bytes(junk)
        exe = ground_demo.build(
            ground_demo.config("udpout:127.0.0.1:9", str(key_file)), Resources(mavlink_link=memory_link)
        )
        assert exe.events.count("mavlink.WINDOW_BAD") == 1


def test_store_round_trip_and_refusals(tmp_path: Path) -> None:
    path = tmp_path / "w" / "replay.json"
    assert signing_store.load(path) == ({}, None)
    streams = {(1, 255, 190): 123456789, (0, 254, 1): 5}
    signing_store.save(path, streams)
    assert signing_store.load(path) == (streams, None)
    path.write_text('{"version": 2, "streams": []}')
    assert signing_store.load(path)[1] is not None
