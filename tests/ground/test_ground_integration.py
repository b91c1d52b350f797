"""Issue 7, done-when 1 and 2: the flight software in lockstep talks to a pymavlink ground
station in another process over loopback UDP; signed commands are accepted, unsigned,
wrong-key, replayed and stale ones are rejected, counted and evented; the .tlog of the run
parses with pymavlink's mavlogdump.py."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import ground_demo
import pytest

from fsw.comm.mavlink_commands import Reason
from fsw.comm.mavlink_dialect import mavlink
from fsw.executive.topology import dictionary

HERE = Path(__file__).resolve().parent.parent / "support"
MAVLOGDUMP = Path(sys.executable).parent / "mavlogdump.py"


@pytest.mark.slow
def test_lockstep_fsw_and_ground_process(tmp_path: Path, key_file: Path, demo_kind: None) -> None:
    """Issue 7, done-when 1: heartbeat + telemetry to another process; command authentication."""
    tlog = tmp_path / "fsw.tlog"
    cmds = dictionary(ground_demo.config("udpout:127.0.0.1:9"))["commands"]
    opcode = next(c["opcode"] for c in cmds if c["name"] == "demo.NOOP")
    proc = subprocess.Popen([sys.executable, str(HERE / "ground_receiver.py"), str(key_file), str(opcode)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline() if proc.stdout else ""
        assert line.startswith("PORT "), proc.stderr.read() if proc.stderr else line
        port = int(line.split()[1])
        exe = ground_demo.build(ground_demo.config(f"udpout:127.0.0.1:{port}", str(key_file), str(tlog)))
        deadline = time.monotonic() + 40.0
        while proc.poll() is None and time.monotonic() < deadline:
            exe.run_lockstep(1)
            time.sleep(0.01)  # rover time runs ~10x real time
        out, err = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
        exe.tasks["mavlink"].close()  # type: ignore[attr-defined]
    report = json.loads(out.strip().splitlines()[-1])
    assert "results" in report, err
    seen = report["seen"]
    for kind in ("HEARTBEAT", "SYS_STATUS", "NAMED_VALUE_FLOAT", "NAMED_VALUE_INT", "LOCAL_POSITION_NED",
                 "ATTITUDE", "GIMBAL_DEVICE_ATTITUDE_STATUS", "STATUSTEXT"):
        assert seen.get(kind, 0) > 0, (kind, seen)
    hb = report["heartbeat"]
    assert hb["type"] == mavlink.MAV_TYPE_GROUND_ROVER and hb["signed"]
    assert not hb["base_mode"] & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED  # standard flags (docs/ground.md)
    res = report["results"]
    accepted, denied = mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_DENIED
    assert res["signed"] == {"result": accepted, "reason": 0, "opcode": opcode}
    assert res["replayed"] == {"result": denied, "reason": Reason.REPLAY, "opcode": opcode}
    assert res["unsigned"] == {"result": denied, "reason": Reason.UNSIGNED, "opcode": opcode}
    assert res["wrong_key"] == {"result": denied, "reason": Reason.BAD_SIGNATURE, "opcode": opcode}
    assert res["stale"] == {"result": denied, "reason": Reason.STALE, "opcode": opcode}
    # counted ...
    tm = exe.telemetry
    assert tm.get("mavlink.cmds_accepted") == 1
    assert (tm.get("mavlink.auth_replay"), tm.get("mavlink.auth_unsigned"), tm.get("mavlink.auth_bad_signature"),
            tm.get("mavlink.auth_stale")) == (1, 1, 1, 1)
    assert exe.tasks["demo"].cmd_count == 1
    # ... and summarised (one event per auth_event_period_s with the count), on board and on the ground
    assert 1 <= exe.events.count("mavlink.AUTH_REJECTED") <= 2
    assert exe.events.count("demo.NOOP") == 1
    rejected = [t for t in report["texts"] if "AUTH_REJECTED" in t]
    assert 1 <= len(rejected) <= 2 and "REPLAY" in rejected[0], report["texts"]

    # Issue 7, done-when 2: the .tlog of this run parses with pymavlink's mavlogdump.py
    dump = subprocess.run([sys.executable, str(MAVLOGDUMP), "--types", "HEARTBEAT,COMMAND_LONG,COMMAND_ACK",
                           str(tlog)], capture_output=True, text=True, timeout=60)
    assert dump.returncode == 0, dump.stderr
    assert dump.stdout.count("COMMAND_ACK") == 5, dump.stdout[-2000:]
    assert dump.stdout.count("COMMAND_LONG") == 5
    assert "HEARTBEAT {type : 10, autopilot : 0" in dump.stdout, dump.stdout[:2000]
