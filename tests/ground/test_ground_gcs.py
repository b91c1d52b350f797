"""Issue 29, items 2 and 3: a stock ground station's requests, answered by the flight MAVLink task.

pymavlink plays the ground station as MAVProxy does: a HEARTBEAT a second, ``param fetch``
(PARAM_REQUEST_LIST, then PARAM_REQUEST_READ for the gaps), ``wp list`` and ``fence list``
(MISSION_REQUEST_LIST per mission type, then MISSION_REQUEST_INT per item, MISSION_ACK),
a HOME_POSITION poll every 2 s (unsigned COMMAND_LONG MAV_CMD_GET_HOME_POSITION) and a
PARAM_SET unsigned, then signed. Stepped clock, deterministic task timer (the subject is
what is answered and how many events it costs, not CPU time)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import ground_demo
from ground_demo import MemoryLink

from fsw.comm import mavlink_params as mp
from fsw.comm.mavlink_dialect import load_mavutil, mavlink, new_codec, signing_timestamp
from fsw.comm.mavlink_plan import GroundPlan
from fsw.comm.mavlink_telemetry import MISSION_STATES, mode_fields
from fsw.drivers.resources import Resources
from fsw.executive.executive import Executive
from fsw.framework.clock import SteppedClock

FRAME_S = 0.1
PLAN = GroundPlan(stations=((0.0, 0.0, 0.0), (1.0, -0.5, 0.5), (2.0, -0.8, 0.3)), current=2,
                  fence=(((3.0, 1.0), (3.2, 1.0), (3.2, -2.0), (3.0, -2.0)),))
#: events that say nothing changed: timing noise and answers to routine polls
NOISE = ("OVERRUN", "SLIP", "TIMING", "AUTH_REJECTED", "CMD_UNSUPPORTED", "RX_BAD", "COMMAND_REFUSED")


class Gcs:
    """A ground station on the other end of a MemoryLink (pymavlink codecs both ways)."""

    def __init__(self, link: MemoryLink, key: bytes) -> None:
        self.link, self.key = link, key
        self.tx = new_codec(255, 190)
        self.signed = new_codec(255, 190)
        self.signed.signing.secret_key, self.signed.signing.sign_outgoing = key, True
        self.signed.signing.link_id = 1
        self.signed.signing.timestamp = signing_timestamp(time.time())
        self.rx = new_codec(255, 190)
        self.seen = 0
        self.got: list[tuple[float, Any]] = []

    def send(self, msg: Any, signed: bool = False) -> None:
        self.link.inbox.append(bytes(msg.pack(self.signed if signed else self.tx)))

    def read(self, now: float) -> list[Any]:
        out = []
        for batch in self.link.sent[self.seen:]:
            for f in batch:
                out += [m for m in self.rx.parse_buffer(f) or []]
        self.seen = len(self.link.sent)
        self.got += [(now, m) for m in out]
        return out


def _rover(key_file: Path, link: MemoryLink) -> Executive:
    cfg = ground_demo.config("udpout:127.0.0.1:9", str(key_file))
    clock = SteppedClock()
    return Executive(cfg, clock, Resources(mavlink_link=link), timer=clock.now)


def test_a_stock_ground_station_is_served_and_costs_no_noise(key_file: Path, demo_kind: None) -> None:
    """req(29.2), req(29.3): every parameter, the plan, the fence and HOME answered; <= 5 % noise."""
    key = bytes.fromhex(key_file.read_text())
    link = MemoryLink()
    exe = _rover(key_file, link)
    exe.bus.publish("mission.plan", PLAN)
    gcs = Gcs(link, key)
    table = mp.build_table(exe.cfg)
    params: dict[str, float] = {}
    missions: dict[int, dict[int, Any]] = {mavlink.MAV_MISSION_TYPE_MISSION: {},
                                           mavlink.MAV_MISSION_TYPE_FENCE: {}}
    counts: dict[int, int] = {}
    homes: list[float] = []
    hb_id = mp.param_id(("mavlink", "heartbeat_period_s"))
    for k in range(int(60 / FRAME_S)):
        now = k * FRAME_S
        if k % 10 == 0:
            gcs.send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
        if k % 20 == 5:  # MAVProxy's home poll
            gcs.send(mavlink.MAVLink_command_long_message(1, 1, mavlink.MAV_CMD_GET_HOME_POSITION, 0, *[0] * 7))
        if k == 3:
            gcs.send(mavlink.MAVLink_param_request_list_message(1, 1))
        if k == 250:  # gaps, asked one by one
            for p in table:
                if p.pid not in params:
                    gcs.send(mavlink.MAVLink_param_request_read_message(1, 1, p.pid.encode(), -1))
        if k in (4, 6):
            mtype = mavlink.MAV_MISSION_TYPE_MISSION if k == 4 else mavlink.MAV_MISSION_TYPE_FENCE
            gcs.send(mavlink.MAVLink_mission_request_list_message(1, 1, mtype))
        if k == 300:
            gcs.send(mavlink.MAVLink_param_set_message(1, 1, hb_id.encode(), 0.5, mavlink.MAV_PARAM_TYPE_REAL32))
        if k == 320:
            gcs.send(mavlink.MAVLink_param_set_message(1, 1, hb_id.encode(), 0.5, mavlink.MAV_PARAM_TYPE_REAL32),
                     signed=True)
        if k == 340:  # not a run-time key: refused with a reason, value unchanged
            gcs.send(mavlink.MAVLink_param_set_message(1, 1, b"MAV_SYSTEM_ID", 7, mavlink.MAV_PARAM_TYPE_INT32),
                     signed=True)
        exe.run_lockstep(1)
        for m in gcs.read(now):
            kind = m.get_type()
            if kind == "PARAM_VALUE":
                params[mp.decode_id(m.param_id)] = m.param_value
            elif kind == "HOME_POSITION":
                homes.append(now)
                assert (m.x, m.y, m.z) == (0.0, 0.0, 0.0)
            elif kind == "MISSION_COUNT":
                counts[m.mission_type] = m.count
                for seq in range(m.count):
                    gcs.send(mavlink.MAVLink_mission_request_int_message(1, 1, seq, m.mission_type))
            elif kind == "MISSION_ITEM_INT":
                missions[m.mission_type][m.seq] = m
                if len(missions[m.mission_type]) == counts[m.mission_type]:
                    gcs.send(mavlink.MAVLink_mission_ack_message(1, 1, mavlink.MAV_MISSION_ACCEPTED, m.mission_type))

    # param fetch: every parameter, with the config's values; the signed set applied, the other refused
    assert set(params) == {p.pid for p in table} and len(table) > 200
    assert params[mp.param_id(("mavlink", "budget_bytes_per_frame"))] == exe.cfg.mavlink.budget_bytes_per_frame
    assert params[hb_id] == 0.5 and exe.tasks["mavlink"].cfg.heartbeat_period_s == 0.5
    assert params["MAV_SYSTEM_ID"] == 1.0
    errors = [m for _, m in gcs.got if m.get_type() == "PARAM_ERROR"]
    assert [e.error for e in errors] == [mavlink.MAV_PARAM_ERROR_READ_ONLY]
    hb = [t for t, m in gcs.got if m.get_type() == "HEARTBEAT" and t > 40.0]
    assert max(b - a for a, b in zip(hb, hb[1:], strict=False)) <= 0.6  # the new period is in force
    # wp list and fence list: the plan's stations and the fence polygon, local NED in 1e-4 m
    wps = missions[mavlink.MAV_MISSION_TYPE_MISSION]
    assert [(wps[i].x, wps[i].y) for i in range(3)] == [(0, 0), (10000, 5000), (20000, 8000)]
    assert wps[2].current == 1 and all(w.frame == mavlink.MAV_FRAME_LOCAL_NED for w in wps.values())
    fence = missions[mavlink.MAV_MISSION_TYPE_FENCE]
    assert len(fence) == 4 and all(f.command == mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION
                                   and f.param1 == 4 for f in fence.values())
    # HOME_POSITION for every poll (30 in 60 s), each with an ACCEPTED ack
    assert len(homes) == 30
    acks = [m for _, m in gcs.got if m.get_type() == "COMMAND_ACK"]
    assert len(acks) == 30 and all(a.result == mavlink.MAV_RESULT_ACCEPTED for a in acks)
    # events: the unsigned PARAM_SET is the only refusal (one summary); no event per poll
    names = [e.name.split(".", 1)[1] for e in exe.events.history]
    noise = [n for n in names if n in NOISE]
    assert noise == ["AUTH_REJECTED"] and len(noise) <= 0.05 * len(names) + 1
    assert names.count("PARAM_SET") == 1 and names.count("PARAM_SET_REFUSED") == 1
    assert exe.telemetry.get("mavlink.polls") == 30 and exe.telemetry.get("mavlink.polls_unsupported") == 0
    assert all(t.exceptions == 0 for t in exe.tasks.values())


def test_standard_mode_flags_are_never_named_with_another_autopilots_table() -> None:
    """req(29.2): MAVProxy (mavutil.mode_string_v10) no longer shows ArduRover names for our states."""
    mavutil = load_mavutil()
    rover_names = set(mavutil.mode_mapping_rover.values())
    for i, name in enumerate(MISSION_STATES):
        base, custom, status = mode_fields(name, False, True)
        hb = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GROUND_ROVER, mavlink.MAV_AUTOPILOT_GENERIC,
                                               base, custom, status, 3)
        assert custom == i and not base & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        assert mavutil.mode_string_v10(hb) not in rover_names
    assert mode_fields("MOVE", False, False)[0] & mavlink.MAV_MODE_FLAG_AUTO_ENABLED
    assert mode_fields("MOVE", False, False)[0] & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    assert not mode_fields("SAFE", False, False)[0] & mavlink.MAV_MODE_FLAG_SAFETY_ARMED


def test_the_gcs_check_probe_is_fully_answered_by_the_flight_task(key_file: Path, demo_kind: None) -> None:
    """req(29.2): ``safer-ground gcs-check``'s probe, on the stepped clock: everything answered, no noise."""
    from ground.gcs_check import GcsProbe

    link = MemoryLink()
    exe = _rover(key_file, link)
    exe.bus.publish("mission.plan", PLAN)
    probe, rx, tx = GcsProbe(), new_codec(255, 190), new_codec(255, 190)
    for k in range(int(30 / FRAME_S)):
        now = k * FRAME_S
        link.inbox.extend(bytes(m.pack(tx)) for m in probe.step(now))
        exe.run_lockstep(1)
        for f in link.sent[-1]:
            for msg in rx.parse_buffer(f) or []:
                link.inbox.extend(bytes(m.pack(tx)) for m in probe.feed(now, msg))
    r = probe.report()
    assert probe.complete(), r
    assert r["mission_items"] == {"mission": 3, "fence": 4} and r["homes"] == r["home_polls"] >= 14
    assert r["events"] >= 5 and r["noise"] == 0
