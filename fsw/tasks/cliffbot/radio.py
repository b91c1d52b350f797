"""The Cliff-bot's radio task: the map link's receiving end, and fixes from the RECON-bot.

Thin: every activation it reads the radio (``res.radio_port``, or ``[link] transport``
opened here). Fix packets (``fsw.comm.team.fix_packets``: FIX, NO_FIX) go to the mission
(:data:`~fsw.tasks.cliffbot.messages.CB_FIX`); a damaged one is counted and reported, never
used. Everything else feeds the sans-I/O :class:`~fsw.comm.link_receiver.LinkReceiver`; each
map it delivers verified is decoded (``fsw.core.codec.mapcodec``), put in the team's height
frame (``[cliffbot_site] map_datum_m``) and handed to the mission. It sends the mission's fix
requests first, then the link's own packets (acknowledgements).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from fsw.comm.link_packets import PacketError
from fsw.comm.link_receiver import LinkReceiver
from fsw.comm.team import fix_packets
from fsw.core.codec.mapcodec import MapCodecError, decode_map
from fsw.core.geometry import MapGrid
from fsw.drivers.radio import RadioPort, open_radio
from fsw.framework.telemetry import Channel, EventDef, Severity
from fsw.tasks.base import FlightTask
from fsw.tasks.cliffbot.messages import CB_FIX, CB_FIX_REQUEST, CB_MAP, FixAnswer, ReceivedMap

MAX_DATAGRAMS = 64  # datagrams taken per activation


class CliffbotRadioTask(FlightTask):
    KIND: ClassVar[str] = "cliffbot_radio"
    RATE_HZ: ClassVar[tuple[float, float]] = (5.0, 50.0)  # the link's timers assume ~10 Hz
    DOC: ClassVar[str] = "Cliff-bot radio: receives the map and the RECON-bot's fixes, sends fix requests."
    CHANNELS = (
        Channel("maps", "count", doc="maps received, verified and decoded"),
        Channel("fixes", "count", doc="FIX and NO_FIX packets received"),
        Channel("requests", "count", doc="fix requests sent"),
        Channel("tx_bytes", "B", doc="radio bytes sent since start"),
        Channel("rx_bytes", "B", doc="radio bytes received since start"),
        Channel("bad_packets", "count", hi=0, doc="fix packets refused (CRC, format)"),
    )
    EVENTS = (
        EventDef("MAP_RECEIVED", Severity.ACTIVITY_HI, "map {map_id}: {size} B, {known} known cells"),
        EventDef("MAP_REFUSED", Severity.WARNING_HI, "map {map_id} not used: {error}"),
        EventDef("BAD_PACKET", Severity.WARNING_LO, "radio packet refused: {error}", throttle=5),
        EventDef("RADIO_ERROR", Severity.WARNING_LO, "radio: {text}", throttle=5),
    )

    def setup(self) -> None:
        cfg = self.ctx.cfg
        port = self.ctx.res.radio_port
        if port is None:
            port = open_radio(cfg.link.transport, cfg.link.peer)
        self.port: RadioPort = port
        self.rx = LinkReceiver(cfg.link)
        self.grid = MapGrid.from_config(cfg.map)
        self.requests = self.subscribe(CB_FIX_REQUEST, depth=4)
        self.counts = {"maps": 0, "fixes": 0, "requests": 0, "tx_bytes": 0, "rx_bytes": 0, "bad_packets": 0}

    def run(self, frame: int) -> None:
        now = self.ctx.clock.now()
        for req in self.requests.drain():  # ahead of the link's own packets
            self._send(fix_packets.encode(req), now, "requests")
        for _ in range(MAX_DATAGRAMS):
            d = self.port.recv(0.0, now)
            if d is None:
                break
            self.counts["rx_bytes"] += len(d)
            if fix_packets.is_fix_packet(d):
                self._fix(d)
            else:
                self.rx.receive(d, now)
        for pkt in self.rx.poll(now):
            self._send(pkt, now)
        got = self.rx.take_map()
        while got is not None:
            self._map(*got)
            got = self.rx.take_map()
        for name, args in self.port.drain_events():
            self.event("RADIO_ERROR", text=f"{name} {args.get('error', '')}")
        self.tlm_record(self.counts)

    def _send(self, pkt: bytes, now: float, count: str = "") -> None:
        if self.port.send(pkt, now):
            self.counts["tx_bytes"] += len(pkt)
            if count:
                self.counts[count] += 1

    def _fix(self, d: bytes) -> None:
        try:
            p = fix_packets.decode(d)
        except PacketError as exc:
            self.counts["bad_packets"] += 1
            self.event("BAD_PACKET", error=str(exc))
            return
        if isinstance(p, fix_packets.FixRequest):  # ours, echoed: not for us
            return
        self.counts["fixes"] += 1
        reason = ""
        if isinstance(p, fix_packets.NoFix):
            names = fix_packets.NO_FIX_REASONS
            reason = names[p.reason] if p.reason < len(names) else f"reason {p.reason}"
        self.publish(CB_FIX, FixAnswer(p, reason))

    def _map(self, map_id: int, data: bytes) -> None:
        try:
            decoded = decode_map(data)
            z = decoded.z
        except MapCodecError as exc:
            self.event("MAP_REFUSED", map_id=map_id, error=str(exc))
            return
        if z.shape != self.grid.shape:
            self.event("MAP_REFUSED", map_id=map_id, error=f"shape {z.shape}, the map grid is {self.grid.shape}")
            return
        zf = np.asarray(z, np.float64) + self.ctx.cfg.cliffbot_site.map_datum_m
        self.counts["maps"] += 1
        self.event("MAP_RECEIVED", map_id=map_id, size=len(data), known=int(np.isfinite(zf).sum()))
        self.publish(CB_MAP, ReceivedMap(map_id, zf, float(decoded.header.error_bound_m)))
