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

* reserved bits: every payload bit that no DBC signal covers must be zero.

The layout (where ``Counter`` and ``Checksum`` sit, which bits are reserved) is read from the
DBC message through cantools, so the DBC stays the single source of truth and a new frame
(e.g. an IMU frame) is protected by declaring the two signals. Conventions a DBC must follow:
little-endian (``@1``) signals, ``Counter`` 4 bits, ``Checksum`` 8 or 16 bits on whole bytes.

:class:`SequenceChecker` is the receiver's counter state machine (AUTOSAR E2E profile 1
statuses): a repeated counter or a jump beyond ``max_delta`` is refused; two consecutive
frames re-synchronise after a jump; a gap longer than ``reinit_after_s`` re-initialises.
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
        """The checksum of a payload: CRC over the data id and the bytes around the checksum."""
        k, n = self.checksum_byte, self.checksum_bytes
        return self._crc_fn(self._id_bytes + bytes(data[:k]) + bytes(data[k + n :]))

    def protect(self, data: bytes, counter: int) -> bytes:
        """``data`` with the counter and checksum filled in (their previous contents ignored)."""
        if len(data) != self.length:
            raise ValueError(f"{self.name}: {len(data)} bytes, expected {self.length}")
        word = int.from_bytes(data, "little") & ~(0xF << self.counter_start)
        return self.seal((word | ((counter & 0xF) << self.counter_start)).to_bytes(self.length, "little"))

    def seal(self, data: bytes) -> bytes:
        """``data``, whose counter is already packed, with the checksum filled in (its previous
        contents ignored): :meth:`protect` without the counter step."""
        if len(data) != self.length:
            raise ValueError(f"{self.name}: {len(data)} bytes, expected {self.length}")
        k, n = self.checksum_byte, self.checksum_bytes
        return data[:k] + self.crc(data).to_bytes(n, "little") + data[k + n :]

    def counter(self, data: bytes) -> int:
        return (int.from_bytes(data, "little") >> self.counter_start) & 0xF

    def verify(self, data: bytes) -> tuple[str, str] | None:
        """``None`` if the frame is intact, else ``(reason, detail)``: dlc, checksum or reserved."""
        if len(data) != self.length:
            return "dlc", f"{self.name}: {len(data)} bytes, expected {self.length}"
        k, n = self.checksum_byte, self.checksum_bytes
        got, want = int.from_bytes(data[k : k + n], "little"), self.crc(data)
        if got != want:
            return "checksum", f"{self.name}: checksum 0x{got:0{2 * n}X} != 0x{want:0{2 * n}X}"
        if int.from_bytes(data, "little") & self.reserved_mask:
            return "reserved", f"{self.name}: reserved bits set"
        return None


class Seq(Enum):
    """Counter verdicts (AUTOSAR E2E profile 1 names); ``accepted`` says whether to use the data."""

    INITIAL = "initial"  # first frame, or after a silence of reinit_after_s, or re-synchronised
    OK = "ok"
    OK_SOME_LOST = "ok_some_lost"  # counter advanced by 2..max_delta: frames were lost
    REPEATED = "repeated"  # same counter again: a stuck sender or a replayed/duplicated frame
    WRONG_SEQUENCE = "wrong_sequence"  # a jump beyond max_delta, or backwards: stale or reordered

    @property
    def accepted(self) -> bool:
        return self in (Seq.INITIAL, Seq.OK, Seq.OK_SOME_LOST)


@dataclass
class _Track:
    counter: int
    t_s: float
    candidate: int | None = None


@dataclass
class SequenceChecker:
    """Receiver-side alive-counter check per data id; returns a verdict and the frames lost."""

    max_delta: int = 3
    reinit_after_s: float = 1.0
    _tracks: dict[int, _Track] = field(default_factory=dict)

    def check(self, data_id: int, counter: int, now_s: float) -> tuple[Seq, int]:
        t = self._tracks.get(data_id)
        if t is None or now_s - t.t_s > self.reinit_after_s:
            self._tracks[data_id] = _Track(counter, now_s)
            return Seq.INITIAL, 0
        delta = (counter - t.counter) % COUNTER_MOD
        if delta == 0:
            return Seq.REPEATED, 0
        if delta <= self.max_delta:
            t.counter, t.t_s, t.candidate = counter, now_s, None
            return (Seq.OK, 0) if delta == 1 else (Seq.OK_SOME_LOST, delta - 1)
        if t.candidate is not None and (counter - t.candidate) % COUNTER_MOD == 1:
            t.counter, t.t_s, t.candidate = counter, now_s, None  # two frames agree on a new sequence
            return Seq.INITIAL, 0
        t.candidate = counter
        return Seq.WRONG_SEQUENCE, 0

    def forget(self, data_id: int | None = None) -> None:
        """Drop the state of one data id (or all): the next frame is INITIAL (e.g. a node rebooted)."""
        if data_id is None:
            self._tracks.clear()
        else:
            self._tracks.pop(data_id, None)
