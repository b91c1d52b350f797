"""``safer-hil relay``: the radio impairment relay between two loopback UDP ends (docs/link.md).

Runs :class:`hil_sim.link.udp_relay.UdpRelay` (the bench channel model on the wall clock) between
the RECON-bot's side ``a`` and the Cliff-bot's side ``b``; prints
``{"a": "udp://...", "b": "udp://..."}`` first and its counters as one JSON line at the end.
"""

from __future__ import annotations

import argparse
import json
import math
import sys

HELP = "loopback UDP relay with loss (per direction), bit errors, duplication, reordering, outages, a bit-rate cap"
DESCRIPTION = (
    "Impairment relay for the map link over real sockets (127.0.0.1 only). The RECON-bot sends "
    "to side a (any port; the relay answers whoever sent last), the relay forwards to the "
    "Cliff-bot at --b-peer from side b, and back. Each direction is the bench's seeded channel "
    "model (hil_sim/link/radio_channel.py) on the wall clock, with its own random draws; "
    "--reverse-loss gives the answers (b -> a) a loss of their own. Stops after --duration seconds or "
    "--idle-exit seconds without a datagram once traffic started. Exit 2 on bad arguments."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--b-peer", required=True, help="the Cliff-bot's udp://127.0.0.1:PORT")
    p.add_argument("--a-port", type=int, default=0, help="side a port (0: any free)")
    p.add_argument("--b-port", type=int, default=0, help="side b port (0: any free)")
    p.add_argument("--rate-bps", type=float, default=9600.0, help="bit-rate cap of each direction")
    p.add_argument("--latency-s", type=float, default=0.05, help="one-way latency")
    p.add_argument("--loss", type=float, default=0.0, help="packet loss probability (both directions)")
    p.add_argument("--reverse-loss", type=float, default=-1.0,
                   help="loss probability of side b -> a alone (the Cliff-bot's answers, "
                   "acknowledgements included); -1: the same as --loss")
    p.add_argument("--ber", type=float, default=0.0, help="bit error rate")
    p.add_argument("--duplicate", type=float, default=0.0, help="probability a packet arrives twice")
    p.add_argument("--reorder", type=float, default=0.0, help="probability a packet is held back")
    p.add_argument("--reorder-delay-s", type=float, default=0.5, help="longest hold-back")
    p.add_argument("--outage", type=float, nargs=2, action="append", default=[],
                   metavar=("START_S", "DURATION_S"),
                   help="no link in this window, counted from the first datagram (repeatable)")
    p.add_argument("--seed", type=int, default=0, help="seed of the impairments")
    p.add_argument("--duration", type=float, default=600.0, help="stop after this many seconds")
    p.add_argument("--idle-exit", type=float, default=10.0,
                   help="stop after this many seconds without a datagram (once traffic started)")


def channel_config(args: argparse.Namespace) -> object:
    """The channel model of the arguments; ConfigError/ValueError on bad values."""
    from fsw.framework.params import build
    from hil_sim.link.radio_channel import RadioChannelConfig

    values = {"rate_bps": args.rate_bps, "latency_s": args.latency_s, "loss": args.loss,
              "reverse_loss": args.reverse_loss,
              "ber": args.ber, "duplicate": args.duplicate, "reorder": args.reorder,
              "reorder_delay_s": args.reorder_delay_s}
    for k, v in values.items():
        if not math.isfinite(v):
            raise ValueError(f"--{k.replace('_', '-')}: {v} is not a finite number")
    for start, dur in args.outage:
        if not (math.isfinite(start) and math.isfinite(dur) and start >= 0 and dur >= 0):
            raise ValueError(f"--outage {start} {dur}: need finite START_S, DURATION_S >= 0")
    return build(RadioChannelConfig, {**values, "outages": [list(o) for o in args.outage]},
                 "safer-hil relay", "")


def run(args: argparse.Namespace) -> int:
    from fsw.drivers.radio import parse_udp
    from fsw.framework.params import ConfigError
    from hil_sim.link.udp_relay import UdpRelay, relay_summary

    try:
        ch = channel_config(args)
        peer = parse_udp(args.b_peer)
        if not all(math.isfinite(x) and x > 0 for x in (args.duration, args.idle_exit)):
            raise ValueError("--duration and --idle-exit must be finite and > 0")
        relay = UdpRelay(ch, args.seed, peer, args.a_port, args.b_port)  # type: ignore[arg-type]
    except (ConfigError, ValueError, OSError) as exc:
        print(f"safer-hil relay: error: {exc}", file=sys.stderr)
        return 2
    try:
        print(json.dumps({side: "udp://{}:{}".format(*relay.address(side)) for side in "ab"}), flush=True)
        res = relay.run(args.duration, args.idle_exit)
    finally:
        relay.close()
    print(json.dumps(relay_summary(res)), flush=True)
    return 0
