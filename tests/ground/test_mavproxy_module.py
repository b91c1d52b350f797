"""Issue 29: the MAVProxy module ``ground.mavproxy.safer`` names SAFER's modes (both vehicles),
keeps their status and sends mode requests as the project's dictionary commands. Its logic is
tested with pymavlink messages, without MAVProxy (which lives in a venv of its own)."""

from __future__ import annotations

import io
import json
from pathlib import Path

import pytest

from fsw.comm.mavlink_commands import Reason
from fsw.comm.mavlink_dialect import load_mavutil, mavlink, new_codec
from fsw.comm.mavlink_telemetry import CLIFFBOT_STATES, MISSION_STATES, MODES, heartbeat, mode_fields, statustext
from fsw.comm.mavlink_tlog import TlogWriter
from fsw.framework.telemetry import Severity
from ground.mavproxy import safer
from ground.mavproxy.modes import FleetModes, RequestError


def _parse(frame: bytes) -> mavlink.MAVLink_message:
    msgs = new_codec(255, 190).parse_buffer(frame) or []
    assert len(msgs) == 1
    return msgs[0]


def _hb(state: str, system: int) -> mavlink.MAVLink_message:
    return _parse(heartbeat(state, False, True).pack(new_codec(system, 1)))


def test_one_mode_table_for_both_agents() -> None:
    from fsw.tasks.cliffbot.checkpoint import STATES as CLIFFBOT

    assert set(CLIFFBOT) == set(CLIFFBOT_STATES) | {"DONE", "SAFE"} and len(set(MODES)) == len(MODES)
    assert MODES[:len(MISSION_STATES)] == MISSION_STATES  # the RECON-bot's numbers do not move
    for i, name in enumerate(MODES):
        assert mode_fields(name, False, False)[1] == i
        assert FleetModes().mode_string(_hb(name, 2)) == name
    assert mode_fields("DRIVE", False, False)[0] & mavlink.MAV_MODE_FLAG_SAFETY_ARMED


def test_pymavlink_names_safer_modes_while_installed(tmp_path: Path) -> None:
    """pymavlink alone shows the flags; installed, a connection (what MAVProxy reads for its prompt
    and its ``Mode`` announcements) names each system's mode; any other autopilot keeps its names."""
    mavutil = load_mavutil()
    ardurover = _parse(new_codec(3, 1).heartbeat_encode(
        mavlink.MAV_TYPE_GROUND_ROVER, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
        mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 10, mavlink.MAV_STATE_ACTIVE).pack(new_codec(3, 1)))
    assert mavutil.mode_string_v10(_hb("MOVE", 1)).startswith("Mode(0x")
    buf = io.BytesIO()
    w = TlogWriter(buf)
    for k, (state, system) in enumerate([("MOVE", 1), ("WAIT_MAP", 2), ("SAFE", 1), ("DRIVE", 2)]):
        w.write(1.7e9 + k, heartbeat(state, False, False).pack(new_codec(system, 1)))
    w.flush()
    (tmp_path / "two.tlog").write_bytes(buf.getvalue())
    modes = FleetModes()
    original = safer.install(modes)
    try:
        assert mavutil.mode_string_v10(_hb("ACQUIRE", 1)) == "ACQUIRE"
        assert mavutil.mode_string_v10(ardurover) == original(ardurover) == "AUTO"
        conn = mavutil.mavlink_connection(str(tmp_path / "two.tlog"))
        seen = []
        while (m := conn.recv_match(type="HEARTBEAT")) is not None:
            seen.append((m.get_srcSystem(), conn.sysid_state[m.get_srcSystem()].flightmode))
        conn.close()
        assert seen == [(1, "MOVE"), (2, "WAIT_MAP"), (1, "SAFE"), (2, "DRIVE")]
    finally:
        safer.uninstall(original)
    assert mavutil.mode_string_v10 is original


def test_status_lines_and_mode_changes_of_both_vehicles() -> None:
    modes = FleetModes()
    assert modes.feed(_hb("SELECT", 1), 10.0) == ["recon (system 1): mode SELECT"]
    assert modes.feed(_hb("SELECT", 1), 11.0) == []
    assert modes.feed(_hb("MOVE", 1), 12.0) == ["recon (system 1): mode SELECT -> MOVE"]
    assert modes.feed(_hb("WAIT_MAP", 2), 12.5) == ["cliffbot (system 2): mode WAIT_MAP"]
    for m in statustext(Severity.ACTIVITY_HI, "mission.STATE: mission WAIT_MAP -> PLAN", 3):
        modes.feed(_parse(m.pack(new_codec(2, 1))), 13.0)
    assert modes.feed(_hb("MOVE", 9), 13.0) == []  # not one of ours
    lines = modes.status_lines(14.0)
    assert len(lines) == 2 and "mode MOVE" in lines[0] and "ARMED" in lines[0] and "heard   2.0 s" in lines[0]
    assert "1 mode change(s)" in lines[0] and "0 mode change(s)" in lines[1]
    assert "cliffbot" in lines[1] and "last event: mission.STATE: mission WAIT_MAP -> PLAN" in lines[1]
    assert modes.prompt() == "recon:MOVE cliffbot:WAIT_MAP"


@pytest.fixture(scope="module")
def dictionaries(tmp_path_factory: pytest.TempPathFactory) -> dict[int, Path]:
    from fsw.executive.topology import dictionary
    from fsw.settings import load_settings

    root = Path(__file__).resolve().parents[2]
    out = {}
    for system, name in ((1, "fsw.toml"), (2, "cliffbot.toml")):
        out[system] = tmp_path_factory.mktemp("dict") / f"{name}.json"
        out[system].write_text(json.dumps(dictionary(load_settings(root / "config" / name))))
    return out


def test_a_mode_request_is_the_vehicles_dictionary_command(dictionaries: dict[int, Path], tmp_path: Path) -> None:
    modes = FleetModes()
    with pytest.raises(RequestError, match="no dictionary for system 1"):
        modes.request("SAFE", 1)
    assert modes.load_dictionary(1, dictionaries[1]) > 5 and modes.load_dictionary(2, dictionaries[2]) > 1
    ops = {c["name"]: c["opcode"] for c in json.loads(dictionaries[1].read_text())["commands"]}
    name, op, msg = modes.request("safe", 1)
    assert (name, op) == ("mission.ABORT", ops["mission.ABORT"])
    assert (msg.target_system, msg.command, msg.param1) == (1, mavlink.MAV_CMD_USER_1, float(op))
    assert modes.request("RECOVER", 2)[0] == "mission.RECOVER"
    with pytest.raises(RequestError, match="no command for SAFE"):
        modes.request("SAFE", 2)  # the Cliff-bot's SAFE is its own: no command enters it
    with pytest.raises(RequestError, match="no mode request 'MOVE'"):
        modes.request("MOVE", 1)
    (tmp_path / "bad.json").write_text("{}")
    with pytest.raises(RequestError, match="not a dictionary"):
        modes.load_dictionary(1, tmp_path / "bad.json")
    cb = new_codec(1, 1)
    ack = _parse(cb.command_ack_encode(mavlink.MAV_CMD_USER_1, mavlink.MAV_RESULT_DENIED, int(Reason.UNSIGNED), op,
                                       255, 190).pack(cb))
    assert modes.feed(ack, 1.0) == ["recon: mission.ABORT -> DENIED (UNSIGNED): set the key first "
                                    "(`signing key PASSPHRASE`)"]
    assert modes.feed(ack, 1.0) == []  # answered once


def test_loading_it_outside_mavproxy_says_so() -> None:
    if safer.mp_module is not None:
        pytest.skip("MAVProxy is importable here")
    with pytest.raises(ImportError, match="load it from MAVProxy"):
        safer.init(None)
