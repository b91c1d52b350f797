"""Uplink: bytes from the ground -> whole frames, authenticated commands, ground heartbeats.

Sans-I/O: :meth:`Uplink.feed` takes whatever the transport read (any split, any garbage)
and the current signing time, and returns what it found. It never raises on input: bad
prefixes, CRCs, lengths and unknown messages are counted and reported as ``bad`` entries,
and a parser fault resets the parser (counted). Only COMMAND_LONG addressed to us (or
broadcast) is authenticated (mavlink_signing), and so is PARAM_SET; the read-only requests of
a stock ground station (PARAM_REQUEST_LIST/READ, MISSION_REQUEST_LIST/INT/REQUEST) need no key
and are handed on as :class:`GcsRequest`; other messages are counted and ignored.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from fsw.comm.mavlink_dialect import mavlink, new_codec
from fsw.comm.mavlink_signing import SignatureVerifier, Verdict, signature_fields

#: read-only requests of a ground station (fsw.comm.mavlink_gcs answers them), and PARAM_SET
GCS_REQUESTS = frozenset({"PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET", "MISSION_REQUEST_LIST",
                          "MISSION_REQUEST_INT", "MISSION_REQUEST"})


@dataclass(frozen=True)
class CommandIn:
    """A COMMAND_LONG for us, with the verdict on its signature."""

    command_id: int
    param1: float
    params: tuple[float, ...]  # param2..param7
    src_system: int
    src_component: int
    confirmation: int
    verdict: Verdict
    link_id: int = -1  # signature fields (-1: unsigned): the replay window's stream and time
    timestamp: int = -1

    @property
    def stream(self) -> tuple[int, int, int]:
        return (self.link_id, self.src_system, self.src_component)


@dataclass(frozen=True)
class GcsRequest:
    """A PARAM_* or MISSION_* message for us; ``verdict`` is the signature's (PARAM_SET only,
    else None: read-only requests need no key)."""

    msg: mavlink.MAVLink_message
    src_system: int
    src_component: int
    verdict: Verdict | None = None
    link_id: int = -1
    timestamp: int = -1

    @property
    def kind(self) -> str:
        return str(self.msg.get_type())

    @property
    def stream(self) -> tuple[int, int, int]:
        return (self.link_id, self.src_system, self.src_component)


@dataclass
class UplinkBatch:
    frames: list[bytes] = field(default_factory=list)  # every whole, valid frame (for the tlog)
    commands: list[CommandIn] = field(default_factory=list)
    requests: list[GcsRequest] = field(default_factory=list)
    heartbeats: list[tuple[int, int]] = field(default_factory=list)  # (system, component) of GCSs
    bad: list[str] = field(default_factory=list)


@dataclass
class UplinkCounters:
    bytes: int = 0
    frames: int = 0
    bad_frames: int = 0
    parser_resets: int = 0
    commands: int = 0
    requests: int = 0  # PARAM_* and MISSION_* messages for us
    not_for_us: int = 0
    ignored: int = 0


class Uplink:
    """Turns uplink bytes into authenticated commands."""

    def __init__(self, verifier: SignatureVerifier, system_id: int, component_id: int) -> None:
        self.verifier = verifier
        self.system_id, self.component_id = system_id, component_id
        self._parser = new_codec(system_id, component_id)
        self.counters = UplinkCounters()

    def feed(self, data: bytes, now_ts: int, packet_end: bool = False) -> UplinkBatch:
        """Parse ``data``; ``packet_end``: it was a whole datagram, so a frame left incomplete
        at its end is garbage (counted) and the parser starts clean on the next one."""
        out = UplinkBatch()
        if not data:
            return out
        self.counters.bytes += len(data)
        try:
            msgs = self._parser.parse_buffer(data) or []
        except Exception as exc:  # noqa: BLE001 - pymavlink on hostile bytes: reset, count, go on
            self._parser = new_codec(self.system_id, self.component_id)
            self.counters.parser_resets += 1
            out.bad.append(f"parser reset: {type(exc).__name__}: {exc}")
            return out
        for msg in msgs:
            self._one(msg, now_ts, out)
        if packet_end and self._parser.buf_len() > 0:
            self.counters.bad_frames += 1
            out.bad.append(f"{self._parser.buf_len()} bytes of an incomplete frame at the end of a datagram")
            self._parser = new_codec(self.system_id, self.component_id)
        return out

    def _one(self, msg: mavlink.MAVLink_message, now_ts: int, out: UplinkBatch) -> None:
        kind = msg.get_type()
        if kind == "BAD_DATA":
            self.counters.bad_frames += 1
            out.bad.append(f"{msg.reason}"[:120])
            return
        frame = bytes(msg.get_msgbuf())
        self.counters.frames += 1
        out.frames.append(frame)
        if kind.startswith("UNKNOWN"):  # a valid frame of another dialect: logged, not used
            self.counters.ignored += 1
            return
        hdr = msg.get_header()
        if kind == "HEARTBEAT":
            if msg.type == mavlink.MAV_TYPE_GCS:
                out.heartbeats.append((hdr.srcSystem, hdr.srcComponent))
            return
        if kind != "COMMAND_LONG" and kind not in GCS_REQUESTS:
            self.counters.ignored += 1
            return
        if msg.target_system not in (0, self.system_id) or msg.target_component not in (0, self.component_id):
            self.counters.not_for_us += 1
            return
        link_id, ts = signature_fields(frame) or (-1, -1)
        if kind != "COMMAND_LONG":
            self.counters.requests += 1
            verdict = self.verifier.verify(frame, hdr.srcSystem, hdr.srcComponent, now_ts) \
                if kind == "PARAM_SET" else None
            out.requests.append(GcsRequest(msg, hdr.srcSystem, hdr.srcComponent, verdict, link_id, ts))
            return
        self.counters.commands += 1
        verdict = self.verifier.verify(frame, hdr.srcSystem, hdr.srcComponent, now_ts)
        out.commands.append(CommandIn(
            msg.command, float(msg.param1),
            tuple(float(p) for p in (msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)),
            hdr.srcSystem, hdr.srcComponent, msg.confirmation, verdict, link_id, ts))

    def rejected(self) -> int:
        """Commands refused by authentication so far."""
        return sum(n for v, n in self.verifier.counts.items() if v is not Verdict.OK)
