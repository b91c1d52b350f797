"""``safer-hil send-map``: the RECON-bot's end of the map link as its own process (docs/algorithm.md §6.6).

Runs the flight :class:`~fsw.comm.link_sender.LinkSender` over the flight radio driver
(``fsw.drivers.radio``, the same pair the executive's radio task uses) in real time, sends
one payload (a map container file, or ``--bytes`` seeded random bytes) and stops by itself:
once DONE and no FIN has come for ``--linger-s`` (the FIN_ACK of its close got through) or
the close was given up, or when the transfer failed, or at ``--timeout``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import sys
import time
from pathlib import Path

HELP = "RECON-bot map link sender alone: send a file or random bytes to a Cliff-bot over a radio"
DESCRIPTION = (
    "The RECON-bot's end of the map link as a separate process (the bench counterpart of "
    "safer-hil cliffbot). Sends --file, or --bytes seeded random bytes, to --peer over "
    "--listen (udp://127.0.0.1:0 picks a free port) with the [link] settings of --config, "
    'and prints JSON lines: {"started_wall_s", "sha256", ...} first, one {"event": ...} per '
    'link event, and {"result": STATE, ...} at the end. Exit 0 when delivered, 1 when the '
    "transfer failed or timed out, 2 on bad arguments."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--peer", required=True, help="the Cliff-bot's (or relay's) udp://HOST:PORT")
    p.add_argument("--listen", default="udp://127.0.0.1:0", help="radio URL to send from")
    p.add_argument("--config", default=None, help="flight config for [link] (default config/fsw.toml)")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--file", type=Path, help="payload file (e.g. a map container from safer-map)")
    src.add_argument("--bytes", type=int, default=65536, help="random payload of this many bytes")
    p.add_argument("--seed", type=int, default=0, help="seed of the random payload")
    p.add_argument("--map-id", type=int, default=1, help="map id (0 .. 2**32-1)")
    p.add_argument("--session", type=int, default=1, help="link session id (1 .. 65535)")
    p.add_argument("--timeout", type=float, default=600.0, help="give up after this many seconds")
    p.add_argument("--rate-bps", type=float, default=None, help="radio bit rate (default: [link])")
    p.add_argument("--linger-s", type=float, default=5.0,
                   help="after delivery, answer FINs until none came for this long")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from fsw.comm.link_sender import LinkSender, SenderState
    from fsw.drivers.radio import open_radio
    from fsw.framework.params import ConfigError
    from hil_sim.link.link_pump import load_link_config, monotonic_clock, pump_once

    def fail(msg: str) -> int:
        print(f"safer-hil send-map: error: {msg}", file=sys.stderr)
        return 2

    finite = all(math.isfinite(x) and x > 0 for x in (args.timeout, args.linger_s))
    if not finite or not 0 <= args.map_id < 2**32 or not 1 <= args.session <= 0xFFFF:
        return fail("need finite --timeout, --linger-s > 0, --map-id in 0..2**32-1, --session in 1..65535")
    try:
        link = load_link_config(args.config, args.rate_bps)
    except (ConfigError, ValueError) as exc:
        return fail(str(exc))
    if args.file is not None:
        try:
            data = args.file.read_bytes()
        except OSError as exc:
            return fail(f"{args.file}: {exc.strerror or exc}")
    else:
        if args.bytes < 1:
            return fail("--bytes must be >= 1")
        data = np.random.default_rng(args.seed).integers(0, 256, args.bytes, dtype=np.uint8).tobytes()
    if not 1 <= len(data) <= link.max_map_bytes:
        return fail(f"payload of {len(data)} bytes outside 1..{link.max_map_bytes} ([link] max_map_bytes)")
    try:
        port = open_radio(args.listen, args.peer)
    except (ValueError, OSError) as exc:
        return fail(str(exc))
    tx = LinkSender(link, session=args.session)
    clock = monotonic_clock()
    print(json.dumps({"started_wall_s": time.time(), "bytes": len(data),
                      "sha256": hashlib.sha256(data).hexdigest()}), flush=True)
    tx.start(args.map_id, data, clock())
    last_fin_s: float | None = None
    with port:
        while clock() < args.timeout:
            before = tx.stats.packets_in
            pump_once(tx, port, clock, 0.05)
            now = clock()
            for ev in tx.events.pop_all():
                print(json.dumps({"event": ev.name, "wall_s": time.time(), **ev.args}), flush=True)
            if tx.state is SenderState.DONE:
                if last_fin_s is None or tx.stats.packets_in > before:
                    last_fin_s = now  # delivery, or a packet (a FIN) since: linger on
                if tx.close_given_up or now - last_fin_s >= args.linger_s:
                    break
            elif tx.finished:
                break
    result = {"result": tx.state.value, "delivered_wall_s": None, "stats": vars(tx.stats),
              "srtt_s": tx.srtt_s, "radio": vars(port.stats)}
    if tx.delivered_s is not None:
        result["delivered_wall_s"] = time.time() - (clock() - tx.delivered_s)
    print(json.dumps(result), flush=True)
    return 0 if tx.state is SenderState.DONE else 1
