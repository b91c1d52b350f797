"""A pymavlink ground station in its own process, for the integration test (not a test file).

Usage: ``python ground_receiver.py KEY_FILE`` - binds ``udpin:127.0.0.1:0``, prints
``PORT <n>``, waits for the rover's heartbeat, collects telemetry, then sends five
commands and prints one JSON line with what it saw: a correctly signed NOOP, the same
frame again (replay), an unsigned one, one signed with another key, and one signed with a
two-minute-old timestamp on a new stream (stale).
"""

from __future__ import annotations

import json
import os
import socket
import sys
import time
from collections import Counter
from typing import Any

os.environ["MAVLINK20"] = "1"
os.environ["MAVLINK_DIALECT"] = "common"
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import common as mavlink  # noqa: E402

SIGNING_EPOCH = 1420070400


def main() -> int:
    with open(sys.argv[1]) as fh:
        key = bytes.fromhex(fh.read().strip())
    opcode = int(sys.argv[2])
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255, source_component=190)
    print(f"PORT {port}", flush=True)
    seen: Counter[str] = Counter()
    texts: list[str] = []
    chunks: dict[int, list[str]] = {}
    acks: list[dict[str, Any]] = []
    hb: Any = None

    def pump(until: float, want_ack: bool = False) -> Any:
        nonlocal hb
        while time.monotonic() < until:
            m = conn.recv_match(blocking=True, timeout=0.05)
            if m is None:
                continue
            kind = m.get_type()
            seen[kind] += 1
            if kind == "HEARTBEAT" and hb is None:
                hb = m
            if kind == "STATUSTEXT":  # MAVLink 2 long texts: chunks share an id, a short chunk ends
                text = m.text if isinstance(m.text, str) else m.text.decode()
                chunks.setdefault(m.id, []).append(text)
                if not m.id or len(text.encode()) < 50:
                    texts.append("".join(chunks.pop(m.id)))
            if kind == "COMMAND_ACK":
                acks.append({"result": m.result, "reason": m.progress, "opcode": m.result_param2})
                if want_ack:
                    return m
        return None

    deadline = time.monotonic() + 20.0
    while hb is None and time.monotonic() < deadline:
        pump(time.monotonic() + 0.2)
    if hb is None:
        print(json.dumps({"error": "no heartbeat"}), flush=True)
        return 1
    pump(time.monotonic() + 1.5)  # telemetry for a while (15 s of rover time at 10x)
    target = (hb.get_srcSystem(), hb.get_srcComponent())
    now_ts = int((time.time() - SIGNING_EPOCH) * 100_000)

    def encoder(k: bytes | None, link_id: int, ts: int) -> Any:
        mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        if k is not None:
            mav.signing.secret_key, mav.signing.sign_outgoing = k, True
            mav.signing.link_id, mav.signing.timestamp = link_id, ts
        return mav

    def command(mav: Any) -> bytes:
        msg = mavlink.MAVLink_command_long_message(target[0], target[1], mavlink.MAV_CMD_USER_1, 0,
                                                   float(opcode), 0, 0, 0, 0, 0, 0)
        return bytes(msg.pack(mav))

    good = command(encoder(key, 1, now_ts))
    frames = {
        "signed": good,
        "replayed": good,
        "unsigned": command(encoder(None, 0, 0)),
        "wrong_key": command(encoder(os.urandom(32), 2, now_ts)),
        "stale": command(encoder(key, 3, now_ts - 120 * 100_000)),
    }
    results = {}
    for name, frame in frames.items():
        conn.write(frame)
        ack = pump(time.monotonic() + 5.0, want_ack=True)
        results[name] = None if ack is None else {"result": int(ack.result), "reason": int(ack.progress),
                                                   "opcode": int(ack.result_param2)}
    pump(time.monotonic() + 1.0)  # the rejection events as STATUSTEXT
    print(json.dumps({"results": results, "seen": seen, "texts": texts, "acks": acks,
                      "heartbeat": {"type": hb.type, "custom_mode": hb.custom_mode, "system_status": hb.system_status,
                                    "base_mode": hb.base_mode, "signed": bool(hb.get_header().incompat_flags & 1)}}),
          flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
