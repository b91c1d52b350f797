"""``safer-hil cliffbot``: the bench Cliff-bot as its own process (docs/algorithm.md §6.6; docs/link.md).

Runs the flight :class:`~fsw.comm.link_receiver.LinkReceiver` (through
:class:`hil_sim.cliffbot_receiver.Cliffbot`) over a radio URL in real time, prints one JSON
line per event and per map, and stops by itself: once ``--count`` maps are verified and the
receiver's close has ended (FIN_ACK, or ``fin_linger_s`` of the ``[link]`` config), or at
``--timeout``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import sys
import time
from dataclasses import asdict
from pathlib import Path

HELP = "bench Cliff-bot: receive maps over a radio (udp://, serial:), verify, decode, report"
DESCRIPTION = (
    "The Cliff-bot's end of the map link as a separate process. Listens on a radio URL "
    "(udp://127.0.0.1:PORT; port 0 picks a free one), answers the RECON-bot's sender, checks "
    "each map's SHA-256, decodes it, draws Figure 13 into --out and prints JSON lines: "
    '{"listening": URL} first, then one report per map (with its SHA-256 and the wall time '
    "it was verified) and, with --events, {\"event\": ...} for every link event. Exits 0 once --count maps "
    "arrived and the close has ended, 1 on --timeout, 2 on bad arguments."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--listen", default="udp://127.0.0.1:0", help="radio URL to receive on")
    p.add_argument("--peer", default="", help="udp: the RECON-bot's udp://HOST:PORT (default: "
                   "answer whoever sent first)")
    p.add_argument("--config", default=None, help="flight config for [link] (default config/fsw.toml)")
    p.add_argument("--out", type=Path, default=Path("out/cliffbot"), help="PNG/npy directory")
    p.add_argument("--original", type=Path, help=".npy original map (for the error check)")
    p.add_argument("--map-id", type=int, default=1, help="map id the original belongs to")
    p.add_argument("--count", type=int, default=1, help="exit after this many maps")
    p.add_argument("--timeout", type=float, default=300.0, help="give up after this many seconds")
    p.add_argument("--rate-bps", type=float, default=None, help="radio bit rate (default: [link])")
    p.add_argument("--events", action="store_true", help="also print every link event as a JSON line")
    p.add_argument("--no-decode", action="store_true",
                   help="verify and report only (for raw payloads that are not map containers)")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from fsw.drivers.radio import open_radio
    from fsw.framework.params import ConfigError
    from hil_sim.cliffbot_receiver import Cliffbot
    from hil_sim.link.link_pump import load_link_config, monotonic_clock, pump_once

    def fail(msg: str) -> int:
        print(f"safer-hil cliffbot: error: {msg}", file=sys.stderr)
        return 2

    if args.count < 1 or not (math.isfinite(args.timeout) and args.timeout > 0):
        return fail("need --count >= 1 and a finite --timeout > 0")
    try:
        link = load_link_config(args.config, args.rate_bps)
    except (ConfigError, ValueError) as exc:
        return fail(str(exc))
    originals = {}
    if args.original is not None:
        try:
            originals[args.map_id] = np.load(args.original, allow_pickle=False).astype(np.float32)
        except (OSError, ValueError) as exc:
            return fail(f"{args.original}: {exc}")
    try:
        port = open_radio(args.listen, args.peer)
    except (ValueError, OSError) as exc:
        return fail(str(exc))
    bot = Cliffbot(link, port, None if args.no_decode else args.out, originals,
                   decode=not args.no_decode)
    url = args.listen
    if hasattr(port, "address"):
        url = "udp://{}:{}".format(*port.address)
    print(json.dumps({"listening": url}), flush=True)
    clock = monotonic_clock()
    with port:
        while clock() < args.timeout:
            pump_once(bot.rx, port, clock, 0.05)
            for ev in bot.rx.events.pop_all():
                if args.events:
                    print(json.dumps({"event": ev.name, "wall_s": time.time(), **ev.args}), flush=True)
            for rep, data in bot.collect():
                print(json.dumps({**asdict(rep), "sha256": hashlib.sha256(data).hexdigest(),
                                  "verified_wall_s": time.time()}), flush=True)
            if len(bot.reports) >= args.count and not bot.rx.closing:
                return 0
    print(json.dumps({"timeout_s": args.timeout, "maps": len(bot.reports)}), flush=True)
    return 1
