"""``safer-ground record LOG.tlog --out mission.mcap``: a Foxglove recording of any run from its
telemetry log, made on the ground (a real-time mission's flight process records nothing).

What the link carried goes into the same topics as a bench recording (``ground.recording``):
the pose (LOCAL_POSITION_NED + ATTITUDE) and the mast (GIMBAL_DEVICE_ATTITUDE_STATUS) on ``/tf``
(at most 5 Hz), the events (STATUSTEXT, long ones reassembled) on ``/recon/events``, and each
complete map preview (image transfer) as ``/recon/map/preview``. Each vehicle on the link (MAVLink
system id) is a source of its own: ``/recon/...`` for system 1, ``/cliffbot/...`` for system 2
(``ground.state.VEHICLE_NAMES``). Exit 2 and one line for a file that is not a readable .tlog."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from ground.dictionary import GroundDictionary

HELP = "write a Foxglove recording (MCAP) of a run from its .tlog (pose, mast, events, map previews)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("tlog", metavar="LOG.tlog", help="telemetry log of a run")
    p.add_argument("--out", type=Path, required=True, metavar="MCAP", help="recording to write (.mcap)")
    p.add_argument("--vehicle", default="recon", help="the name (topic and frame prefix) of system 1; other "
                                                      "systems are named as in docs/ground.md (2: cliffbot)")


def _level(severity: int) -> object:
    from foxglove import messages as fm

    if severity <= 2:
        return fm.LogLevel.Fatal
    return {3: fm.LogLevel.Error, 4: fm.LogLevel.Warning, 7: fm.LogLevel.Debug}.get(severity, fm.LogLevel.Info)


def run(args: argparse.Namespace, d: GroundDictionary) -> int:
    from fsw.comm.mavlink_tlog import TlogError
    from ground.recording import MissionRecorder
    from ground.state import Fleet, vehicle_name
    from ground.tlog import load_messages

    if args.out.suffix != ".mcap":
        print("safer-ground record: --out must name a .mcap file", file=sys.stderr)
        return 2
    try:
        messages, note = load_messages(args.tlog)
    except (TlogError, OSError) as exc:
        print(f"safer-ground record: {exc}", file=sys.stderr)
        return 2
    if note:
        print(f"safer-ground record: warning: {note}", file=sys.stderr)
    rec = MissionRecorder(args.out)
    fleet = Fleet(d)
    feeds: dict[int, _Feed] = {}
    try:
        for lm in messages:
            st = fleet.feed(lm.msg, lm.time_s)
            if st is None:
                continue
            sid = lm.msg.get_srcSystem()
            if sid not in feeds:
                feeds[sid] = _Feed(rec.source(args.vehicle if sid == 1 else vehicle_name(sid)))
            feeds[sid].update(st, lm.msg.get_type(), lm.time_s)
    finally:
        rec.close()
    if not feeds:
        print(f"{args.out}: no vehicle HEARTBEAT in {args.tlog}: an empty recording")
    for f in feeds.values():
        c = f.src.counts
        print(f"{args.out}: /{f.src.vehicle}: {c['pose']} poses, {c['events']} events, {c['map']} map previews "
              f"from {args.tlog}")
    return 0


class _Feed:
    """What one vehicle's state adds to its recording source since the last message."""

    POSE_KINDS = frozenset({"LOCAL_POSITION_NED", "ATTITUDE", "GIMBAL_DEVICE_ATTITUDE_STATUS"})

    def __init__(self, src: object) -> None:
        self.src: Any = src
        self.last_event: object = None
        self.images = 0
        self.next_pose = -1.0

    def update(self, st: Any, kind: str, t: float) -> None:
        src = self.src
        if kind in self.POSE_KINDS and st.position_ned is not None and t >= self.next_pose:
            self.next_pose = t + 0.2
            n, e, dn = st.position_ned
            pan, tilt = st.mast or (0.0, 0.0)
            src.pose(t, SimpleNamespace(x=n, y=-e, z_m=-dn, roll=0.0, pitch=0.0,
                                        yaw=-(st.yaw_ned or 0.0), joints=(pan, tilt, 0.0)))
        if st.events and st.events[-1] is not self.last_event:
            new = []
            for ev in reversed(st.events):
                if ev is self.last_event:
                    break
                new.append(ev)
            for ev in reversed(new):
                src.log_line(ev.time_s, _level(ev.severity), ev.text.split(":", 1)[0], ev.text)
            self.last_event = st.events[-1]
        done = [im for im in st.images.images if im.complete]
        for im in done[self.images:]:
            src.map_preview(t, bytes(im.data))
        self.images = len(done)
