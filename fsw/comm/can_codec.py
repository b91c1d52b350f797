"""CAN frame codecs compiled once from the DBC (issue 15, "a lean foreground").

cantools re-reads a message's signal list, builds dictionaries and goes through bitstruct
for every frame; at 12 axis commands and 15 status/heartbeat frames per 100 ms that was a
third of the motor tasks' time. :class:`CompiledMessage` reads the signals of one
``cantools`` message once, at start-up, into tuples of (name, start bit, mask, sign bit,
scale, offset), and then packs and unpacks a frame as one little-endian integer with shifts
and masks. The DBC stays the single source of truth: nothing here names a signal.

The results are those of ``cantools`` (``encode(..., strict=False)``, ``decode(...,
decode_choices=False, scaling=True)``): the same raw rounding (``round((v - offset) /
scale)``), the same scaled values (``raw * scale + offset``; raw integers where the scale is 1
and the offset 0). A message this fast path does not cover (big-endian or float signals,
multiplexing) keeps cantools' own codec, so any DBC still works.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

_Sig = tuple[str, int, int, int, float, float, bool]  # name, start, mask, sign bit, scale, offset, identity


def _compilable(msg: Any) -> bool:
    if msg.is_multiplexed():
        return False
    return all(s.byte_order == "little_endian" and not s.is_float and s.length > 0 for s in msg.signals)


class CompiledMessage:
    """Encoder/decoder of one DBC message (a ``cantools`` ``Message``), compiled once."""

    def __init__(self, msg: Any) -> None:
        self.msg = msg
        self.name = str(msg.name)
        self.frame_id = int(msg.frame_id)
        self.length = int(msg.length)
        self.compiled = _compilable(msg)
        sigs: list[_Sig] = []
        for s in msg.signals:
            scale, offset = s.scale, s.offset
            sign = (1 << (s.length - 1)) if s.is_signed else 0
            sigs.append((s.name, int(s.start), (1 << s.length) - 1, sign, scale, offset,
                         scale == 1 and offset == 0))
        self._sigs = tuple(sigs)

    def encode(self, values: Mapping[str, Any]) -> bytes:
        """The payload of ``values`` (physical units; every signal of the message given).
        Raises ``KeyError`` for a missing signal and ``ValueError`` for a value outside its
        field (as cantools/bitstruct do)."""
        if not self.compiled:
            return bytes(self.msg.encode(dict(values), strict=False))
        word = 0
        for name, start, mask, sign, scale, offset, ident in self._sigs:
            v = values[name]
            raw = round(v) if ident else round((v - offset) / scale)
            if sign:
                if not -sign <= raw < sign:
                    raise ValueError(f"{self.name}.{name}: {v} does not fit the signal")
            elif not 0 <= raw <= mask:
                raise ValueError(f"{self.name}.{name}: {v} does not fit the signal")
            word |= (raw & mask) << start
        return word.to_bytes(self.length, "little")

    def decode(self, data: bytes) -> dict[str, Any]:
        """Every signal of a payload of the message's length, scaled."""
        if not self.compiled:
            return dict(self.msg.decode(bytes(data), decode_choices=False, scaling=True))
        if len(data) != self.length:
            raise ValueError(f"{self.name}: {len(data)} bytes, expected {self.length}")
        word = int.from_bytes(data, "little")
        out: dict[str, Any] = {}
        for name, start, mask, sign, scale, offset, ident in self._sigs:
            raw = (word >> start) & mask
            if raw & sign:
                raw -= mask + 1
            out[name] = raw if ident else raw * scale + offset
        return out


def compile_messages(db: Any) -> dict[str, CompiledMessage]:
    """Every message of a loaded ``cantools`` CAN database, compiled, by name."""
    return {m.name: CompiledMessage(m) for m in db.messages}
