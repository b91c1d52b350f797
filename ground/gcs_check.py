"""``safer-ground gcs-check URL``: behave as a stock ground station does for a while, and report.

What MAVProxy and QGroundControl ask of a vehicle when they connect, done by a probe
(:class:`GcsProbe`, sans-I/O: messages in, messages to send out): a GCS HEARTBEAT every
second, a HOME_POSITION poll every ``--home-period`` seconds (unsigned MAV_CMD_GET_HOME_POSITION,
as MAVProxy's), a parameter fetch (PARAM_REQUEST_LIST, then PARAM_REQUEST_READ by index for
the gaps once the list stops arriving), and the plan and fence downloads (MISSION_REQUEST_LIST
per mission type, MISSION_REQUEST_INT per item, MISSION_ACK). It also sorts the rover's
STATUSTEXT events: *noise* are the ones that say nothing changed (timing overruns and slips
and their summaries, refusals and answers to routine polls).

Prints what was answered and the noise share; ``--json`` prints it as one JSON line. Exit
0 when every request was answered, 1 when something was not, 3 without a heartbeat.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass, field
from typing import Any

from fsw.comm.mavlink_dialect import mavlink
from ground.dictionary import GroundDictionary

HELP = "act as a stock ground station (params, plan, fence, home polls) and report answers and event noise"
NOISE_EVENTS = ("OVERRUN", "SLIP", "TIMING", "AUTH_REJECTED", "CMD_UNSUPPORTED", "COMMAND_REFUSED", "RX_BAD")
MISSION_TYPES = {"mission": mavlink.MAV_MISSION_TYPE_MISSION, "fence": mavlink.MAV_MISSION_TYPE_FENCE}


def is_noise(text: str) -> bool:
    """True for an event text ``task.EVENT: ...`` whose EVENT says nothing changed."""
    head = text.split(":", 1)[0]
    return head.rsplit(".", 1)[-1] in NOISE_EVENTS


@dataclass
class GcsProbe:
    """The ground station's side of the conversation, driven by ``step(now)`` and ``feed(now, msg)``."""

    target: tuple[int, int] = (1, 1)
    home_period_s: float = 2.0
    param_gap_s: float = 5.0  # no PARAM_VALUE for this long: ask for the missing ones
    params: dict[int, tuple[str, float]] = field(default_factory=dict)  # index -> (id, value)
    param_count: int | None = None
    items: dict[int, dict[int, Any]] = field(default_factory=lambda: {t: {} for t in MISSION_TYPES.values()})
    counts: dict[int, int] = field(default_factory=dict)
    homes: int = 0
    home_polls: int = 0
    acks: dict[int, int] = field(default_factory=dict)  # MAV_RESULT -> count
    events: list[str] = field(default_factory=list)
    heartbeats: int = 0
    modes: set[tuple[int, int]] = field(default_factory=set)  # (base_mode, custom_mode) seen
    _next_hb: float = 0.0
    _next_home: float = 0.5
    _started: bool = False
    _last_param_s: float = 0.0
    _gap_asked: bool = False

    def step(self, now: float) -> list[Any]:
        out: list[Any] = []
        t = self.target
        if now >= self._next_hb:
            self._next_hb = now + 1.0
            out.append(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                                                         mavlink.MAV_STATE_ACTIVE, 3))
        if not self.heartbeats:
            return out
        if not self._started:
            self._started, self._last_param_s = True, now
            out.append(mavlink.MAVLink_param_request_list_message(*t))
            out += [mavlink.MAVLink_mission_request_list_message(*t, mt) for mt in MISSION_TYPES.values()]
        if now >= self._next_home:
            self._next_home = now + self.home_period_s
            self.home_polls += 1
            out.append(mavlink.MAVLink_command_long_message(*t, mavlink.MAV_CMD_GET_HOME_POSITION, 0, *[0.0] * 7))
        if (self.param_count is not None and not self._gap_asked and now - self._last_param_s > self.param_gap_s
                and len(self.params) < self.param_count):
            self._gap_asked = True
            out += [mavlink.MAVLink_param_request_read_message(*t, b"", i)
                    for i in range(self.param_count) if i not in self.params]
        return out

    def feed(self, now: float, msg: Any) -> list[Any]:
        kind, out = msg.get_type(), []
        if kind == "HEARTBEAT" and msg.type != mavlink.MAV_TYPE_GCS:
            self.heartbeats += 1
            self.modes.add((msg.base_mode, msg.custom_mode))
        elif kind == "PARAM_VALUE":
            pid = msg.param_id.decode() if isinstance(msg.param_id, bytes) else str(msg.param_id)
            self.params[msg.param_index] = (pid.split("\x00", 1)[0], msg.param_value)
            self.param_count, self._last_param_s = msg.param_count, now
        elif kind == "HOME_POSITION":
            self.homes += 1
        elif kind == "COMMAND_ACK":
            self.acks[msg.result] = self.acks.get(msg.result, 0) + 1
        elif kind == "STATUSTEXT" and getattr(msg, "chunk_seq", 0) == 0:  # an event's first chunk
            text = msg.text.decode("utf-8", "replace") if isinstance(msg.text, bytes) else str(msg.text)
            self.events.append(text.split("\x00", 1)[0])
        elif kind == "MISSION_COUNT" and msg.mission_type in self.items:
            self.counts[msg.mission_type] = msg.count
            out += [mavlink.MAVLink_mission_request_int_message(*self.target, s, msg.mission_type)
                    for s in range(msg.count)]
            if msg.count == 0:
                out.append(mavlink.MAVLink_mission_ack_message(*self.target, mavlink.MAV_MISSION_ACCEPTED,
                                                               msg.mission_type))
        elif kind == "MISSION_ITEM_INT" and msg.mission_type in self.items:
            got = self.items[msg.mission_type]
            got[msg.seq] = msg
            if len(got) == self.counts.get(msg.mission_type, -1):
                out.append(mavlink.MAVLink_mission_ack_message(*self.target, mavlink.MAV_MISSION_ACCEPTED,
                                                               msg.mission_type))
        return out

    def report(self) -> dict[str, Any]:
        noise = [e for e in self.events if is_noise(e)]
        return {
            "heartbeats": self.heartbeats,
            "params": len(self.params), "param_count": self.param_count,
            "mission_items": {name: len(self.items[t]) for name, t in MISSION_TYPES.items()},
            "mission_counts": {name: self.counts.get(t) for name, t in MISSION_TYPES.items()},
            "home_polls": self.home_polls, "homes": self.homes,
            "acks": {str(k): v for k, v in sorted(self.acks.items())},
            "events": len(self.events), "noise": len(noise),
            "noise_share": len(noise) / len(self.events) if self.events else 0.0,
            "noise_examples": noise[:5],
        }

    def complete(self) -> bool:
        r = self.report()
        return (r["param_count"] is not None and r["params"] == r["param_count"]
                and all(r["mission_counts"][n] == r["mission_items"][n] for n in MISSION_TYPES)
                and r["homes"] >= max(1, self.home_polls - 2))


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("url", help="udpin:HOST:PORT (the rover sends to us), udpout:HOST:PORT or serial:DEVICE")
    p.add_argument("--seconds", type=float, default=60.0, help="how long to behave as a ground station")
    p.add_argument("--home-period", type=float, default=2.0, metavar="S", help="HOME_POSITION poll period")
    p.add_argument("--baud", type=int, default=57600, help="serial: line rate")
    p.add_argument("--json", action="store_true", help="print the report as one JSON line")


def run(args: argparse.Namespace, d: GroundDictionary) -> int:
    from ground.link import LinkError, open_connection

    if args.seconds <= 0 or args.home_period <= 0:
        print("safer-ground gcs-check: --seconds and --home-period must be positive", file=sys.stderr)
        return 2
    try:
        conn = open_connection(args.url, args.baud)
    except LinkError as exc:
        print(f"safer-ground gcs-check: {exc}", file=sys.stderr)
        return 2
    probe = GcsProbe(home_period_s=args.home_period)
    t0 = time.monotonic()
    try:
        while (now := time.monotonic() - t0) < args.seconds:
            for m in probe.step(now):
                _send(conn, m)
            msg = conn.recv_match(blocking=True, timeout=0.1)
            if msg is not None:
                for m in probe.feed(now, msg):
                    _send(conn, m)
    finally:
        conn.close()
    r = probe.report()
    if args.json:
        print(json.dumps(r))
    else:
        for k, v in r.items():
            print(f"{k:15} {v}")
    if not probe.heartbeats:
        return 3
    return 0 if probe.complete() else 1


def _send(conn: Any, msg: Any) -> None:
    try:
        conn.mav.send(msg)
    except Exception as exc:  # noqa: BLE001 - udpin before any peer: nothing to send to yet
        if "Destination" not in str(exc) and not isinstance(exc, (AttributeError, TypeError)):
            raise
