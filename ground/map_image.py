"""``safer-ground map LOG.tlog|CHECKPOINT|URL --out map.png``: the map preview reassembled from image
transfers, or the map of a checkpoint; live from a link (``udpin:0.0.0.0:14550``, ...), ``--out``
is rewritten (atomically: an image viewer that reloads it never reads half a file) each time a
preview completes, one line per preview, until Ctrl-C or ``--duration``.

Feeds the log's DATA_TRANSMISSION_HANDSHAKE + ENCAPSULATED_DATA messages (from the rover)
to the same reassembler the live view uses, decodes the chosen image (JPEG/PNG/PGM/BMP) and
writes it as PNG, optionally enlarged and false-coloured (unknown cells, value 0, stay
black, grey levels below 8). Exit code 1 when the log holds no complete preview. A map
checkpoint (``SAFERMAP``, fsw/core/map/checkpoint.py) is drawn in metres: elevation with +y up
(``origin="lower"``, as ``map.png`` of a mission), axes in metres and a colour bar.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from ground.dictionary import GroundDictionary

HELP = "write the map preview reassembled from the image transfers in a .tlog, or a checkpoint's map, as PNG"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("tlog", metavar="LOG.tlog|CHECKPOINT|URL",
                   help="telemetry log, a map checkpoint, or a link to follow live (udpin:HOST:PORT, "
                        "udpout:HOST:PORT, serial:DEVICE)")
    p.add_argument("--out", required=True, metavar="PNG", help="output image (PNG)")
    p.add_argument("--index", type=int, default=-1,
                   help="which complete preview: 0 = first, -1 = last")
    p.add_argument("--scale", type=int, default=4, help="enlarge by this integer factor")
    p.add_argument("--gray", action="store_true", help="keep the grey levels (default: viridis colours)")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="live: stop after S seconds")
    p.add_argument("--system", type=int, default=None, metavar="ID",
                   help="live: only this vehicle's previews (MAVLink system id; default every vehicle's)")


def images_from(messages: list[Any]) -> tuple[list[Any], int]:
    """Complete images and the number of incomplete ones, from the rover's messages."""
    from fsw.comm.mavlink_image import ImageReceiver

    rx = ImageReceiver()
    for lm in messages:
        rx.feed(lm.msg, lm.time_s)
    rx.close()
    done = [im for im in rx.images if im.complete]
    return done, len(rx.images) - len(done)


def run(args: argparse.Namespace, d: GroundDictionary) -> int:
    import cv2
    import numpy as np

    from fsw.comm.mavlink_tlog import TlogError
    from ground.tlog import load_messages

    if args.scale < 1 or args.scale > 64:
        print("safer-ground map: --scale must be 1..64", file=sys.stderr)
        return 2
    if not args.out.lower().endswith(".png"):
        print("safer-ground map: --out must name a .png file", file=sys.stderr)
        return 2
    from fsw.core.map import checkpoint

    if args.tlog.split(":", 1)[0] in ("udpin", "udpout", "serial"):
        return follow(args)
    try:
        with open(args.tlog, "rb") as fh:
            head = fh.read(len(checkpoint.MAGIC))
    except OSError as exc:
        print(f"safer-ground map: {args.tlog}: cannot read ({exc.strerror or exc})", file=sys.stderr)
        return 2
    if head == checkpoint.MAGIC:
        return render_checkpoint(args.tlog, args.out)
    try:
        messages, note = load_messages(args.tlog)
    except TlogError as exc:
        print(f"safer-ground map: {exc}", file=sys.stderr)
        return 2
    if note:
        print(f"safer-ground map: warning: {note}", file=sys.stderr)
    done, incomplete = images_from(messages)
    if not done:
        print(f"safer-ground map: no complete map preview in {args.tlog} ({incomplete} incomplete)", file=sys.stderr)
        return 1
    if not -len(done) <= args.index < len(done):
        print(f"safer-ground map: --index {args.index} out of range ({len(done)} complete previews)", file=sys.stderr)
        return 2
    im = done[args.index]
    img = cv2.imdecode(np.frombuffer(im.data, np.uint8), cv2.IMREAD_GRAYSCALE)
    if img is None:
        print(f"safer-ground map: preview {args.index} does not decode (type {im.info.kind})", file=sys.stderr)
        return 1
    if not write_preview(img, args.out, args.scale, args.gray):
        print(f"safer-ground map: cannot write {args.out}", file=sys.stderr)
        return 2
    print(f"{args.out}: preview {args.index % len(done) + 1} of {len(done)} complete "
          f"({incomplete} incomplete), {im.info.width}x{im.info.height} px, {im.info.size} B in "
          f"{im.info.packets} packets")
    return 0


def write_preview(grey: Any, out: str, scale: int, gray: bool) -> bool:
    """A decoded preview (grey levels) to ``out`` as PNG, enlarged and false-coloured (unknown
    black), written under a temporary name and renamed; False if it cannot be written."""
    import os

    import cv2

    from fsw.tasks.mavlink_preview import UNKNOWN_BELOW

    img = grey
    if scale > 1:
        img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    if not gray:
        colour = cv2.applyColorMap(img, cv2.COLORMAP_VIRIDIS)
        colour[img < UNKNOWN_BELOW] = 0
        img = colour
    tmp = os.path.join(os.path.dirname(out) or ".", f".{os.path.basename(out)}.tmp.png")
    try:
        if not cv2.imwrite(tmp, img):
            return False
        os.replace(tmp, out)
    except (OSError, cv2.error):
        return False
    return True


def follow(args: argparse.Namespace) -> int:
    """Live: listen on the link (announcing a GCS heartbeat, as listen does) and rewrite ``--out``
    with each complete preview of the vehicle(s)."""
    import time

    import cv2
    import numpy as np

    from fsw.comm.mavlink_image import ImageReceiver
    from ground.link import GroundLink, LinkError
    from ground.state import vehicle_name

    if args.duration is not None and args.duration <= 0:
        print("safer-ground map: --duration must be positive", file=sys.stderr)
        return 2
    try:
        link = GroundLink(args.tlog, 57600)
    except LinkError as exc:
        print(f"safer-ground map: {exc}", file=sys.stderr)
        return 2
    receivers: dict[int, ImageReceiver] = {}
    t0 = time.monotonic()
    n = 0
    print(f"safer-ground map: waiting for map previews on {args.tlog} (Ctrl-C to stop)", flush=True)
    try:
        while args.duration is None or time.monotonic() - t0 < args.duration:
            msg = link.recv(timeout_s=0.2)
            if msg is None or msg.get_type() not in ("DATA_TRANSMISSION_HANDSHAKE", "ENCAPSULATED_DATA"):
                continue
            sid = msg.get_srcSystem()
            if args.system is not None and sid != args.system:
                continue
            rx = receivers.setdefault(sid, ImageReceiver())
            before = sum(im.complete for im in rx.images)
            rx.feed(msg, time.monotonic() - t0)
            done = [im for im in rx.images if im.complete]
            if len(done) == before:
                continue
            img = cv2.imdecode(np.frombuffer(done[-1].data, np.uint8), cv2.IMREAD_GRAYSCALE)
            if img is None:
                print(f"  {vehicle_name(sid)}: a preview that does not decode", flush=True)
                continue
            out = args.out if args.system is not None or len(receivers) == 1 and sid == min(receivers) else \
                args.out.removesuffix(".png") + f".{vehicle_name(sid)}.png"
            n += 1
            ok = write_preview(img, out, args.scale, args.gray)
            print(f"[{time.monotonic() - t0:8.1f} s] {vehicle_name(sid)}: preview {len(done)} "
                  f"({done[-1].info.width}x{done[-1].info.height} px, {done[-1].info.size} B) -> "
                  f"{out if ok else 'NOT WRITTEN'}", flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        link.close()
    print(f"safer-ground map: {n} preview(s) received")
    return 0


def render_checkpoint(path: str, out: str) -> int:
    """Draw a checkpoint's elevation map in metres (+y up, as ``map.png``); exit code."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from fsw.core.map import checkpoint

    try:
        with open(path, "rb") as fh:
            emap, meta = checkpoint.decode(fh.read())
    except (OSError, checkpoint.CheckpointError) as exc:
        print(f"safer-ground map: {path}: map checkpoint, unreadable: {exc}", file=sys.stderr)
        return 2
    fig, ax = plt.subplots(figsize=(7, 5.5), constrained_layout=True)
    im = ax.imshow(np.where(emap.mapped, emap.z, np.nan), origin="lower", extent=emap.grid.extent,
                   cmap="terrain")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"checkpoint {meta.seq}, mission time {meta.time_s:.0f} s: "
                 f"{int(emap.mapped.sum())} cells mapped")
    fig.colorbar(im, ax=ax, shrink=0.85, label="elevation (m)")
    try:
        fig.savefig(out, dpi=90)
    except OSError as exc:
        print(f"safer-ground map: cannot write {out} ({exc.strerror or exc})", file=sys.stderr)
        return 2
    finally:
        plt.close(fig)
    print(f"{out}: checkpoint {meta.seq} at {meta.time_s:.1f} s, {emap.grid.ny}x{emap.grid.nx} cells, "
          f"{int(emap.mapped.sum())} mapped")
    return 0
