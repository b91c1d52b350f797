"""The Cliff-bot's radio task: the map link's receiving end, and fixes from the RECON-bot.

Thin: every activation it reads the radio (``res.radio_port``, or ``[link] transport``
opened here). Fix packets (``fsw.comm.team.fix_packets``: FIX, NO_FIX) go to the mission
(:data:`~fsw.tasks.cliffbot.messages.CB_FIX`); a damaged one is counted and reported, never
used. Everything else feeds the sans-I/O :class:`~fsw.comm.link_receiver.LinkReceiver`; each
map it delivers verified is decoded (``fsw.core.codec.mapcodec``), put in the team's height
frame (``[cliffbot_site] map_datum_m``) and handed to the mission. It sends the mission's fix
requests first, then the link's own packets (acknowledgements).

With ``[map_sync] enabled`` it runs the Cliff-bot's end of the two-way map sync
(``fsw.comm.team.sync_end``, docs/sync.md "In flight") on the same radio, after the other
packets and within the same budget: its own map after each of its looks (the sensing task's
``own``) is one sync round (a background slack job), new tiles nearest its corridor first (where it
stands, then its targets). Once the link's map is in, the RECON-bot's tiles that arrive newer
than it and say something new (a cell the map does not know, or one moved by more than both
maps' error bounds) win over the link's map on every cell they know: the map handed on again
(``cliffbot.map``, event ``SYNC_MAP``) is the one the sensing task fills with its own views.
The end's state is written to ``[checkpoint] directory`` (``cliffbot_sync.json``) after each
round and as the RECON-bot's tiles arrive; a restarted Cliff-bot continues from it.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from fsw.comm.link_packets import PacketError
from fsw.comm.link_receiver import LinkReceiver
from fsw.comm.team import fix_packets
from fsw.comm.team.sync_end import FlightSync, overlay_newer
from fsw.core.codec.mapcodec import CodecConfig, MapCodecError, decode_map
from fsw.core.geometry import MapGrid
from fsw.drivers.radio import RadioPort, open_radio
from fsw.framework.jobs import JobHandle
from fsw.framework.telemetry import Channel, EventDef, Severity
from fsw.tasks.base import FlightTask
from fsw.tasks.cliffbot import checkpoint
from fsw.tasks.cliffbot.messages import (
    CB_FIX,
    CB_FIX_REQUEST,
    CB_MAP,
    CB_NAV,
    CB_SENSED_MAP,
    FixAnswer,
    NavEstimate,
    ReceivedMap,
    SensedMap,
)

MAX_DATAGRAMS = 64  # datagrams taken per activation
# Its sync tiles: the RECON-bot's [codec] bound (a quarter wheel, of its own wheel), the rest the
# codec's defaults (the relief disc: about the RECON-bot's footprint, the tiles' receiver)
TILE_CODEC = CodecConfig(error_bound_wheels=0.25)
SYNC_SAVE_S = 10.0  # the sync state is written at most this often as the RECON-bot's tiles arrive


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
        Channel("sync_rounds", "count", doc="map sync rounds published (one per look)"),
        Channel("sync_peer_tiles", "count", doc="the RECON-bot's tiles received"),
        Channel("sync_bytes_out", "B", doc="map sync bytes sent"),
    )
    EVENTS = (
        EventDef("MAP_RECEIVED", Severity.ACTIVITY_HI, "map {map_id}: {size} B, {known} known cells"),
        EventDef("MAP_REFUSED", Severity.WARNING_HI, "map {map_id} not used: {error}"),
        EventDef("BAD_PACKET", Severity.WARNING_LO, "radio packet refused: {error}", throttle=5),
        EventDef("RADIO_ERROR", Severity.WARNING_LO, "radio: {text}", throttle=5),
        EventDef("SYNC", Severity.ACTIVITY_LO, "map sync: {what} {detail}", throttle=5),
        EventDef("SYNC_MAP", Severity.ACTIVITY_HI, "map {map_id}: {tiles} newer tiles of the RECON-bot's in it"),
        EventDef("SYNC_STATE", Severity.WARNING_LO, "map sync state: {text}"),
        # the map link's receiver (fsw.comm.link_receiver; docs/link.md)
        EventDef("OFFER_ACCEPTED", Severity.ACTIVITY_LO, "map {map_id}: offer of {size} B accepted"),
        EventDef("OFFER_REJECTED", Severity.WARNING_HI, "map {map_id}: offer of {size} B refused (over max_map_bytes)"),
        EventDef("RESUMED", Severity.ACTIVITY_LO, "map {map_id}: transfer resumed with {held} segments held"),
        EventDef("MAP_VERIFIED", Severity.ACTIVITY_LO, "map {map_id}: {size} B verified (SHA-256) in {seconds} s"),
        EventDef("HASH_MISMATCH", Severity.WARNING_LO, "map {map_id}: SHA-256 mismatch, its segments discarded"),
        EventDef("SESSION_TIMEOUT", Severity.WARNING_LO, "map transfer given up: {held} of {of} segments held"),
        EventDef("SESSION_DROPPED", Severity.WARNING_HI,
                 "map {map_id}: session dropped ({reason}; {held} segments held): its offer was not the sender's"),
        EventDef("CLOSED", Severity.ACTIVITY_LO, "map {map_id}: session closed ({how})"),
        EventDef("UNKNOWN_SESSION", Severity.WARNING_LO, "map link: session {session} unknown, NO_SESSION sent",
                 throttle=5),
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
        self.sent = 0  # bytes sent in this activation
        period = self.ctx.frame_period_s
        self.budget = max(int(cfg.link.rate_bps / 8 * period * 2), cfg.map_sync.mtu_bytes)
        self.counts = {"maps": 0, "fixes": 0, "requests": 0, "tx_bytes": 0, "rx_bytes": 0, "bad_packets": 0}
        self.sync: FlightSync | None = None
        self.sync_ignored = 0  # sync packets heard without a sync end
        self.link_map: ReceivedMap | None = None  # the link's last map, and the map handed on
        self.plan_map: ReceivedMap | None = None
        self._seen: dict[int, int] = {}  # the RECON-bot's tile versions weighed against the link's map
        self._sense_seq = 0
        self._saved_s = float("-inf")
        if cfg.map_sync.enabled:
            self._sync_setup()

    # -- the map sync -------------------------------------------------------------------------
    def _sync_setup(self) -> None:
        cfg = self.ctx.cfg
        self.sync = FlightSync(cfg.map_sync, 1, 0, self.grid, cfg.climber.wheel_d_m, TILE_CODEC, cfg.link.rate_bps,
                               cfg.link.pacing_catchup_s)
        site = cfg.cliffbot_site
        self._targets = np.asarray(site.targets_xy, float).reshape(-1, 2)
        self.sync.set_corridor(np.vstack([np.asarray(site.start_xy, float), self._targets]))
        self.nav = self.subscribe(CB_NAV, depth=1)
        self.sensed = self.subscribe(CB_SENSED_MAP, depth=2)
        self.store = checkpoint.CheckpointFile(cfg.checkpoint.directory)
        try:
            st = self.store.load_sync()
            if st is not None:
                self.sync.restore(st)
                self.event("SYNC_STATE", text=f"restored (boot {self.sync.boot})")
        except ValueError as exc:  # CheckpointError too
            self.event("SYNC_STATE", text=f"not restored ({exc}): the end starts afresh")

    def _sync(self, now: float, budget: int) -> int:
        """Rounds, the RECON-bot's newer tiles into the map, the sync's packets; bytes sent."""
        sync = self.sync
        assert sync is not None
        est: NavEstimate | None = self.nav.latest()
        if est is not None:
            sync.set_corridor(np.vstack([np.asarray(est.s[:2], float), self._targets]))
        for sm in self.sensed.drain():
            self._own_round(sm)
        job = sync.round_job(now)
        if job is not None:
            self.submit_job(job, "sync_round", on_done=lambda h: self._round_done(h), background=True)
        sent = 0
        for pkt in sync.poll(now, budget):
            if self.port.send(pkt, now):
                sent += len(pkt)
        for ev in sync.end.events.pop_all():
            self.event("SYNC", what=ev.name, detail=" ".join(f"{k}={v}" for k, v in ev.args.items()))
        if sync.peer_tiles_since():
            self._newer_tiles()
            if now - self._saved_s >= SYNC_SAVE_S:
                self._save(now)
        return sent

    def _own_round(self, sm: SensedMap) -> None:
        """A look's views are all in: its own map is the next sync round."""
        if sm.own is None or sm.sense_seq <= self._sense_seq or self.sync is None:
            return
        self._sense_seq = sm.sense_seq
        self.sync.offer(sm.own)

    def _round_done(self, h: JobHandle) -> None:
        assert self.sync is not None
        self.sync.round_done()
        if h.error is not None:
            self.event("SYNC", what="ROUND_FAILED", detail=f"{type(h.error).__name__}: {h.error}")
        self._save(self.ctx.clock.now())

    def _save(self, now: float) -> None:
        assert self.sync is not None
        self._saved_s = now
        err = self.store.save_sync(self.sync.state())
        if err:
            self.event("SYNC_STATE", text=f"not written: {err}")

    def _newer_tiles(self) -> None:
        """The RECON-bot's tiles newer than the link's map into the map handed on (module docstring)."""
        assert self.sync is not None
        if self.link_map is None or self.plan_map is None:
            return
        tol = self.link_map.error_bound_m + self.sync.bound_m
        z, n = overlay_newer(self.plan_map.z, self.sync, self._seen, self.ctx.cfg.cliffbot_site.map_datum_m, tol)
        if n:
            self.plan_map = ReceivedMap(self.link_map.map_id, z, max(self.link_map.error_bound_m, self.sync.bound_m))
            self.event("SYNC_MAP", map_id=self.link_map.map_id, tiles=n)
            self.publish(CB_MAP, self.plan_map)

    def run(self, frame: int) -> None:
        now = self.ctx.clock.now()
        self.sent = 0
        for req in self.requests.drain():  # ahead of the link's own packets
            self._send(fix_packets.encode(req), now, "requests")
        for _ in range(MAX_DATAGRAMS):
            d = self.port.recv(0.0, now)
            if d is None:
                break
            self.counts["rx_bytes"] += len(d)
            if fix_packets.is_fix_packet(d):
                self._fix(d)
            elif FlightSync.is_sync_packet(d):
                if self.sync is not None:
                    self.sync.receive(d, now)
                else:
                    self.sync_ignored += 1
            else:
                self.rx.receive(d, now)
        for pkt in self.rx.poll(now):
            self._send(pkt, now)
        for ev in self.rx.events.pop_all():
            self.event(ev.name, **ev.args)
        got = self.rx.take_map()
        while got is not None:
            self._map(*got)
            got = self.rx.take_map()
        if self.sync is not None:
            self.counts["tx_bytes"] += self._sync(now, max(self.budget - self.sent, 0))
            st = self.sync.stats()
            self.tlm_record({"sync_rounds": st.rounds, "sync_peer_tiles": st.tiles_in, "sync_bytes_out": st.bytes_out})
        for name, args in self.port.drain_events():
            self.event("RADIO_ERROR", text=f"{name} {args.get('error', '')}")
        self.tlm_record(self.counts)

    def _send(self, pkt: bytes, now: float, count: str = "") -> None:
        if self.port.send(pkt, now):
            self.counts["tx_bytes"] += len(pkt)
            self.sent += len(pkt)
            if self.sync is not None:
                self.sync.charge(len(pkt), now)
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
        got = ReceivedMap(map_id, zf, float(decoded.header.error_bound_m))
        self.link_map = self.plan_map = got
        if self.sync is not None:  # the RECON-bot's tiles held now are no newer than this map
            self._seen = {t: v for t, (v, _z) in self.sync.held().items()}
        self.publish(CB_MAP, got)
