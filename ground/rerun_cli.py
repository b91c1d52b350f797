"""``safer-ground rerun MISSION.mcap --out mission.rrd``: a mission's recording for the rerun viewer.

The MCAP a mission writes (``ground.recording``, Foxglove schemas) is converted by rerun's own
MCAP importer (``rerun.log_file_from_path``) into a rerun recording file; open it with
``rerun mission.rrd`` (or the web viewer). Exit 2 and one line for a missing or unreadable file.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ground.dictionary import GroundDictionary

HELP = "convert a mission's MCAP recording into a rerun recording (.rrd)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("mcap", type=Path, metavar="MISSION.mcap", help="a mission's recording (safer-hil run --out DIR)")
    p.add_argument("--out", type=Path, required=True, metavar="RRD", help="rerun recording to write (.rrd)")


def convert(mcap: Path, out: Path, application_id: str = "mit_safer") -> None:
    """Write ``out`` (.rrd) from ``mcap``; ``ValueError`` with the reason if it cannot."""
    import rerun as rr

    with mcap.open("rb") as fh:
        if fh.read(8) != b"\x89MCAP0\r\n":
            raise ValueError(f"{mcap}: not an MCAP file")
    rec = rr.RecordingStream(application_id, recording_id=mcap.stem)
    rec.save(out)
    rec.log_file_from_path(mcap)
    rec.flush()
    rec.disconnect()


def run(args: argparse.Namespace, d: GroundDictionary) -> int:
    if args.out.suffix != ".rrd":
        print("safer-ground rerun: --out must name a .rrd file", file=sys.stderr)
        return 2
    try:
        convert(args.mcap, args.out)
    except (OSError, ValueError) as exc:
        print(f"safer-ground rerun: {getattr(exc, 'strerror', None) or exc}", file=sys.stderr)
        return 2
    print(f"{args.out}: rerun recording of {args.mcap} ({args.out.stat().st_size} B); open with: rerun {args.out}")
    return 0
