"""``safer-hil bench e2e``: how well the CAN end-to-end protection and the serial framing hold.

Prints, for the DBC given (default ``config/rover.dbc``):

* per frame layout, the exhaustive count of 1-, 2-, 3- (and 4-) bit error patterns over the
  identifier and payload bits that escape the checksum (a proof, ``hil_sim.lab.frame_fuzz``);
* CAN fuzz: ``--cases`` valid frames of every message, 1-3 flipped bits, accepted count;
  ``--cases`` random frames (any id, length, bytes), accepted count; and, as information,
  random payloads on the DBC's own ids and lengths against the expected residual rate;
* CAN replays: ``--cases`` old frames or pairs of every message replayed to a receiver that
  follows the live sender (must all be refused); and, as information, live frames with 8
  flipped bits through the whole receiver, accepted per CRC width;
* serial fuzz: ``--cases`` frames with 1-3 flipped bits between two valid frames, and
  ``--cases`` frame-shaped noise bursts: frames accepted that were never sent, valid frames
  after the corruption that were not parsed; and ``--cases`` mutated frames (cut, flipped,
  bytes deleted or inserted) followed by a valid frame that ends the stream.

Exit status 1 if anything that must never happen happened (a corrupted or random frame
accepted, a valid frame lost behind garbage, an undetected 1-3 bit pattern).
"""

from __future__ import annotations

import argparse
import sys
import time

HELP = "E2E/CRC fuzz figures: CAN frames of every DBC message and serial frames (issue 12)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--cases", type=int, default=25000, help="cases per fuzz campaign")
    p.add_argument("--seed", type=int, default=0, help="seed of the generators")
    p.add_argument("--dbc", default=None, help="CAN database (default config/rover.dbc)")
    p.add_argument("--weight4", action="store_true", help="also count 4-bit patterns (slower)")


def run(args: argparse.Namespace) -> int:
    from fsw.comm.e2e import CRC_NAMES
    from fsw.comm.rover_can import DEFAULT_DBC, RoverCan
    from hil_sim.lab import frame_fuzz as ff

    if args.cases < 1:
        print("safer-hil bench e2e: --cases must be >= 1", file=sys.stderr)
        return 2
    try:
        codec = RoverCan(args.dbc or DEFAULT_DBC)
    except ValueError as exc:  # unreadable, not a DBC, or a frame without Counter/Checksum
        print(f"safer-hil bench e2e: {exc}", file=sys.stderr)
        return 2
    bad = 0
    print("CAN layouts (exhaustive: undetected / all error patterns over id + payload bits)")
    groups: dict[tuple[int, int, int, int], list[str]] = {}
    first = {}
    for lay in sorted(codec.e2e.values(), key=lambda x: x.data_id):
        key = (lay.length, lay.checksum_bytes, lay.counter_start, lay.reserved_mask)
        groups.setdefault(key, []).append(lay.name)
        first.setdefault(key, lay)
    for key, names in groups.items():
        lay = first[key]
        weights = (1, 2, 3, 4) if args.weight4 else (1, 2, 3)
        counts = [ff.undetected_patterns(lay, w) for w in weights]
        bad += sum(u for w, (u, _) in zip(weights, counts, strict=True) if w <= 3)
        cells = "  ".join(f"w{w}: {u}/{t}" for w, (u, t) in zip(weights, counts, strict=True))
        print(
            f"  {len(names):2d} x {lay.length} B  {CRC_NAMES[lay.crc_bits]:20s} reserved "
            f"{bin(lay.reserved_mask).count('1'):2d} bits  {cells}   e.g. {names[0]}"
        )
    t0 = time.perf_counter()
    flips = ff.can_bit_flips(codec, args.cases, args.seed)
    rnd = ff.can_random_frames(codec, args.cases, args.seed + 1)
    on_ids = ff.can_random_frames(codec, args.cases, args.seed + 2, valid_ids_only=True)
    expected = args.cases * sum(ff.residual_rate(lay) for lay in codec.e2e.values()) / len(codec.e2e)
    bad += flips.accepted + rnd.accepted
    print(flips.line("CAN, 1-3 flipped bits in valid frames of every message"))
    print(rnd.line("CAN, random frames (any 11-bit id, length 0-8, bytes)"))
    print(
        f"CAN, random payloads on the DBC's ids and lengths (information): {on_ids.accepted} of "
        f"{on_ids.cases} pass checksum and reserved bits (expected {expected:.1f}; the receiver's "
        f"alive-counter check refuses most of those)"
    )
    replays = ff.can_replays(codec, args.cases, args.seed + 6)
    bad += replays.accepted
    print(replays.line("CAN, replayed old frames and pairs of every message (ages 1-32, then any below 16 x 2^w - 4)"))
    for bits, c in sorted(ff.can_receiver_flips(codec, args.cases, args.seed + 7).items()):
        print(f"CAN, 8 flipped bits in live frames through the receiver, {bits}-bit CRC (information): "
              f"{c.accepted} of {c.cases} accepted")
    sflips = ff.serial_bit_flips(args.cases, args.seed + 3)
    snoise = ff.serial_random_frames(args.cases, args.seed + 4)
    smut = ff.serial_mutations(args.cases, args.seed + 5)
    bad += sflips.accepted + sflips.missed_next + snoise.accepted + snoise.missed_next
    bad += smut.accepted + smut.missed_next
    print(sflips.line("serial, 1-3 flipped bits in a frame between two valid ones"))
    print(snoise.line("serial, frame-shaped noise then a valid frame"))
    print(smut.line("serial, a cut/flipped/shifted frame then a valid one, nothing after"))
    print(f"{time.perf_counter() - t0:.1f} s; {'FAIL' if bad else 'ok'}: {bad} must-never events")
    return 1 if bad else 0
