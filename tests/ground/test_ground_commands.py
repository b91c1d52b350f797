"""Issue 7, item 2: the command dictionary in COMMAND_LONG, answered by COMMAND_ACK."""

from __future__ import annotations

from pathlib import Path

import ground_demo
import pytest
from ground_demo import command_frame
from hypothesis import given, settings
from hypothesis import strategies as st

from fsw.comm.mavlink_commands import Reason, decode_args, encode_args, string_capacity
from fsw.comm.mavlink_dialect import mavlink, new_codec
from fsw.drivers.resources import Resources
from fsw.framework.commands import Arg, CommandDef

CDEF = CommandDef("X", (Arg("n", int, -1000, 1000), Arg("gain", float), Arg("on", bool),
                        Arg("mode", str, choices=("fast", "slow", "safe")), Arg("target", str)))


@settings(max_examples=150, deadline=None)
@given(n=st.integers(-(2**23), 2**23), gain=st.floats(width=32, allow_nan=False, allow_infinity=False),
       on=st.booleans(), mode=st.sampled_from(("fast", "slow", "safe")),
       target=st.text(alphabet=st.characters(blacklist_characters="\x00", blacklist_categories=("Cs",)),
                      max_size=6))
def test_args_round_trip(n: int, gain: float, on: bool, mode: str, target: str) -> None:
    """Issue 7, item 2: every argument kind survives param2..param7 (float32 on the wire)."""
    args = {"n": n, "gain": gain, "on": on, "mode": mode, "target": target}
    if len(target.encode()) > string_capacity(CDEF):
        with pytest.raises(ValueError, match="UTF-8 bytes"):
            encode_args(CDEF, args)
        return
    params = encode_args(CDEF, args)
    # through a real frame: params become float32
    mav = new_codec(255, 190)
    buf = mavlink.MAVLink_command_long_message(1, 1, 31010, 0, 1.0, *params).pack(mav)
    msg = new_codec(1, 1).parse_buffer(buf)[0]
    wire = [msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7]
    assert decode_args(CDEF, wire) == args


def test_decode_refuses_what_is_not_a_value() -> None:
    with pytest.raises(ValueError, match="expected 0 or 1"):
        decode_args(CDEF, [1, 1.0, 0.5, 0, 0, 0])
    with pytest.raises(ValueError, match="choice index"):
        decode_args(CDEF, [1, 1.0, 1, 3, 0, 0])
    with pytest.raises(ValueError, match="packed string"):
        decode_args(CDEF, [1, 1.0, 1, 0, -1.0, 0])
    with pytest.raises(ValueError, match="do not fit"):
        encode_args(CommandDef("Y", tuple(Arg(f"a{i}") for i in range(7))), {f"a{i}": 0 for i in range(7)})


def _run(exe, link, frames, n=2):  # type: ignore[no-untyped-def]
    link.inbox.extend(frames)
    exe.run_lockstep(n)
    acks = []
    parser = new_codec(255, 190)
    for batch in link.sent:
        for f in batch:
            acks += [m for m in parser.parse_buffer(f) or [] if m.get_type() == "COMMAND_ACK"]
    link.sent.clear()
    return [(a.result, a.progress, a.result_param2) for a in acks]


def test_command_paths_and_acks(key_file: Path, demo_kind: None, memory_link) -> None:  # type: ignore[no-untyped-def]
    """Issue 7, item 2: ACCEPTED / DENIED (validation, bad args, unknown opcode) / FAILED /
    UNSUPPORTED, each answered exactly once with the opcode in result_param2."""
    key = bytes.fromhex(key_file.read_text())
    exe = ground_demo.build(ground_demo.config("udpout:127.0.0.1:9", str(key_file)),
                            Resources(mavlink_link=memory_link))
    ops = {name: op for name, (op, _) in exe.commands.definitions().items()}
    ok, denied, failed = mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_DENIED, mavlink.MAV_RESULT_FAILED
    budget = ops["mavlink.SET_BUDGET"]
    assert _run(exe, memory_link, [command_frame(key, budget, (400, 0, 0, 0, 0, 0))]) == [(ok, 0, budget)]
    assert exe.tasks["mavlink"].adapter.budget_bytes == 400  # type: ignore[attr-defined]
    assert _run(exe, memory_link, [command_frame(key, budget, (100, 0, 0, 0, 0, 0))]) == \
        [(denied, Reason.VALIDATION, budget)]
    assert _run(exe, memory_link, [command_frame(key, budget, (400.5, 0, 0, 0, 0, 0))]) == \
        [(denied, Reason.VALIDATION, budget)]
    enable = ops["exec.SET_TASK_ENABLED"]
    params = encode_args(exe.commands.definitions()["exec.SET_TASK_ENABLED"][1], {"target": "demo", "enabled": False})
    assert _run(exe, memory_link, [command_frame(key, enable, tuple(params))]) == [(ok, 0, enable)]
    assert exe.enabled["demo"] is False
    params = encode_args(exe.commands.definitions()["exec.SET_TASK_ENABLED"][1], {"target": "nope", "enabled": True})
    assert _run(exe, memory_link, [command_frame(key, enable, tuple(params))]) == [(failed, 0, enable)]
    assert _run(exe, memory_link, [command_frame(key, enable, (0.5, 0, 0, 0, 0, 0))]) == \
        [(denied, Reason.BAD_ARGUMENTS, enable)]
    assert _run(exe, memory_link, [command_frame(key, 0xFFFF)]) == [(denied, Reason.UNKNOWN_OPCODE, 0xFFFF)]
    unsupported = command_frame(key, 0, command=mavlink.MAV_CMD_COMPONENT_ARM_DISARM)
    assert _run(exe, memory_link, [unsupported]) == [(mavlink.MAV_RESULT_UNSUPPORTED, 0, 0)]
    not_for_us = command_frame(key, budget, (500, 0, 0, 0, 0, 0), target=(7, 1))
    assert _run(exe, memory_link, [not_for_us]) == []
    t = exe.telemetry
    assert t.get("mavlink.cmds_accepted") == 2 and t.get("mavlink.cmds_refused") == 5
    assert t.get("mavlink.polls_unsupported") == 1  # another MAV_CMD: a poll, counted, never an event
    assert exe.events.count("mavlink.CMD_BAD_ARGS") == 1
    assert exe.events.count("exec.COMMAND_REFUSED") == 2  # unknown opcode, no such task
    assert exe.events.count("mavlink.COMMAND_REFUSED") == 2  # budget out of range, not an integer


def test_no_key_refuses_everything(demo_kind: None, memory_link, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """Issue 7, item 2: without a key (none configured, or unreadable) no command runs."""
    for key_file in ("", str(tmp_path / "missing.key")):
        exe = ground_demo.build(ground_demo.config("udpout:127.0.0.1:9", key_file), Resources(mavlink_link=memory_link))
        op = exe.commands.definitions()["demo.NOOP"][0]
        acks = _run(exe, memory_link, [command_frame(bytes(32), op), command_frame(None, op)])
        denied = mavlink.MAV_RESULT_DENIED
        assert acks == [(denied, Reason.NO_KEY, op), (denied, Reason.UNSIGNED, op)]
        assert exe.events.count("mavlink.KEY_MISSING" if key_file else "mavlink.KEY_NONE") == 1
        assert exe.tasks["demo"].cmd_count == 0
