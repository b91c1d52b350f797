"""Issue 26, item 3: MAVLink under a flood, on the stepped clock.

An unauthenticated flood keeps the heartbeat and telemetry going and costs no slip; a signed
flood costs a handful of replay-window writes, not one per command, and trips no watchdog; a
command runs only once its timestamp is on disk (an unwritable window: nothing runs); a
command recorded before a restart is refused after it."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import ground_demo
from ground_demo import MemoryLink, command_frame

from fsw.comm.mavlink_commands import Reason
from fsw.comm.mavlink_dialect import mavlink, new_codec, signing_timestamp
from fsw.drivers.resources import Resources
from fsw.executive.executive import Executive
from fsw.framework.clock import SteppedClock
from fsw.framework.telemetry import Severity

FRAME_S = 0.1


def _messages(link: MemoryLink) -> list[tuple[int, Any]]:
    """``(activation, message)`` of everything the rover sent."""
    parser, out = new_codec(255, 190), []
    for k, batch in enumerate(link.sent):
        for f in batch:
            out += [(k, m) for m in parser.parse_buffer(f) or []]
    return out


def _rover(key_file: Path, link: MemoryLink, **extra: Any) -> Executive:
    """The demo rover, its frames timed in CPU time of this thread: a slip is then work that
    did not fit the frame, not the waits of a machine shared with other processes."""
    cfg = ground_demo.config("udpout:127.0.0.1:9", str(key_file), extra=extra)
    return Executive(cfg, SteppedClock(), Resources(mavlink_link=link), timer=time.thread_time)


def _gaps(times: list[float]) -> float:
    return max(b - a for a, b in zip(times, times[1:], strict=False))


def test_an_unsigned_flood_of_2000_per_second_leaves_heartbeat_and_telemetry_alone(
    key_file: Path, demo_kind: None
) -> None:
    """req(26.3): heartbeat period within 2x nominal, telemetry on time, 0 slips, bounded answers."""
    link = MemoryLink()
    exe = _rover(key_file, link)
    exe.run_lockstep(20)  # 2 s of quiet first
    flood_s, per_frame = 10.0, 200  # 2,000 unsigned commands a second, 10 per datagram
    frames = [command_frame(None, 0x101 + i % 7) for i in range(10)]
    for _ in range(int(flood_s / FRAME_S)):
        link.inbox.extend(b"".join(frames) for _ in range(per_frame // 10))
        exe.run_lockstep(1)
    exe.run_lockstep(20)
    mav = exe.tasks["mavlink"]
    msgs = _messages(link)
    hb = [k * FRAME_S for k, m in msgs if m.get_type() == "HEARTBEAT"]
    pose = [k * FRAME_S for k, m in msgs if m.get_type() == "LOCAL_POSITION_NED"]
    in_flood = [t for t in hb if 2.0 <= t <= 12.0]
    assert len(in_flood) >= 9 and _gaps(hb) <= 2 * mav.cfg.heartbeat_period_s
    assert _gaps(pose) <= 2 * mav.cfg.pose_period_s
    assert exe.telemetry.get("mavlink.auth_unsigned") == flood_s * 2000
    assert exe.slips == 0 and exe.tasks["demo"].cmd_count == 0
    denials = [m for _, m in msgs if m.get_type() == "COMMAND_ACK"]
    assert len(denials) <= mav.cfg.denial_acks_per_s * flood_s + 5  # a trickle, not 20,000
    assert exe.telemetry.get("mavlink.acks_suppressed") >= flood_s * 2000 - len(denials)
    assert len(mav.adapter.denials.items) <= mav.adapter.denials.depth
    # one summary per period, with the count, instead of an event per command
    summaries = [e for e in exe.events.history if e.name == "mavlink.AUTH_REJECTED"]
    assert 1 <= len(summaries) <= flood_s / mav.cfg.auth_event_period_s + 2
    assert "UNSIGNED" in summaries[0].text and "latest: opcode 0x10" in summaries[0].text  # the opcode, not 0x0


def test_a_signed_flood_of_300_per_second_costs_few_window_writes_and_no_watchdog(
    key_file: Path, demo_kind: None
) -> None:
    """req(26.3): the replay window is written once per signing_reserve_s, not per command."""
    key = bytes.fromhex(key_file.read_text())
    link = MemoryLink()
    exe = _rover(key_file, link)
    op = exe.commands.definitions()["demo.NOOP"][0]
    ts = signing_timestamp(time.time())
    flood_s, per_frame = 10.0, 30
    for _ in range(int(flood_s / FRAME_S)):
        for _ in range(per_frame):
            ts += 100_000 // 300  # the ground's clock runs in real time
            link.inbox.append(command_frame(key, op, ts=ts))
        exe.run_lockstep(1)
    exe.run_lockstep(10)
    mav, t = exe.tasks["mavlink"], exe.telemetry
    assert t.get("mavlink.window_writes") <= flood_s / mav.cfg.signing_reserve_s + 2  # not 3,000
    ran = exe.tasks["demo"].cmd_count
    assert ran == t.get("mavlink.cmds_accepted") and ran >= flood_s / FRAME_S * mav.cfg.commands_per_frame
    assert ran + t.get("mavlink.cmds_busy") == flood_s * 300
    assert exe.slips == 0
    assert not [e for e in exe.events.history if e.severity <= Severity.WARNING_HI and e.name.startswith("health")]
    assert t.get("health.tasks_fatal") in (0, None)


def test_with_an_unwritable_replay_window_no_command_executes(key_file: Path, demo_kind: None, tmp_path: Path) -> None:
    """req(26.3): a signed, fresh command whose timestamp cannot be recorded is refused (UNRECORDED)."""
    key = bytes.fromhex(key_file.read_text())
    blocker = tmp_path / "not_a_dir"
    blocker.write_text("a file where the window's folder should be")
    link = MemoryLink()
    exe = _rover(key_file, link, signing_state_file=str(blocker / "window.json"))
    op = exe.commands.definitions()["demo.NOOP"][0]
    for _ in range(3):
        link.inbox.append(command_frame(key, op))
        exe.run_lockstep(2)
    acks = [(m.result, m.progress) for _, m in _messages(link) if m.get_type() == "COMMAND_ACK"]
    assert acks == [(mavlink.MAV_RESULT_DENIED, Reason.UNRECORDED)] * 3
    assert exe.tasks["demo"].cmd_count == 0 and exe.telemetry.get("mavlink.cmds_unrecorded") == 3
    assert exe.events.count("mavlink.WINDOW_SAVE_ERROR") == 3


def test_a_command_recorded_before_a_crash_is_refused_after_the_restart(key_file: Path, demo_kind: None) -> None:
    """req(26.3): the window is on disk before the command acts, so a crash right after it
    (no clean shutdown) still knows the timestamp; the restart never reuses it."""
    key = bytes.fromhex(key_file.read_text())
    link = MemoryLink()
    exe = _rover(key_file, link)
    op = exe.commands.definitions()["demo.NOOP"][0]
    ts = signing_timestamp(time.time())
    frames = [command_frame(key, op, ts=ts + i) for i in range(5)]
    link.inbox.extend(frames)
    exe.run_lockstep(1)
    assert exe.tasks["demo"].cmd_count == 5 and exe.telemetry.get("mavlink.window_writes") == 1
    del exe  # the crash: nothing closed, nothing flushed
    link2 = MemoryLink()
    again = _rover(key_file, link2)
    link2.inbox.extend(frames)
    again.run_lockstep(2)
    acks = [(m.result, m.progress) for _, m in _messages(link2) if m.get_type() == "COMMAND_ACK"]
    assert acks == [(mavlink.MAV_RESULT_DENIED, Reason.REPLAY)] * 5 and again.tasks["demo"].cmd_count == 0
