"""Fuzzing of the protected frames (CAN end-to-end protection, serial mast framing), sans I/O.

Used by ``safer-hil bench e2e`` (the 25,000-case figures) and by the tests (smaller counts).
Inputs are generated so they reach the checksum path: valid frames of every kind, then
mutated by 1-3 flipped bits; and random frames. What must never happen is counted:

* CAN (every message of the DBC, laid out by ``fsw.comm.e2e``): a frame with 1-3 flipped
  bits (payload or identifier) that :meth:`fsw.comm.rover_can.RoverCan.decode` accepts; a
  random frame (random identifier, length and bytes) that it accepts;
* serial (``fsw.comm.serial_frames``): a frame that the decoder returns but that was never
  sent (a corrupted frame taken as good), and a valid frame after the corrupted one that is
  not parsed (a corrupted frame swallowing the next), also with the stream ending right after
  it (:func:`serial_mutations`: flips, cuts, deletions, insertions, overwrites, sync pairs).

:func:`undetected_patterns` proves the CAN figure rather than sampling it: a CRC is linear,
so an error pattern escapes the checksum exactly when the XOR of its bits' syndromes is 0,
whatever the frame's content; it counts every such pattern of a given weight over the
identifier and payload bits of one layout (flips of reserved bits are always refused).
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from fsw.comm import serial_frames as sf
from fsw.comm.e2e import E2ELayout, SequenceChecker
from fsw.comm.imu_can import ImuCan
from fsw.comm.rover_can import Bad, RoverCan

ID_BITS = 11


@dataclass
class FuzzCount:
    cases: int = 0
    accepted: int = 0  # must stay 0 (random CAN payloads on valid ids: see residual_rate)
    missed_next: int = 0  # serial only: a valid frame after the corrupted one that was not parsed

    def line(self, what: str) -> str:
        extra = f", next valid frame missed {self.missed_next}" if what.startswith("serial") else ""
        return f"{what}: {self.cases} cases, {self.accepted} accepted{extra}"


def random_valid_can(layout: E2ELayout, rng: np.random.Generator) -> bytes:
    """A valid frame of ``layout``'s message: random bits in every signal, counter, checksum."""
    used = ((1 << (8 * layout.length)) - 1) & ~layout.reserved_mask
    word = int.from_bytes(rng.bytes(layout.length), "little") & used
    return layout.protect(word.to_bytes(layout.length, "little"), int(rng.integers(16)))


def dbc_decoder(codec: RoverCan) -> Callable[[int, bytes], object]:
    """The flight software's decoder for any frame id: the attitude sensor's frame goes to its
    own codec (``fsw.comm.imu_can``, as the motor driver's listener does), the rest to the motor
    codec; so every message of the DBC is fuzzed through the code that receives it."""
    imu = ImuCan(db=codec.db)

    def decode(frame_id: int, data: bytes) -> object:
        return imu.decode(frame_id, data) if frame_id == imu.frame_id else codec.decode(frame_id, data)

    return decode


def can_bit_flips(codec: RoverCan, cases: int, seed: int, max_flips: int = 3) -> FuzzCount:
    """Valid frames of every DBC message in turn, 1..max_flips distinct bits flipped (id or payload)."""
    rng = np.random.default_rng(seed)
    decode = dbc_decoder(codec)
    layouts = sorted(codec.e2e.values(), key=lambda lay: lay.data_id)
    out = FuzzCount()
    for i in range(cases):
        lay = layouts[i % len(layouts)]
        data = random_valid_can(lay, rng)
        if isinstance(decode(lay.data_id, data), Bad):
            raise AssertionError(f"{lay.name}: a valid frame was refused")  # the generator is wrong
        nbits = ID_BITS + 8 * lay.length
        flips = rng.choice(nbits, size=int(rng.integers(1, max_flips + 1)), replace=False)
        fid, word = lay.data_id, int.from_bytes(data, "little")
        for b in flips:
            if b < ID_BITS:
                fid ^= 1 << int(b)
            else:
                word ^= 1 << int(b - ID_BITS)
        out.cases += 1
        out.accepted += not isinstance(decode(fid, word.to_bytes(lay.length, "little")), Bad)
    return out


def can_random_frames(codec: RoverCan, cases: int, seed: int, valid_ids_only: bool = False) -> FuzzCount:
    """Random frames: any 11-bit id, any length 0..8, random bytes (or: DBC ids and lengths only)."""
    rng = np.random.default_rng(seed)
    decode = dbc_decoder(codec)
    layouts = list(codec.e2e.values())
    out = FuzzCount()
    for _ in range(cases):
        if valid_ids_only:
            lay = layouts[int(rng.integers(len(layouts)))]
            fid, n = lay.data_id, lay.length
        else:
            fid, n = int(rng.integers(1 << ID_BITS)), int(rng.integers(9))
        out.cases += 1
        out.accepted += not isinstance(decode(fid, rng.bytes(n)), Bad)
    return out


def _live_receiver(layout: E2ELayout, data: bytes, f0: int) -> tuple[SequenceChecker, float]:
    """A receiver that followed a live sender up to its full counter ``f0``; (checker, time)."""
    seq, t = SequenceChecker(max_delta=3, reinit_after_s=1.0), 0.0
    for f in range(f0 - 3, f0 + 1):
        t += 0.01
        seq.check_frame(layout, layout.protect(data, f), t)
    return seq, t


def can_replays(codec: RoverCan, cases: int, seed: int) -> FuzzCount:
    """Replays of one old frame or a pair of consecutive old frames of every message, aged 1-32
    frames and then at random below ``16 x 2^w - 4``, to a receiver following the live sender
    (``SequenceChecker.check_frame``): ``accepted`` must stay 0."""
    rng = np.random.default_rng(seed)
    layouts = sorted(codec.e2e.values(), key=lambda lay: lay.data_id)
    out = FuzzCount()
    for i in range(cases):
        lay = layouts[i % len(layouts)]
        data = random_valid_can(lay, rng)
        span = 16 * lay.epoch_mod
        age = 1 + (i // len(layouts)) % 32 if i < 32 * len(layouts) else int(rng.integers(1, span - 5))
        f0 = int(rng.integers(age + 2, 10 * span))
        seq, t = _live_receiver(lay, data, f0)
        replay = [f0 - age] if rng.random() < 0.5 else [f0 - age - 1, f0 - age]
        for f in replay:
            out.cases += 1
            out.accepted += seq.check_frame(lay, lay.protect(data, f), t + 0.001)[0].accepted
    return out


def can_receiver_flips(codec: RoverCan, cases: int, seed: int, flips: int = 8) -> dict[int, FuzzCount]:
    """Live frames of every message with ``flips`` flipped payload bits, through the whole
    receiver (length and reserved bits, then counter and checksum under the freshness): the
    frames accepted, by CRC width (information: the residual of a multi-bit error)."""
    rng = np.random.default_rng(seed)
    layouts = sorted(codec.e2e.values(), key=lambda lay: lay.data_id)
    out: dict[int, FuzzCount] = {}
    for i in range(cases):
        lay = layouts[i % len(layouts)]
        data = random_valid_can(lay, rng)
        f0 = int(rng.integers(10, 100_000))
        seq, t = _live_receiver(lay, data, f0)
        bad = bytearray(lay.protect(data, f0 + 1))
        for b in rng.choice(8 * lay.length, size=min(flips, 8 * lay.length), replace=False):
            bad[int(b) // 8] ^= 1 << (int(b) % 8)
        ok = lay.verify(bytes(bad), None) is None and seq.check_frame(lay, bytes(bad), t + 0.01)[0].accepted
        c = out.setdefault(lay.crc_bits, FuzzCount())
        c.cases += 1
        c.accepted += ok
    return out


def residual_rate(layout: E2ELayout) -> float:
    """Chance that a random payload on ``layout``'s id passes checksum and reserved bits."""
    return 2.0 ** -(layout.crc_bits + bin(layout.reserved_mask).count("1"))


def undetected_patterns(layout: E2ELayout, weight: int) -> tuple[int, int]:
    """(undetected, total) error patterns of ``weight`` bits over the id and non-reserved payload bits."""
    base = bytes(layout.length)
    k, n = layout.checksum_byte, layout.checksum_bytes
    ref = layout.crc(base)
    positions: list[int] = []
    syndromes: list[int] = []
    for b in range(ID_BITS):  # an id bit: the same payload checked under another data id
        other = dataclasses.replace(layout, data_id=layout.data_id ^ (1 << b))
        positions.append(b)
        syndromes.append(other.crc(base) ^ ref)
    for b in range(8 * layout.length):
        if (layout.reserved_mask >> b) & 1:
            continue
        flipped = bytearray(base)
        flipped[b // 8] ^= 1 << (b % 8)
        stored = int.from_bytes(flipped[k : k + n], "little")
        positions.append(ID_BITS + b)
        syndromes.append(stored ^ layout.crc(bytes(flipped)) ^ ref)  # change of (stored ^ computed)
    s = np.array(syndromes, dtype=np.int64)
    total = undetected = 0
    for combo in _chunks(len(s), weight):
        x = np.bitwise_xor.reduce(s[combo], axis=1)
        total += len(combo)
        undetected += int(np.count_nonzero(x == 0))
    return undetected, total


def crossing_masks(max_delta: int) -> set[int]:
    """Counter XOR masks that can move a received counter across an epoch boundary of the
    freshness reconstruction while staying in a window of ``max_delta`` (``fsw.comm.e2e``)."""
    out = set()
    for m, r, true_d in itertools.product(range(1, 16), range(16), range(1, max_delta + 1)):
        got = (((r + true_d) % 16) ^ m) - r
        d = got % 16
        if 1 <= d <= max_delta and (r + true_d) // 16 != (r + d) // 16:
            out.add(m)
    return out


def epoch_boundary_escapes(layout: E2ELayout, weight: int, max_delta: int) -> tuple[int, int]:
    """(escaping, total) error patterns of ``weight`` bits that a receiver with a counter window
    of ``max_delta`` would take at an epoch boundary: the pattern moves the counter across the
    boundary (:func:`crossing_masks`) and its checksum change equals the one-bit change of the
    Gray-coded epoch there. Exhaustive, like :func:`undetected_patterns` (a CRC is linear)."""
    base = bytes(layout.length)
    k, n = layout.checksum_byte, layout.checksum_bytes
    ref = layout.crc(base)
    syndromes: list[int] = []
    counter_bit: list[int] = []
    for b in range(ID_BITS):
        other = dataclasses.replace(layout, data_id=layout.data_id ^ (1 << b))
        syndromes.append(other.crc(base) ^ ref)
        counter_bit.append(0)
    for b in range(8 * layout.length):
        if (layout.reserved_mask >> b) & 1:
            continue
        flipped = bytearray(base)
        flipped[b // 8] ^= 1 << (b % 8)
        syndromes.append(int.from_bytes(flipped[k : k + n], "little") ^ layout.crc(bytes(flipped)) ^ ref)
        j = b - layout.counter_start
        counter_bit.append(1 << j if 0 <= j < 4 else 0)
    s, c = np.array(syndromes, dtype=np.int64), np.array(counter_bit, dtype=np.int64)
    crossing = np.array(sorted(crossing_masks(max_delta)), dtype=np.int64)
    total = escaping = 0
    for combo in _chunks(len(s), weight):
        x = np.bitwise_xor.reduce(s[combo], axis=1)
        m = np.bitwise_xor.reduce(c[combo], axis=1)
        one_bit = (x > 0) & ((x & (x - 1)) == 0) & (x < (1 << layout.crc_bits))
        total += len(combo)
        escaping += int(np.count_nonzero(one_bit & np.isin(m, crossing)))
    return escaping, total


def _chunks(n: int, weight: int, size: int = 200_000) -> Iterator[np.ndarray]:
    it = itertools.combinations(range(n), weight)
    while block := list(itertools.islice(it, size)):
        yield np.array(block, dtype=np.int64)


# -- serial framing -------------------------------------------------------------------------
def _random_message(rng: np.random.Generator) -> sf.Message:
    kind = int(rng.integers(7))
    f = [float(x) for x in rng.uniform(-2.0, 2.0, 3)]
    b = [int(x) for x in rng.integers(256, size=3)]
    options: list[sf.Message] = [
        sf.Move(*f), sf.Stop(), sf.Query(), sf.ClearFault(), sf.Ack(b[0], b[1]), sf.Nak(*b), sf.MastState(*f, b[0])
    ]
    return options[kind]


def serial_bit_flips(cases: int, seed: int, max_flips: int = 3) -> FuzzCount:
    """``A | B with 1..max_flips bits flipped | C | filler``: only A, C and the filler may come out."""
    rng = np.random.default_rng(seed)
    out = FuzzCount()
    query = sf.encode_message(sf.Query(), 4)
    filler = query * ((sf.MAX_PAYLOAD + sf.HEADER_LEN + sf.CRC_LEN) // len(query) + 1)  # flushes a bad LEN
    for _ in range(cases):
        a = sf.encode_message(_random_message(rng), 1)
        b = bytearray(sf.encode_message(_random_message(rng), 2))
        c = sf.encode_message(_random_message(rng), 3)
        for bit in rng.choice(8 * len(b), size=int(rng.integers(1, max_flips + 1)), replace=False):
            b[int(bit) // 8] ^= 1 << (int(bit) % 8)
        sent = {a, c, query}
        got = [x for x in sf.FrameDecoder().feed(a + bytes(b) + c + filler) if isinstance(x, sf.Frame)]
        out.cases += 1
        out.accepted += sum(1 for g in got if sf.encode_frame(g.seq, g.type, g.payload) not in sent)
        out.missed_next += not any(g.seq == 3 for g in got)
    return out


def serial_random_frames(cases: int, seed: int) -> FuzzCount:
    """Frame-shaped noise (sync, random length/seq/type/payload/CRC) followed by one valid frame."""
    rng = np.random.default_rng(seed)
    out = FuzzCount()
    good = sf.encode_message(sf.Stop(), 9)
    query = sf.encode_message(sf.Query(), 4)
    filler = query * ((sf.MAX_PAYLOAD + sf.HEADER_LEN + sf.CRC_LEN) // len(query) + 1)
    for _ in range(cases):
        n = int(rng.integers(sf.MAX_PAYLOAD + 1))
        noise = sf.SYNC + bytes([n]) + rng.bytes(2 + n + sf.CRC_LEN)
        got = [x for x in sf.FrameDecoder().feed(noise + good + filler) if isinstance(x, sf.Frame)]
        out.cases += 1
        out.accepted += sum(1 for g in got if sf.encode_frame(g.seq, g.type, g.payload) not in (good, query))
        out.missed_next += not any(g.seq == 9 for g in got)
    return out


MUTATIONS = ("flip", "cut", "delete", "insert", "overwrite", "sync")


def mutate_frame(frame: bytes, rng: np.random.Generator) -> tuple[str, bytes]:
    """One mutation of a frame: 1-8 flipped bits, cut short, a byte deleted, 1-7 random bytes
    inserted, 1-3 bytes overwritten, or a sync pair inserted."""
    b = bytearray(frame)
    kind = MUTATIONS[int(rng.integers(len(MUTATIONS)))]
    if kind == "flip":
        for bit in rng.choice(8 * len(b), size=int(rng.integers(1, 9)), replace=False):
            b[int(bit) // 8] ^= 1 << (int(bit) % 8)
    elif kind == "cut":
        del b[int(rng.integers(1, len(b))):]
    elif kind == "delete":
        del b[int(rng.integers(len(b)))]
    elif kind == "insert":
        i = int(rng.integers(len(b) + 1))
        b[i:i] = rng.bytes(int(rng.integers(1, 8)))
    elif kind == "overwrite":
        for _ in range(int(rng.integers(1, 4))):
            b[int(rng.integers(len(b)))] = int(rng.integers(256))
    else:
        i = int(rng.integers(len(b) + 1))
        b[i:i] = sf.SYNC
    return kind, bytes(b)


def serial_mutations(cases: int, seed: int) -> FuzzCount:
    """``A | mutated B | C`` and nothing after (no filler to flush a wrong LEN): C must come
    out of the decoder; nothing but A, the original B and C may."""
    rng = np.random.default_rng(seed)
    out = FuzzCount()
    for _ in range(cases):
        a, b, c = (sf.encode_message(_random_message(rng), k) for k in (1, 2, 3))
        _kind, mb = mutate_frame(b, rng)
        got = [x for x in sf.FrameDecoder().feed(a + mb + c) if isinstance(x, sf.Frame)]
        out.cases += 1
        out.accepted += sum(1 for g in got if sf.encode_frame(g.seq, g.type, g.payload) not in (a, b, c))
        out.missed_next += not any(sf.encode_frame(g.seq, g.type, g.payload) == c for g in got)
    return out
