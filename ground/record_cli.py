"""``safer-ground record LOG.tlog --out mission.mcap``: a Foxglove recording of any run from its
telemetry log, made on the ground (a real-time mission's flight process records nothing).

What the link carried goes into the same topics as a bench recording (``ground.recording``):
the pose (LOCAL_POSITION_NED + ATTITUDE) and the mast (GIMBAL_DEVICE_ATTITUDE_STATUS) on ``/tf``
(at most 5 Hz), the events (STATUSTEXT, long ones reassembled) on ``/recon/events``, and each
complete map preview (image transfer) as ``/recon/map/preview``. Exit 2 and one line for a
file that is not a readable .tlog."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from types import SimpleNamespace

from ground.dictionary import GroundDictionary

HELP = "write a Foxglove recording (MCAP) of a run from its .tlog (pose, mast, events, map previews)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("tlog", metavar="LOG.tlog", help="telemetry log of a run")
    p.add_argument("--out", type=Path, required=True, metavar="MCAP", help="recording to write (.mcap)")
    p.add_argument("--vehicle", default="recon", help="the source's name (topic and frame prefix)")


def _level(severity: int) -> object:
    from foxglove import messages as fm

    if severity <= 2:
        return fm.LogLevel.Fatal
    return {3: fm.LogLevel.Error, 4: fm.LogLevel.Warning, 7: fm.LogLevel.Debug}.get(severity, fm.LogLevel.Info)


def run(args: argparse.Namespace, d: GroundDictionary) -> int:
    from fsw.comm.mavlink_tlog import TlogError
    from ground.recording import MissionRecorder
    from ground.state import GroundState
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
    src = rec.source(args.vehicle)
    st = GroundState(d)
    last_event, images, next_pose = None, 0, -1.0
    pose_kinds = {"LOCAL_POSITION_NED", "ATTITUDE", "GIMBAL_DEVICE_ATTITUDE_STATUS"}
    try:
        for lm in messages:
            st.feed(lm.msg, lm.time_s)
            kind = lm.msg.get_type()
            if kind in pose_kinds and st.position_ned is not None and lm.time_s >= next_pose:
                next_pose = lm.time_s + 0.2
                n, e, dn = st.position_ned
                pan, tilt = st.mast or (0.0, 0.0)
                src.pose(lm.time_s, SimpleNamespace(x=n, y=-e, z_m=-dn, roll=0.0, pitch=0.0,
                                                    yaw=-(st.yaw_ned or 0.0), joints=(pan, tilt, 0.0)))
            if st.events and st.events[-1] is not last_event:
                new = []
                for ev in reversed(st.events):
                    if ev is last_event:
                        break
                    new.append(ev)
                for ev in reversed(new):
                    src.log_line(ev.time_s, _level(ev.severity), ev.text.split(":", 1)[0], ev.text)
                last_event = st.events[-1]
            done = [im for im in st.images.images if im.complete]
            for im in done[images:]:
                src.map_preview(lm.time_s, bytes(im.data))
            images = len(done)
    finally:
        rec.close()
    c = src.counts
    print(f"{args.out}: {c['pose']} poses, {c['events']} events, {c['map']} map previews from {args.tlog}")
    return 0
