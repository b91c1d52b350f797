"""Issue 29, item 5: two vehicles on one link (the RECON-bot is MAVLink system 1, the Cliff-bot
system 2) are two vehicles in ``listen`` and two sources in a recording made from the .tlog."""

from __future__ import annotations

import io
from collections import defaultdict
from pathlib import Path
from typing import Any

import pytest

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


@pytest.mark.slow
def test_map_follows_a_link_and_rewrites_the_picture_per_preview(tmp_path: Path) -> None:
    """Issue 29, item 1: ``safer-ground map URL`` shows the preview live: each complete preview of
    each vehicle rewrites its PNG (system 2's beside the first vehicle's)."""
    import socket
    import threading
    import time

    import cv2
    import numpy as np

    from fsw.comm.mavlink_image import ImageSender

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    out = tmp_path / "live.png"
    rc: list[int] = []
    t = threading.Thread(target=lambda: rc.append(ground_main(
        ["map", f"udpin:127.0.0.1:{port}", "--out", str(out), "--duration", "4", "--scale", "1"])))
    t.start()
    time.sleep(1.0)
    grey = np.full((16, 24), 200, np.uint8)
    grey[:, :8] = 0
    jpeg = cv2.imencode(".jpg", grey)[1].tobytes()
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    for sid in (1, 2):
        codec, sender = new_codec(sid, 1), ImageSender()
        tx.sendto(heartbeat("MOVE", False, False).pack(codec), ("127.0.0.1", port))
        sender.offer(jpeg, 24, 16, mavlink.MAVLINK_DATA_STREAM_IMG_JPEG, 90)
        while (m := sender.peek()) is not None:
            tx.sendto(m.pack(codec), ("127.0.0.1", port))
            sender.consume()
    tx.close()
    t.join(timeout=20)
    assert rc == [0]
    img = cv2.imread(str(out))
    assert img is not None and img.shape[:2] == (16, 24)
    assert img[:, :6].max() == 0 and img[:, 10:].mean() > 50  # unknown black, known coloured
    assert cv2.imread(str(tmp_path / "live.cliffbot.png")) is not None


def test_listen_replays_one_log_per_vehicle_together(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A team mission writes one .tlog per agent (``fsw.tlog``, ``cliffbot.tlog``): ``listen`` given
    both replays them in time order and shows both vehicles; a link and a log together is a usage error."""
    logs = {1: tmp_path / "fsw.tlog", 2: tmp_path / "cliffbot.tlog"}
    bufs = {sid: io.BytesIO() for sid in logs}
    writers = {sid: TlogWriter(buf) for sid, buf in bufs.items()}
    parser = new_codec(250, 1)
    for k, f in enumerate(_frames()):
        sid = (parser.parse_buffer(f) or [])[0].get_srcSystem()
        if sid in writers:
            writers[sid].write(1.7e9 + 0.3 * k, f)
    for sid, path in logs.items():
        writers[sid].flush()
        path.write_bytes(bufs[sid].getvalue())
    assert ground_main(["listen", "--no-color", str(logs[1]), str(logs[2])]) == 0
    out = capsys.readouterr().out
    assert "recon (sys 1) MOVE" in out and "cliffbot (sys 2) SELECT" in out
    assert f"{logs[1]} + {logs[2]}" in out
    assert ground_main(["listen", str(logs[1]), "udpin:127.0.0.1:9"]) == 2
