"""End-to-end protection of CAN frames (AUTOSAR E2E style), laid out by the DBC, sans I/O.

The bench's CAN runs over UDP datagrams with no bus CRC underneath, and even a real bus lets
a faulty node or gateway deliver stale or corrupted data; so every frame of the rover DBC
carries its own protection, which the receiving application checks:

* ``Counter``: a 4-bit alive counter, +1 (mod 16) per frame of that data id;
* ``Checksum``: a CRC over the **data id** (the 11-bit frame id as two bytes, little-endian)
  followed by every data byte except the checksum's own byte(s), in order, stored
  little-endian in the ``Checksum`` signal. The CRC is chosen by the signal's width:

  - 8 bits: CRC-8/AUTOSAR (poly 0x2F, init 0xFF, xorout 0xFF, not reflected; AUTOSAR
    "CRC8H2F"), Hamming distance 4 up to 119 data bits (Koopman): every 1-, 2- and 3-bit
    error of a 9-byte protected input is detected (CRC-8/SAE-J1850, used before, misses
    362 of the 3-bit patterns at that length);
  - 16 bits: CRC-16/DNP (poly 0x3D65, reflected, init 0, xorout 0xFFFF): no undetected error
    pattern of up to 4 bits at these lengths (counted exhaustively by ``safer-hil bench e2e``);
    used for the frames that make the rover move (COMMAND, ESTOP).

* reserved bits: every payload bit that no DBC signal covers must be zero;
* freshness (AUTOSAR SecOC style, implicit): the sender's alive counter is a full integer
  ``F`` (+1 per frame of the data id, from 0 at the sender's start); the frame carries its low
  4 bits in ``Counter`` and the checksum is ``CRC ^ gray(F >> 4 mod 2^w)`` (the *epoch*, Gray
  coded, modulo the CRC's width ``w``). The receiver reconstructs ``F`` from its track of the
  data id, so an old frame, replayed when its 4-bit counter fits the window, fails the
  checksum: refused for every age below 16 x 2^8 - max_delta frames of an 8-bit-CRC frame
  (16 x 2^16 - max_delta of a 16-bit one: at 10 Hz, 6.8 min and 29 h), by construction, not
  by chance (the replay's epoch differs, the CRC of its bytes does not); an older replay
  passes with probability about max_delta/16 x 2^-w. The Gray code makes neighbouring epochs
  differ in one checksum bit, so a 1-3 bit error that moves the counter across an epoch
  boundary is still caught for a window of ``max_delta <= 4`` (counted exhaustively:
  ``hil_sim.lab.frame_fuzz.epoch_boundary_escapes``).

The layout (where ``Counter`` and ``Checksum`` sit, which bits are reserved) is read from the
DBC message through cantools, so the DBC stays the single source of truth and a new frame
(e.g. an IMU frame) is protected by declaring the two signals. Conventions a DBC must follow:
little-endian (``@1``) signals, ``Counter`` 4 bits, ``Checksum`` 8 or 16 bits on whole bytes.

:class:`SequenceChecker` is the receiver's counter state machine (AUTOSAR E2E profile 1
statuses): a repeated counter or a jump beyond ``max_delta`` is refused, and so is a frame whose
checksum fails under the reconstructed freshness (``STALE``: a replay, or corruption). A jump
never re-synchronises while the track is fresh (a replayed pair of consecutive old frames is
refused like one). The receiver's first frame of a data id starts its track (AUTOSAR
``INITIAL``: the freshness is learnt from it; the receiver may start long after the sender). A
track without an accepted frame for ``reinit_after_s`` starts over more carefully: a frame of
epoch 0 (a sender in its first 16 frames, the checksum fully checked) is taken at once, any
other is held until the next frame of the same sequence confirms it (``LEARNING``). So a
sender that restarts is refused for ``reinit_after_s`` and then learnt again, and a replay of
recorded frames can only be taken by a receiver that has heard nothing valid for
``reinit_after_s`` (or nothing at all yet).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

import fastcrc

COUNTER, CHECKSUM = "Counter", "Checksum"
COUNTER_MOD = 16
CRCS: dict[int, Callable[[bytes], int]] = {8: fastcrc.crc8.autosar, 16: fastcrc.crc16.dnp}
CRC_NAMES = {8: "CRC-8/AUTOSAR (0x2F)", 16: "CRC-16/DNP (0x3D65)"}


def _gray(v: int) -> int:
    return v ^ (v >> 1)


def _ungray(g: int) -> int:
    v = g
    while g := g >> 1:
        v ^= g
    return v


def _signal_bits(sig: Any) -> int:
    if sig.byte_order != "little_endian":
        raise ValueError(f"signal {sig.name}: E2E layout needs little-endian (@1) signals")
    return ((1 << sig.length) - 1) << sig.start


@dataclass(frozen=True)
class E2ELayout:
    """Where the protection sits in one DBC message; built by :meth:`from_message`."""

    name: str
    data_id: int
    length: int
    counter_start: int
    checksum_byte: int
    checksum_bytes: int
    reserved_mask: int
    _id_bytes: bytes = field(init=False, repr=False, compare=False)
    _crc_fn: Callable[[bytes], int] = field(init=False, repr=False, compare=False)

    @classmethod
    def from_message(cls, msg: Any) -> E2ELayout:
        """Read a cantools message; raises ``ValueError`` if it does not follow the convention."""
        sigs = {s.name: s for s in msg.signals}
        if COUNTER not in sigs or CHECKSUM not in sigs:
            raise ValueError(f"{msg.name}: every frame needs the E2E signals {COUNTER} and {CHECKSUM}")
        ctr, crc = sigs[COUNTER], sigs[CHECKSUM]
        if ctr.length != 4:
            raise ValueError(f"{msg.name}: {COUNTER} must be 4 bits, not {ctr.length}")
        if crc.length not in CRCS or crc.start % 8:
            raise ValueError(f"{msg.name}: {CHECKSUM} must be 8 or 16 bits starting on a byte boundary")
        used = 0
        for s in msg.signals:
            used |= _signal_bits(s)
        full = (1 << (8 * msg.length)) - 1
        if used & ~full:
            raise ValueError(f"{msg.name}: a signal lies beyond the {msg.length}-byte payload")
        return cls(
            msg.name, int(msg.frame_id), int(msg.length), ctr.start, crc.start // 8, crc.length // 8, full & ~used
        )

    def __post_init__(self) -> None:  # the data id's bytes and the CRC function, looked up once
        object.__setattr__(self, "_id_bytes", self.data_id.to_bytes(2, "little"))
        object.__setattr__(self, "_crc_fn", CRCS[8 * self.checksum_bytes])

    @property
    def crc_bits(self) -> int:
        return 8 * self.checksum_bytes

    def crc(self, data: bytes) -> int:
        """The CRC of a payload: over the data id and the bytes around the checksum (the
        checksum field holds this XOR the epoch, :meth:`seal`)."""
        k, n = self.checksum_byte, self.checksum_bytes
        return self._crc_fn(self._id_bytes + bytes(data[:k]) + bytes(data[k + n :]))

    @property
    def epoch_mod(self) -> int:
        """Epochs are told apart modulo this (2^CRC width)."""
        return 1 << self.crc_bits

    def protect(self, data: bytes, counter: int) -> bytes:
        """``data`` with the counter and checksum filled in (their previous contents ignored);
        ``counter`` is the sender's full alive counter (its low 4 bits go in the frame)."""
        if len(data) != self.length:
            raise ValueError(f"{self.name}: {len(data)} bytes, expected {self.length}")
        word = int.from_bytes(data, "little") & ~(0xF << self.counter_start)
        return self.seal((word | ((counter & 0xF) << self.counter_start)).to_bytes(self.length, "little"),
                         counter >> 4)

    def seal(self, data: bytes, epoch: int = 0) -> bytes:
        """``data``, whose counter is already packed, with the checksum filled in (its previous
        contents ignored): :meth:`protect` without the counter step; ``epoch`` = full counter >> 4."""
        if len(data) != self.length:
            raise ValueError(f"{self.name}: {len(data)} bytes, expected {self.length}")
        k, n = self.checksum_byte, self.checksum_bytes
        value = self.crc(data) ^ _gray(epoch % self.epoch_mod)
        return data[:k] + value.to_bytes(n, "little") + data[k + n :]

    def counter(self, data: bytes) -> int:
        return (int.from_bytes(data, "little") >> self.counter_start) & 0xF

    def implied_epoch(self, data: bytes) -> int:
        """The epoch (modulo :attr:`epoch_mod`) under which this frame's checksum holds."""
        k, n = self.checksum_byte, self.checksum_bytes
        return _ungray(int.from_bytes(data[k : k + n], "little") ^ self.crc(data))

    def verify(self, data: bytes, epoch: int | None = 0) -> tuple[str, str] | None:
        """``None`` if the frame is intact, else ``(reason, detail)``: dlc, checksum or reserved.
        ``epoch``: the freshness the checksum must hold under (``None``: leave the checksum to
        :meth:`SequenceChecker.check_frame`, which knows the epoch)."""
        if len(data) != self.length:
            return "dlc", f"{self.name}: {len(data)} bytes, expected {self.length}"
        k, n = self.checksum_byte, self.checksum_bytes
        got, want = int.from_bytes(data[k : k + n], "little"), self.crc(data) ^ _gray((epoch or 0) % self.epoch_mod)
        if epoch is not None and got != want:
            return "checksum", f"{self.name}: checksum 0x{got:0{2 * n}X} != 0x{want:0{2 * n}X}"
        if int.from_bytes(data, "little") & self.reserved_mask:
            return "reserved", f"{self.name}: reserved bits set"
        return None


class Seq(Enum):
    """Counter verdicts (AUTOSAR E2E profile 1 names); ``accepted`` says whether to use the data."""

    INITIAL = "initial"  # first frame (epoch 0), or the confirmed second one of a new track
    OK = "ok"
    OK_SOME_LOST = "ok_some_lost"  # counter advanced by 2..max_delta: frames were lost
    REPEATED = "repeated"  # same counter again: a stuck sender or a replayed/duplicated frame
    WRONG_SEQUENCE = "wrong_sequence"  # a jump beyond max_delta, or backwards: stale or reordered
    STALE = "stale"  # counter in the window but the checksum fails under its freshness: a replay
    LEARNING = "learning"  # a new track's first frame of a later epoch: held until confirmed

    @property
    def accepted(self) -> bool:
        return self in (Seq.INITIAL, Seq.OK, Seq.OK_SOME_LOST)


@dataclass
class _Track:
    fresh: int  # the last accepted full counter (modulo 16 x epoch_mod when learnt from a frame)
    t_s: float


@dataclass
class SequenceChecker:
    """Receiver-side freshness check per data id; returns a verdict and the frames lost."""

    max_delta: int = 3
    reinit_after_s: float = 1.0
    _tracks: dict[int, _Track] = field(default_factory=dict)
    _pending: dict[int, tuple[int, float]] = field(default_factory=dict)  # data id -> (fresh, t) learning
    _seen: set[int] = field(default_factory=set)  # data ids that had a track

    def check_frame(self, layout: E2ELayout, data: bytes, now_s: float) -> tuple[Seq, int]:
        """The verdict on one received frame (length and reserved bits already checked): its
        counter against the track and its checksum under the reconstructed freshness."""
        did, counter = layout.data_id, layout.counter(data)
        t = self._tracks.get(did)
        if t is None or now_s - t.t_s > self.reinit_after_s:
            return self._learn(layout, data, now_s)
        delta = (counter - t.fresh) % COUNTER_MOD
        if delta == 0:
            return Seq.REPEATED, 0
        if delta > self.max_delta:
            return Seq.WRONG_SEQUENCE, 0
        fresh = t.fresh + delta
        if layout.implied_epoch(data) != (fresh >> 4) % layout.epoch_mod:
            return Seq.STALE, 0
        t.fresh, t.t_s = fresh, now_s
        return (Seq.OK, 0) if delta == 1 else (Seq.OK_SOME_LOST, delta - 1)

    def _learn(self, layout: E2ELayout, data: bytes, now_s: float) -> tuple[Seq, int]:
        did, counter = layout.data_id, layout.counter(data)
        fresh = 16 * layout.implied_epoch(data) + counter
        if fresh < 16 or did not in self._seen:  # epoch 0 (checksum fully checked), or a first track
            self._seen.add(did)
            self._tracks[did] = _Track(fresh, now_s)
            self._pending.pop(did, None)
            return Seq.INITIAL, 0
        prev = self._pending.get(did)
        span = 16 * layout.epoch_mod
        if prev is not None and now_s - prev[1] <= self.reinit_after_s \
                and 1 <= (fresh - prev[0]) % span <= self.max_delta:
            self._tracks[did] = _Track(fresh, now_s)
            del self._pending[did]
            return Seq.INITIAL, 0
        self._pending[did] = (fresh, now_s)
        return Seq.LEARNING, 0

    def forget(self, data_id: int | None = None) -> None:
        """Drop the state of one data id (or all): the next frame starts a new track."""
        if data_id is None:
            self._tracks.clear()
            self._pending.clear()
            self._seen.clear()
        else:
            self._tracks.pop(data_id, None)
            self._pending.pop(data_id, None)
            self._seen.discard(data_id)
