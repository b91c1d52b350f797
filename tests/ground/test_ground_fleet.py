"""Issue 29, item 5: two vehicles on one link (the RECON-bot is MAVLink system 1, the Cliff-bot
system 2) are two vehicles in ``listen`` and two sources in a recording made from the .tlog."""

from __future__ import annotations

import io
from collections import defaultdict
from pathlib import Path
from typing import Any

from fsw.comm.mavlink_dialect import mavlink, new_codec
from fsw.comm.mavlink_telemetry import heartbeat, statustext
from fsw.comm.mavlink_tlog import TlogWriter
from fsw.framework.telemetry import Severity
from ground.cli import main as ground_main
from ground.dictionary import load_dictionary
from ground.listen import Painter, render
from ground.state import Fleet
from ground.tlog import load_messages


def _frames() -> list[bytes]:
    recon, cliff, gcs = new_codec(1, 1), new_codec(2, 1), new_codec(255, 190)
    out = [gcs.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0).pack(gcs)]
    for k in range(3):
        out.append(heartbeat("MOVE", False, True).pack(recon))
        out.append(heartbeat("SELECT", False, True).pack(cliff))
        out.append(recon.local_position_ned_encode(k * 100, 1.0 + k, -2.0, 0.0, 0, 0, 0).pack(recon))
        out.append(cliff.local_position_ned_encode(k * 100, 5.0, 3.0 + k, 0.0, 0, 0, 0).pack(cliff))
    for m in statustext(Severity.ACTIVITY_HI, "mission.STATE: mission SELECT -> MOVE", 0):
        out.append(m.pack(recon))
    for m in statustext(Severity.ACTIVITY_HI, "cliffbot_mission.STATE: SELECT", 0):
        out.append(m.pack(cliff))
    return out


def test_listen_shows_both_vehicles_and_the_chosen_one_in_full() -> None:
    d = load_dictionary()
    fleet = Fleet(d)
    for f in _frames():
        for msg in new_codec(250, 1).parse_buffer(f) or []:
            fleet.feed(msg, 1.0)
    assert sorted(fleet.vehicles) == [1, 2]  # the ground station's own heartbeat is no vehicle
    assert fleet.vehicles[1].mode() == "MOVE" and fleet.vehicles[2].mode() == "SELECT"
    assert fleet.vehicles[2].position_ned == (5.0, 5.0, 0.0)
    screen = render(fleet.pick(2), d, "x.tlog", 1.0, Painter(False), fleet=fleet)
    assert "[cliffbot (sys 2) SELECT]" in screen and "recon (sys 1) MOVE" in screen
    assert "cliffbot_mission.STATE" in screen and "mission.STATE: mission SELECT" not in screen
    assert fleet.pick(None) is fleet.vehicles[1] and fleet.pick(7) is None


def test_a_recording_from_a_two_vehicle_tlog_has_a_source_each(tmp_path: Path) -> None:
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    buf = io.BytesIO()
    w = TlogWriter(buf)
    for k, f in enumerate(_frames()):
        w.write(1.7e9 + 0.3 * k, f)
    w.flush()
    tlog = tmp_path / "two.tlog"
    tlog.write_bytes(buf.getvalue())
    assert len(load_messages(str(tlog))[0]) == len(_frames())
    out = tmp_path / "two.mcap"
    assert ground_main(["record", str(tlog), "--out", str(out)]) == 0
    got: dict[str, list[Any]] = defaultdict(list)
    with out.open("rb") as fh:
        for _s, channel, _m, msg in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            got[channel.topic].append(msg)
    assert [m.message for m in got["/recon/events"]] == ["mission.STATE: mission SELECT -> MOVE"]
    assert [m.message for m in got["/cliffbot/events"]] == ["cliffbot_mission.STATE: SELECT"]
    frames = {t.child_frame_id for m in got["/tf"] for t in m.transforms}
    assert {"recon/base_link", "cliffbot/base_link"} <= frames
