"""The radio task: sends the map to the Cliff-bot over the map link (docs/algorithm.md §6).

Thin (docs/architecture.md, tasks). It keeps the latest map snapshot (``map.updated``); a
``SEND_MAP`` command or a :class:`RadioSendRequest` on ``radio.send`` (the mission's last
step, which carries its own snapshot, so a resumed mission needs no ``map.updated``; a
repeat of the request for the map in hand changes nothing) encodes that snapshot in a slack
job (quadtree + codec, ``fsw.core.codec.mapcodec``, the wheel diameter from ``[rover]``) and
hands the container to the sans-I/O :class:`~fsw.comm.link_sender.LinkSender`. Every
activation it feeds the radio's datagrams to the link and sends what the link's pacing
allows, never more than its byte budget (``[link] rate_bps`` over two activation periods),
then reports the link's events and counters. The Cliff-bot's fix requests
(``fsw.comm.team.fix_packets``) on the same radio go to the fixer task
(``radio.fix_request``), and its answers (``radio.fix_out``) are sent ahead of map bytes.
The radio is the ``radio_port`` resource, or ``[link] transport`` opened here.

With ``[map_sync] enabled`` (a team mission) it also runs the RECON-bot's end of the two-way map
sync (``fsw.comm.team.sync_end``, docs/sync.md "In flight") on the same radio: its map at the
end of each imaging step (when the mission asks for the next view, ``nbv.request``) and the map
it is asked to send are each one sync round, published in a background slack job; the Cliff-bot's
tiles are held as the other layer (for the team's hash and summary; not fused into its own
map); new tiles go out nearest the Cliff-bot's corridor first (from where its last fix request
said it stood through its targets, ``[cliffbot_site]``); sync packets go after fixes and map
bytes, within the same budget. The end's state is in the mission's checkpoints.
"""

from __future__ import annotations

from collections.abc import Generator
from typing import ClassVar

import numpy as np

from fsw.comm.link_packets import DATA_OVERHEAD, PacketError
from fsw.comm.link_sender import LinkSender, SenderState
from fsw.comm.team import fix_packets
from fsw.comm.team.sync_end import FlightSync
from fsw.core.codec.mapcodec import EncodedMap, encode_map
from fsw.core.geometry import MapGrid
from fsw.core.map.elevation_map import ElevationMap
from fsw.drivers.radio import RadioPort, open_radio
from fsw.framework.commands import Arg, CommandDef
from fsw.framework.jobs import JobHandle
from fsw.framework.telemetry import Channel, EventDef, Severity
from fsw.tasks.base import FlightTask
from fsw.tasks.messages import (
    MAP_UPDATED,
    NBV_REQUEST,
    RADIO_FIX_OUT,
    RADIO_FIX_REQUEST,
    RADIO_SEND,
    RADIO_STATUS,
    RadioStatus,
)
from fsw.tasks.mission_state import restore_into
from fsw.tasks.state_json import JsonObject


class RadioTask(FlightTask):
    KIND: ClassVar[str] = "radio"
    RATE_HZ: ClassVar[tuple[float, float]] = (5.0, 50.0)  # its timeouts and moves assume ~10 Hz
    DOC: ClassVar[str] = "Map link to the Cliff-bot: encode the map, send it within a byte budget."
    CHANNELS = (
        Channel("state", doc="link sender state: idle, offering, sending, done, rejected, failed"),
        Channel("acked_pct", "%", doc="segments of the current map acknowledged"),
        Channel("map_bytes", "B", doc="size of the map being sent"),
        Channel("tx_bytes", "B", doc="radio bytes sent since start"),
        Channel("frame_bytes", "B", doc="bytes sent in the last activation (<= budget)"),
        Channel("retransmits", "count"),
        Channel("bad_packets", "count", hi=0, doc="datagrams refused (CRC, format)"),
        Channel("radio_faults", "count", hi=0, doc="radio driver fault word"),
        Channel("srtt_ms", "ms", doc="smoothed round-trip time of the link"),
        Channel("maps_delivered", "count"),
        Channel("sync_rounds", "count", doc="map sync rounds published (one per imaging step)"),
        Channel("sync_tiles_out", "count", doc="map sync tiles sent (resends included)"),
        Channel("sync_peer_tiles", "count", doc="the Cliff-bot's tiles received"),
        Channel("sync_bytes_out", "B", doc="map sync bytes sent"),
    )
    EVENTS = (
        EventDef("ENCODED", Severity.ACTIVITY_HI, "map {map_id}: {cells} cells -> {bytes} B, "
                 "{leaves} leaves, max error {max_error_m:.3f} m"),
        EventDef("ENCODE_FAILED", Severity.WARNING_HI, "map {map_id} not encoded: {error}"),
        EventDef("NO_MAP", Severity.WARNING_LO, "no map to send yet"),
        EventDef("BUSY", Severity.WARNING_LO, "map {map_id} refused: map {current} still in transfer"),
        EventDef("OFFERED", Severity.ACTIVITY_LO, "map {map_id}: offered {size} B in {segments} segments"),
        EventDef("ACCEPTED", Severity.ACTIVITY_LO, "map {map_id}: the Cliff-bot accepted"),
        EventDef("REJECTED", Severity.WARNING_HI, "map {map_id}: the Cliff-bot rejected it ({reason})"),
        EventDef("DELIVERED", Severity.ACTIVITY_HI, "map {map_id}: {size} B delivered and verified in {seconds} s"),
        EventDef("REOFFERED", Severity.WARNING_LO, "map {map_id}: offered again as session {session} "
                 "({reason})", throttle=5),
        EventDef("LINK_LOST", Severity.WARNING_HI, "map {map_id}: no answer for {silent_s} s, transfer failed"),
        EventDef("HASH_MISMATCH_RESEND", Severity.WARNING_LO,
                 "map {map_id}: hash mismatch, resend {attempt} (inferred from a STATUS: {inferred})"),
        EventDef("HASH_MISMATCH_GIVE_UP", Severity.WARNING_HI, "map {map_id}: hash mismatch, gave up"),
        EventDef("RADIO_ERROR", Severity.WARNING_LO, "radio: {text}", throttle=5),
        EventDef("SYNC", Severity.ACTIVITY_LO, "map sync: {what} {detail}", throttle=5),
        EventDef("SYNC_STATE_REFUSED", Severity.WARNING_HI, "map sync state not restored ({error}): "
                 "the end starts afresh"),
        EventDef("CLOSE_GIVEN_UP", Severity.WARNING_LO, "map {map_id}: delivered; the Cliff-bot "
                 "still repeats FIN after {fin_acks} FIN_ACKs, close given up"),
    )
    COMMANDS = (
        CommandDef("SEND_MAP", (Arg("map_id", int, lo=0, hi=2**32 - 1),),
                   doc="encode the latest map and send it to the Cliff-bot"),
        CommandDef("ABORT", doc="stop the current transfer"),
    )

    def setup(self) -> None:
        cfg = self.ctx.cfg
        self.link_cfg = cfg.link
        port = self.ctx.res.radio_port
        if port is None:
            port = open_radio(cfg.link.transport, cfg.link.peer)
        self.port: RadioPort = port
        self.sender = LinkSender(cfg.link, session=1)
        self.session = 1
        self.snapshot: ElevationMap | None = None
        self.maps_delivered = 0
        self.encoding: int | None = None
        period = self.ctx.frame_period_s * max(1, self._divisor())
        self.budget_bytes = max(int(cfg.link.rate_bps / 8 * period * 2),
                                cfg.link.segment_bytes + DATA_OVERHEAD)
        self.map_box = self.subscribe(MAP_UPDATED, depth=1)
        self.send_box = self.subscribe(RADIO_SEND, depth=4)
        self.fix_box = self.subscribe(RADIO_FIX_OUT, depth=4)
        self.step_box = self.subscribe(NBV_REQUEST, depth=2)
        self._published_state: SenderState | None = None
        self._offered: ElevationMap | None = None
        self._resume_round = False
        self.sync: FlightSync | None = None
        self.sync_ignored = 0  # sync packets heard without a sync end
        if cfg.map_sync.enabled:
            self.sync = FlightSync(cfg.map_sync, 0, 1, MapGrid.from_config(cfg.map),
                                   cfg.codec.wheel_m(cfg.rover.wheel_diameter_m), cfg.codec, cfg.link.rate_bps,
                                   cfg.link.pacing_catchup_s)
            site = cfg.cliffbot_site
            self._cliffbot_xy = np.asarray(site.start_xy, float)
            self._targets = np.asarray(site.targets_xy, float).reshape(-1, 2)
            self.sync.set_corridor(np.vstack([self._cliffbot_xy, self._targets]))
            self.budget_bytes = max(self.budget_bytes, cfg.map_sync.mtu_bytes)
            restore_into(self)  # a resumed mission: the end's state at the checkpoint

    # -- checkpoint (fsw.tasks.mission_state) ----------------------------------------------------
    def checkpoint_state(self) -> JsonObject:
        """The map sync end's state (nothing without one)."""
        return {} if self.sync is None else {"sync": self.sync.state()}

    def restore_state(self, st: JsonObject) -> None:
        if self.sync is None or "sync" not in st:
            return
        try:
            self.sync.restore(st["sync"])
        except ValueError as exc:
            self.event("SYNC_STATE_REFUSED", error=str(exc))
        # the checkpoint was taken as the step ended, before that step's round: the restored
        # map (the mission publishes it again) is that round
        self._resume_round = True

    def _divisor(self) -> int:
        cfg = self.ctx.cfg.executive
        task = next((t for t in cfg.tasks if t.name == self.name), None)
        group = next((g for g in cfg.groups if task is not None and g.name == task.group), None)
        return group.divisor if group is not None else 1

    # -- commands ------------------------------------------------------------------------------
    def cmd_SEND_MAP(self, map_id: int) -> None:
        self._request(map_id)

    def cmd_ABORT(self) -> None:
        self.session = max(self.session, self.sender.session)
        self.sender = LinkSender(self.link_cfg, session=self._next_session())

    # -- the work --------------------------------------------------------------------------------
    def run(self, frame: int) -> None:
        now = self.ctx.clock.now()
        upd = self.map_box.latest()
        if upd is not None:
            self.snapshot = upd.snapshot
        for req in self.send_box.drain():
            self._request(req.map_id, req.snapshot)
            self._offer(req.snapshot if req.snapshot is not None else self.snapshot)
        step = bool(self.step_box.drain())  # an imaging step ended: its map is a sync round
        if (step or self._resume_round) and self.snapshot is not None:
            self._resume_round = False
            self._offer(self.snapshot)
        d = self.port.recv(0.0, now)
        while d is not None:
            if fix_packets.is_fix_packet(d):
                self._fix_packet(d)
            elif FlightSync.is_sync_packet(d):
                if self.sync is not None:
                    self.sync.receive(d, now)
                else:
                    self.sync_ignored += 1
            else:
                self.sender.receive(d, now)
            d = self.port.recv(0.0, now)
        sent = 0
        for pkt in self.fix_box.drain():  # fixes go ahead of map bytes (they count in the budget)
            sent += self._send(pkt, now)
        for pkt in self.sender.poll(now, max_bytes=max(self.budget_bytes - sent, 0)):
            sent += self._send(pkt, now)
        if self.sync is not None:  # the map sync last, in what is left
            self._sync_round(now)
            for pkt in self.sync.poll(now, self.budget_bytes - sent):
                if self.port.send(pkt, now):
                    sent += len(pkt)
            for ev in self.sync.end.events.pop_all():
                self.event("SYNC", what=ev.name, detail=" ".join(f"{k}={v}" for k, v in ev.args.items()))
        for ev in self.sender.events.pop_all():
            if ev.name == "DELIVERED":
                self.maps_delivered += 1
            self.event(ev.name, **ev.args)
        for name, args in self.port.drain_events():
            self.event("RADIO_ERROR", text=f"{name} {args.get('error', '')}")
        self._telemetry(sent)

    def _send(self, pkt: bytes, now: float) -> int:
        """One fix or map-link packet; its air time is charged to the map sync's pacing."""
        if not self.port.send(pkt, now):
            return 0
        if self.sync is not None:
            self.sync.charge(len(pkt), now)
        return len(pkt)

    def _offer(self, snap: ElevationMap | None) -> None:
        """A map for the next sync round (once per map)."""
        if self.sync is None or snap is None or snap is self._offered:
            return
        self._offered = snap
        z = np.asarray(snap.z, np.float32)
        mapped = getattr(snap, "mapped", None)  # (a bare height map: its finite cells)
        self.sync.offer(z if mapped is None else np.where(mapped, z, np.nan))

    def _sync_round(self, now: float) -> None:
        assert self.sync is not None
        job = self.sync.round_job(now)
        if job is not None:
            self.submit_job(job, "sync_round", on_done=lambda h: self._round_done(h), background=True)

    def _round_done(self, h: JobHandle) -> None:
        assert self.sync is not None
        self.sync.round_done()
        if h.error is not None:
            self.event("SYNC", what="ROUND_FAILED", detail=f"{type(h.error).__name__}: {h.error}")

    def _fix_packet(self, d: bytes) -> None:
        """A relative-localization packet (the Cliff-bot's FIX_REQUEST) for the fixer task."""
        try:
            p = fix_packets.decode(d)
        except PacketError as exc:
            self.sender.stats.bad_packets += 1
            self.event("RADIO_ERROR", text=f"fix packet refused: {exc}")
            return
        if isinstance(p, fix_packets.FixRequest):
            self.publish(RADIO_FIX_REQUEST, p)
            if self.sync is not None and np.isfinite(p.x) and np.isfinite(p.y):  # where the Cliff-bot stands
                self._cliffbot_xy = np.array([p.x, p.y])
                self.sync.set_corridor(np.vstack([self._cliffbot_xy, self._targets]))

    def _telemetry(self, sent: int) -> None:
        s = self.sender
        acked, total = s.progress
        self.tlm("state", s.state.value)
        if s.state is not self._published_state:
            self._published_state = s.state
            self.publish(RADIO_STATUS, RadioStatus(s.state, self.ctx.clock.now(), s.map_id))
        self.tlm("acked_pct", 100.0 * acked / total if total else 0.0)
        self.tlm("map_bytes", s.map_bytes)
        self.tlm("tx_bytes", s.stats.bytes_out)
        self.tlm("frame_bytes", sent)
        self.tlm("retransmits", s.stats.retransmits)
        self.tlm("bad_packets", s.stats.bad_packets)
        self.tlm("radio_faults", self.port.faults)
        self.tlm("srtt_ms", (s.srtt_s or 0.0) * 1e3)
        self.tlm("maps_delivered", self.maps_delivered)
        if self.sync is not None:
            st = self.sync.stats()
            self.tlm("sync_rounds", st.rounds)
            self.tlm("sync_tiles_out", st.tiles_out)
            self.tlm("sync_peer_tiles", st.tiles_in)
            self.tlm("sync_bytes_out", st.bytes_out)

    def _next_session(self) -> int:
        self.session = self.session % 0xFFFF + 1
        return self.session

    def _request(self, map_id: int, snapshot: ElevationMap | None = None) -> None:
        busy = self.sender.state in (SenderState.OFFERING, SenderState.SENDING)
        current = self.encoding if self.encoding is not None else self.sender.map_id
        if busy or self.encoding is not None:
            if current != map_id:  # the same map asked again is a repeat, not a conflict
                self.event("BUSY", map_id=map_id, current=current)
            return
        snapshot = snapshot if snapshot is not None else self.snapshot
        if snapshot is None:
            self.event("NO_MAP")
            return
        z = np.asarray(snapshot.z, np.float32).copy()
        cell_m = float(snapshot.grid.cell)
        self.encoding = map_id

        def job() -> Generator[None, None, EncodedMap]:
            yield
            cfg = self.ctx.cfg  # reduced for the receiver's wheel ([codec] receiver_wheel_diameter_m)
            return encode_map(z, cell_m=cell_m, wheel_diameter_m=cfg.codec.wheel_m(cfg.rover.wheel_diameter_m),
                              cfg=cfg.codec)

        self.submit_job(job(), f"encode_map_{map_id}", on_done=lambda h: self._encoded(map_id, h))

    def _encoded(self, map_id: int, handle: JobHandle) -> None:
        self.encoding = None
        if handle.error is not None:
            self.event("ENCODE_FAILED", map_id=map_id, error=str(handle.error))
            return
        enc: EncodedMap = handle.result
        self.event("ENCODED", map_id=map_id, cells=int(np.prod(enc.tree.shape)), bytes=len(enc.data),
                   leaves=enc.tree.n_leaves, max_error_m=enc.max_error_m)
        if len(enc.data) > self.link_cfg.max_map_bytes:
            self.event("ENCODE_FAILED", map_id=map_id, error="container larger than max_map_bytes")
            return
        self.session = max(self.session, self.sender.session)  # re-offers moved it on
        self.sender = LinkSender(self.link_cfg, session=self._next_session())
        self.sender.start(map_id, enc.data, self.ctx.clock.now())
