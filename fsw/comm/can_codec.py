"""CAN frame codecs compiled once from the DBC (issue 15, "a lean foreground").

cantools re-reads a message's signal list, builds dictionaries and goes through bitstruct
for every frame; at 12 axis commands and 15 status/heartbeat frames per 100 ms that was a
third of the motor tasks' time. :class:`CompiledMessage` reads the signals of one
``cantools`` message once, at start-up, into tuples of (name, start bit, mask, sign bit,
scale, offset), and generates from them one Python function per direction that packs or
unpacks the whole frame as one little-endian integer with shifts and masks, every signal's
constants inlined (no loop, no per-signal tuple unpacking: one call a frame, ~2x faster than
the table-driven loop). The DBC stays the single source of truth: nothing here names a signal.

The results are those of ``cantools`` (``encode(..., strict=False)``, ``decode(...,
decode_choices=False, scaling=True)``): the same raw rounding (``round((v - offset) /
scale)``), the same scaled values (``raw * scale + offset``; raw integers where the scale is 1
and the offset 0). A message this fast path does not cover (big-endian or float signals,
multiplexing) keeps cantools' own codec, so any DBC still works.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

_Sig = tuple[str, int, int, int, float, float, bool]  # name, start, mask, sign bit, scale, offset, identity
_Encoder = Callable[[Mapping[str, Any]], bytes]
_Decoder = Callable[[bytes], dict[str, Any]]


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
        self._encode: _Encoder | None = None
        self._decode: _Decoder | None = None
        if self.compiled:
            self._encode, self._decode = _generate(self.name, self.length, self._sigs)

    def encode(self, values: Mapping[str, Any]) -> bytes:
        """The payload of ``values`` (physical units; every signal of the message given).
        Raises ``KeyError`` for a missing signal and ``ValueError`` for a value outside its
        field (as cantools/bitstruct do)."""
        if self._encode is None:
            return bytes(self.msg.encode(dict(values), strict=False))
        return self._encode(values)

    def decode(self, data: bytes) -> dict[str, Any]:
        """Every signal of a payload of the message's length, scaled."""
        if self._decode is None:
            return dict(self.msg.decode(bytes(data), decode_choices=False, scaling=True))
        return self._decode(data)

    def packer(self, names: tuple[str, ...]) -> Callable[..., bytes]:
        """An encoder taking the named signals' values as arguments, in that order (no
        dictionary: 12 motor commands a frame are packed so); the other signals are packed as
        raw 0. Same bytes and the same errors as :meth:`encode`."""
        index = {sig[0]: i for i, sig in enumerate(self._sigs)}
        picks = tuple(index[n] for n in names)
        if not self.compiled:
            rest = {s[0]: 0 for s in self._sigs if s[0] not in names}
            return lambda *values: self.encode({**rest, **dict(zip(names, values, strict=True))})
        return _generate_packer(self.name, self.length, tuple(self._sigs[i] for i in picks))

    def values(self, names: tuple[str, ...]) -> Callable[[bytes], tuple[Any, ...]]:
        """A decoder of the named signals only, as a tuple in that order (no dictionary: the
        motor status, 12 a frame, is read so). Same values as :meth:`decode`; ``KeyError`` at
        once for a name the message lacks."""
        index = {sig[0]: i for i, sig in enumerate(self._sigs)}
        picks = tuple(index[n] for n in names)
        if not self.compiled:
            decode = self.decode
            return lambda data: tuple(decode(data)[n] for n in names)
        return _generate_values(self.name, self.length, tuple(self._sigs[i] for i in picks), picks)


def _generate(name: str, length: int, sigs: tuple[_Sig, ...]) -> tuple[_Encoder, _Decoder]:
    """The encoder and decoder of one message, generated from its signal table: for each
    signal ``raw = round(v)`` (scale 1, offset 0) or ``round((v - offset) / scale)``, range
    checked, ``word |= (raw & mask) << start``; and back ``raw = (word >> start) & mask``,
    sign-extended, ``raw * scale + offset`` (the table-driven loop's arithmetic, term for term,
    so the values are the same to the bit). Constants travel in the namespace, not as text."""
    ns: dict[str, Any] = {"_round": round, "_ValueError": ValueError, "_from_bytes": int.from_bytes}
    enc = ["def _encode(values):", "    w = 0"]
    ns["_len_err"] = f"{name}: {{}} bytes, expected {length}"
    dec = ["def _decode(data):", f"    if len(data) != {length}:",
           "        raise _ValueError(_len_err.format(len(data)))",
           "    w = _from_bytes(data, 'little')"]
    out = []
    for i, sig in enumerate(sigs):
        ns[f"_n{i}"] = sig[0]
        enc.append(f"    v = values[_n{i}]")
        enc += _pack_lines(i, sig, ns, name, "v")
        dec += _extract(i, sig)
        out.append(f"_n{i}: r{i}" if sig[6] else f"_n{i}: r{i} * _s{i} + _o{i}")
    enc.append(f"    return w.to_bytes({length}, 'little')")
    dec.append("    return {" + ", ".join(out) + "}")
    exec("\n".join(enc) + "\n\n" + "\n".join(dec), ns)  # noqa: S102 - code generated from the DBC's signal table
    return ns["_encode"], ns["_decode"]


def _extract(i: int, sig: _Sig) -> list[str]:
    """Source lines that leave signal ``i``'s raw value, sign-extended, in ``r{i}``."""
    _, start, mask, sign, _, _, _ = sig
    lines = [f"    r{i} = (w >> {start}) & {mask}"]
    if sign:
        lines += [f"    if r{i} & {sign}:", f"        r{i} -= {mask + 1}"]
    return lines


def _pack_lines(i: int, sig: _Sig, ns: dict[str, Any], name: str, value: str) -> list[str]:
    """Source lines that pack the physical ``value`` of signal ``i`` into ``w`` (range checked)."""
    sig_name, start, mask, sign, scale, offset, ident = sig
    ns[f"_s{i}"], ns[f"_o{i}"] = scale, offset
    ns[f"_e{i}"] = f"{name}.{sig_name}: {{}} does not fit the signal"
    bounds = f"-{sign} <= r < {sign}" if sign else f"0 <= r <= {mask}"
    return ["    r = _round(" + (value if ident else f"({value} - _o{i}) / _s{i}") + ")",
            f"    if not {bounds}:", f"        raise _ValueError(_e{i}.format({value}))",
            f"    w |= (r & {mask}) << {start}"]


def _generate_packer(name: str, length: int, sigs: tuple[_Sig, ...]) -> Callable[..., bytes]:
    """An encoder of ``sigs`` given as positional arguments (the others raw 0)."""
    ns: dict[str, Any] = {"_round": round, "_ValueError": ValueError}
    src = ["def _pack(" + ", ".join(f"v{i}" for i in range(len(sigs))) + "):", "    w = 0"]
    for i, sig in enumerate(sigs):
        src += _pack_lines(i, sig, ns, name, f"v{i}")
    src.append(f"    return w.to_bytes({length}, 'little')")
    exec("\n".join(src), ns)  # noqa: S102 - code generated from the DBC's signal table
    return ns["_pack"]  # type: ignore[no-any-return]


def _generate_values(
    name: str, length: int, sigs: tuple[_Sig, ...], picks: tuple[int, ...]
) -> Callable[[bytes], tuple[Any, ...]]:
    """A decoder of the signals ``sigs`` (at positions ``picks`` of the message) to a tuple,
    with the arithmetic of :func:`_generate`'s decoder."""
    ns: dict[str, Any] = {"_ValueError": ValueError, "_from_bytes": int.from_bytes,
                          "_len_err": f"{name}: {{}} bytes, expected {length}"}
    src = ["def _values(data):", f"    if len(data) != {length}:",
           "        raise _ValueError(_len_err.format(len(data)))", "    w = _from_bytes(data, 'little')"]
    out = []
    for i, sig in zip(picks, sigs, strict=True):
        ns[f"_s{i}"], ns[f"_o{i}"] = sig[4], sig[5]
        src += _extract(i, sig)
        out.append(f"r{i}" if sig[6] else f"r{i} * _s{i} + _o{i}")
    src.append("    return (" + ", ".join(out) + ",)")
    exec("\n".join(src), ns)  # noqa: S102 - code generated from the DBC's signal table
    return ns["_values"]  # type: ignore[no-any-return]


def compile_messages(db: Any) -> dict[str, CompiledMessage]:
    """Every message of a loaded ``cantools`` CAN database, compiled, by name."""
    return {m.name: CompiledMessage(m) for m in db.messages}
