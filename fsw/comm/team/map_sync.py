"""Two-way map sync: one map kept in step between two agents over the radio (docs/sync.md).

:class:`MapSync` is one agent's end, sans-I/O like the map link (``receive(datagram, now_s)``,
``poll(now_s) -> list[bytes]``, ``next_deadline_s()``): the protocol, over the agent's
replica of the shared map (:class:`fsw.comm.team.map_replica.MapReplica`: two layers of
versioned map-codec tiles, the agent's own and its copy of the peer's, and their hashes).

* :meth:`publish` (once per sync round, with the agent's current map) compares each tile
  with the map tile its last version was made from and publishes a new version only where a
  cell became known or unknown or moved by more than the error bound (one wheel diameter by
  default).
* New versions go out as TILE packets (compact tile bodies of my tile profile, which the peer
  holds before any goes: it rides on my DIGESTs asking for holdings until the peer says it
  holds it), highest ``priority(ty, tx)`` first (the receiver's task: e.g. its corridor),
  as many in one TILE as fit ``mtu_bytes`` (they share its header and its serial), paced to
  ``rate_bps``. The peer acknowledges them in its DIGESTs by the serials it took in (the echo
  and a window of the 32 before it; I keep which tile versions each serial carried).
  A tile is sent again only when a DIGEST proves it lost: the peer had received a packet sent
  ``reorder_slack_s`` after it, and does not hold it (as TCP RACK). After the last tile a DIGEST
  asking for an answer probes the tail.
* The sender keeps what it believes the peer holds (per-tile versions and digests). A DIGEST
  carries the hash of its sender's copy of the receiver's layer; a peer whose copy of my layer
  hashes equal to mine holds all of it. When the peer restarted (its boot id changed), when I
  restarted (from my checkpoint or empty), or when the hashes keep disagreeing with nothing
  in flight, I ask for the peer's HOLDINGS of my layer (per tile: version, digest) and send
  exactly what they lack; tiles of my layer the peer holds in newer versions than I do (I
  published them after my checkpoint) I ask back (``wants``) and adopt. A full resend happens
  only when the peer started with no replica (its DIGESTs say so): ``stats.full_resends``.
* No packet from the peer for ``stall_s``: tiles pause, a probing DIGEST every ``probe_max_s``.

Its parameters and counters are :mod:`fsw.comm.team.sync_config`'s; its checkpoint (the whole
sync state, both layers, versions, beliefs) and the restore after a restart are
:mod:`fsw.comm.team.sync_checkpoint`'s. Bad packets are counted and dropped
(``stats.bad_packets``), never raised.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Generator

import numpy as np
from numpy.typing import NDArray

from fsw.comm.link import Pacer
from fsw.comm.link_packets import PacketError
from fsw.comm.team import sync_packets as sp
from fsw.comm.team.map_replica import F32, MapReplica, TileRec
from fsw.comm.team.sync_config import SyncConfig, SyncStats
from fsw.core.codec.mapcodec import CodecConfig, TileProfile
from fsw.core.codec.tileformat import PROFILE_BYTES
from fsw.framework.events import EventSink

Priority = Callable[[int, int], float]


class MapSync:
    """One agent's end of the two-way sync (see the module docstring)."""

    def __init__(self, cfg: SyncConfig, agent: int, peer: int, shape: tuple[int, int], cell_m: float,
                 wheel_diameter_m: float, *, frame: int = 0, boot: int = 0, codec: CodecConfig | None = None,
                 priority: Priority | None = None, on_adopt: Callable[[int, F32], None] | None = None,
                 origin: tuple[float, float] = (0.0, 0.0)) -> None:
        if agent == peer or not (0 <= agent < 256 and 0 <= peer < 256):
            raise ValueError(f"agent {agent} and peer {peer} must be distinct ids 0..255")
        self.cfg, self.agent, self.peer, self.frame = cfg, agent, peer, frame & 0xFF
        self.rep = MapReplica(agent, peer, shape, cfg.tile_cells, cell_m, wheel_diameter_m, codec, frame=frame,
                              origin=origin)
        if self.rep.n_tiles > 0xFFFF:
            raise ValueError(f"a {self.rep.shape} map has more than 65535 tiles of {cfg.tile_cells} cells")
        if -(-self.rep.n_tiles // ((cfg.mtu_bytes - sp.HOLDINGS_BASE) // sp.ENTRY_BYTES)) > 255:
            raise ValueError(f"a {self.rep.shape} map needs more than 255 HOLDINGS pages at mtu_bytes={cfg.mtu_bytes}")
        self.priority = priority
        self.on_adopt = on_adopt
        self.boot = boot & 0xFFFF
        self.pacer = Pacer(cfg.rate_bps, cfg.pacing_catchup_s)
        self.events = EventSink()
        self.stats = SyncStats(minimal_bytes=PROFILE_BYTES)  # my profile, once per session
        self.peer_profile: TileProfile | None = None  # the peer's tile profile, once it sent it
        self.attach_profile = True  # my DIGESTs asking for holdings carry my profile
        self._peer_profile_stale = False  # its holdings named another profile of mine
        self._refused_profiles: set[int] = set()
        self._bad_event_s, self._bad_since = float("-inf"), 0
        self._peer_synced = False  # the peer's last hash of my layer equalled mine, nothing published since
        self.belief: dict[int, tuple[int, int]] = {}  # what the peer holds of my layer
        self.peer_boot: int | None = None
        self.want_holdings = True  # every start asks: the peer may hold what I lost
        self.fresh = True  # started with no replica (False once restored from a checkpoint)
        self.wants: set[int] = set()  # own tiles the peer holds newer: asked back
        self._serial = (self.boot * 4099) & 0xFFFF
        self._sent_at: OrderedDict[int, float] = OrderedDict()  # serial -> send time
        self._inflight: dict[int, tuple[int, float]] = {}  # tile -> (version, sent at)
        self._lost: set[int] = set()
        self._last_rx_s: float | None = None
        self._started_s: float | None = None
        self._peer_serial: int | None = None  # the peer's last packet accepted (the echo)
        self._rx_serials: OrderedDict[int, None] = OrderedDict()  # the peer's packets accepted, recent
        # serial -> the (tile, version) of mine it carried
        self._sent_tiles: OrderedDict[int, tuple[tuple[int, int], ...]] = OrderedDict()
        self._recent: OrderedDict[tuple[int, int, bytes], None] = OrderedDict()
        self._digest_due: float | None = None
        self._answer = False
        self._last_digest_s = float("-inf")
        self._last_tile_s: float | None = None
        self._probe_gap = cfg.probe_s
        self._next_probe_s: float | None = None
        self._holdings_out: list[bytes] = []
        self._last_holdings_s = float("-inf")
        self._holdings_in: dict[int, tuple[tuple[int, int, int], ...]] = {}  # page -> entries
        self._set_id = 0
        self._returns: set[int] = set()
        self._returned_at: dict[int, float] = {}
        self._mismatches = 0
        self._now = 0.0
        self._ack_first_s: float | None = None  # first and last tile not yet acknowledged
        self._ack_last_s = 0.0
        self._last_tx_s = float("-inf")

    # ---------------------------------------------------------------- the replica
    @property
    def own(self) -> dict[int, TileRec]:
        return self.rep.own

    @property
    def held(self) -> dict[int, TileRec]:
        return self.rep.held

    @property
    def counter(self) -> int:
        return self.rep.counter

    @property
    def shape(self) -> tuple[int, int]:
        return self.rep.shape

    def tile_slice(self, t: int) -> tuple[slice[int, int, None], slice[int, int, None]]:
        return self.rep.tile_slice(t)

    def layer_hash(self, owner: int) -> bytes:
        return self.rep.layer_hash(owner)

    def replica_hash(self) -> str:
        return self.rep.replica_hash()

    def replica_map(self, owner: int) -> F32:
        return self.rep.replica_map(owner)

    def fused_map(self) -> F32:
        return self.rep.fused_map()

    def _needed(self, t: int) -> bool:
        rec = self.rep.own[t]
        b = self.belief.get(t)
        return b is None or b[0] < rec.version or (b[0] == rec.version and b[1] != rec.digest)

    # ---------------------------------------------------------------- publishing
    def publish(self, z: NDArray[np.float32] | NDArray[np.float64], now_s: float) -> int:
        """One sync round: new versions of the tiles of ``z`` (the agent's map, NaN unknown)
        that changed beyond the error bound; returns how many."""
        steps = self.publish_steps(z, now_s)
        while True:
            try:
                next(steps)
            except StopIteration as stop:
                return int(stop.value)

    def publish_steps(self, z: NDArray[np.float32] | NDArray[np.float64],
                      now_s: float) -> Generator[None, None, int]:
        """:meth:`publish` as a slack job (``fsw.framework.jobs``): it yields after each tile it
        encodes, and returns how many it published. The protocol may run between the steps:
        each tile is whole when it is published."""
        a = np.asarray(z, np.float32)
        if a.shape != self.rep.shape:
            raise ValueError(f"map of shape {a.shape} is not the sync's {self.rep.shape}")
        bad = np.isinf(a)
        if bad.any():
            self.stats.nonfinite_cells += int(bad.sum())
            a = np.where(bad, np.float32(np.nan), a)
        self.stats.rounds += 1
        n = 0
        for t in range(self.rep.n_tiles):
            sub = a[self.rep.tile_slice(t)]
            if self.rep.changed(t, sub):
                n += int(self._publish_tile(t, sub, now_s))
                yield
        return n

    def _publish_tile(self, t: int, sub: F32, now_s: float) -> bool:
        blob = self.rep.encode(sub)
        if sp.TILE_BASE + sp.TileEntry(t, 0xFFFFFFFF, blob).size > self.cfg.mtu_bytes:
            self.stats.oversize_tiles += 1
            self.events.emit(now_s, "TILE_TOO_LARGE", tile=t, bytes=len(blob))
            return False
        self.rep.new_version(t, blob, sub)
        self._peer_synced = False
        self.wants.discard(t)
        self._lost.discard(t)
        self.stats.tiles_published += 1
        self.stats.minimal_bytes += len(blob) + sp.MINIMAL_TILE_OVERHEAD
        return True

    @property
    def profile(self) -> TileProfile:
        """My tile profile: the frame, grid and codec settings of my layer's tiles."""
        return self.rep.profile

    # ---------------------------------------------------------------- receiving
    def receive(self, datagram: bytes, now_s: float) -> None:
        """One datagram from the radio; anything invalid is counted and dropped."""
        try:
            p = sp.decode(datagram)
        except PacketError as exc:
            self._bad(now_s, str(exc))
            return
        self._now = now_s
        if p.agent != self.peer or p.frame != self.frame:
            self.stats.foreign_packets += 1
            return
        key = (p.serial, len(datagram), bytes(datagram[-4:]))  # the CRC: a fingerprint
        if key in self._recent:
            self.stats.dup_packets += 1
            return
        self._recent[key] = None
        if len(self._recent) > 512:
            self._recent.popitem(last=False)
        self.stats.packets_in += 1
        self.stats.bytes_in += len(datagram)
        if self._last_rx_s is not None and now_s - self._last_rx_s > self.cfg.stall_s:
            self.events.emit(now_s, "LINK_BACK", silent_s=round(now_s - self._last_rx_s, 3))
        self._last_rx_s = now_s
        if isinstance(p, sp.Tile):
            self._on_tiles(p, now_s)
        elif isinstance(p, sp.Digest):
            self.stats.digest_bytes_in += len(datagram)
            if p.profile is not None:
                self._on_profile(p.profile, now_s)
            self._on_digest(p, now_s)
        else:
            self.stats.holdings_bytes_in += len(datagram)
            self._on_holdings(p, now_s)

    def _bad(self, now_s: float, reason: str) -> None:
        """A datagram dropped: counted, and an event (at most one a second, with the count)."""
        self.stats.bad_packets += 1
        self._bad_since += 1
        if now_s - self._bad_event_s >= 1.0:
            self.events.emit(now_s, "BAD_PACKET", dropped=self._bad_since, last=reason)
            self._bad_event_s, self._bad_since = now_s, 0

    def _on_profile(self, prof: TileProfile, now_s: float) -> None:
        if not prof.same_grid(self.rep.profile):  # another frame or grid: never merged
            self.stats.profile_mismatches += 1
            if prof.pid not in self._refused_profiles:
                self._refused_profiles.add(prof.pid)
                self.events.emit(now_s, "FRAME_MISMATCH", profile=f"{prof.pid:08x}", frame=prof.frame,
                                 grid=f"{prof.ny}x{prof.nx}@{prof.cell_m:.4g}m/{prof.tile_cells}")
            return
        if self.peer_profile is None or self.peer_profile.pid != prof.pid:
            self.events.emit(now_s, "PEER_PROFILE", profile=f"{prof.pid:08x}")
        self.peer_profile = prof

    def _tile_profile(self, p: sp.Tile) -> TileProfile | None:
        """The profile a TILE names, if it is the one its owner's tiles have here."""
        prof = self.rep.profile if p.owner == self.agent else self.peer_profile
        if prof is not None and prof.pid == p.profile:
            return prof
        if p.profile in self._refused_profiles:
            self.stats.profile_mismatches += 1
        else:
            self.stats.unknown_profile_tiles += 1
        return None

    def _on_tiles(self, p: sp.Tile, now_s: float) -> None:
        """A TILE: every tile decoded first, so the packet is taken in (and acknowledged) whole
        or not at all."""
        if p.owner not in (self.agent, self.peer):
            self.stats.foreign_packets += 1
            return
        prof = self._tile_profile(p)
        if prof is None:  # not decodable here: not acknowledged, so the sender sends it again
            return
        recs = []
        for e in p.tiles:
            z = self.rep.decode_tile(e.tile, e.blob, prof)
            if z is None:
                self._bad(now_s, f"TILE {e.tile}: its body is not a tile of the map")
                return
            recs.append((e, TileRec(e.version, e.digest, e.blob, z)))
        for e, rec in recs:
            if p.owner == self.agent:
                self._on_own_tile(e.tile, rec)
            else:
                self._on_peer_tile(e, rec)
        if p.owner == self.agent:
            return
        self._accepted(p.serial)
        if self._ack_first_s is None:
            self._ack_first_s = now_s
        self._ack_last_s = now_s

    def _on_own_tile(self, t: int, rec: TileRec) -> None:
        """One of my tiles, given back after my restart: adopted if I asked for it."""
        mine = self.rep.own.get(t)
        if t in self.wants and (mine is None or rec.version > mine.version):
            self.rep.own[t] = rec
            self.rep.source.pop(t, None)
            self.rep.counter = max(self.rep.counter, rec.version)
            self.belief[t] = (rec.version, rec.digest)
            self.rep.touch(self.agent)
            self.stats.adopted += 1
            if self.on_adopt is not None:
                self.on_adopt(t, rec.z)
        else:
            self.stats.stale_tiles += 1
        self.wants.discard(t)

    def _on_peer_tile(self, e: sp.TileEntry, rec: TileRec) -> None:
        held = self.rep.held.get(e.tile)
        if held is None or rec.version > held.version or (rec.version == held.version and rec.digest != held.digest):
            self.rep.held[e.tile] = rec
            self.rep.touch(self.peer)
            self.stats.tiles_in += 1
        else:
            self.stats.stale_tiles += 1
            self.stats.stale_bytes_in += e.size

    def _accepted(self, serial: int) -> None:
        """A packet of the peer taken in: my next DIGEST echoes it (and acknowledges its tiles)."""
        self._peer_serial = serial
        self._rx_serials[serial] = None
        self._rx_serials.move_to_end(serial)
        if len(self._rx_serials) > 4 * sp.ACK_WINDOW:
            self._rx_serials.popitem(last=False)

    def _ack_bits(self, echo: int) -> int:
        return sum(1 << i for i in range(sp.ACK_WINDOW) if (echo - 1 - i) & 0xFFFF in self._rx_serials)

    def _ack_due(self) -> float | None:
        """When the acknowledgement of the tiles received is due: ``ack_delay_s`` after the last
        one (a burst is acknowledged once), at most ``4 ack_delay_s`` after the first."""
        if self._ack_first_s is None:
            return None
        d = self.cfg.ack_delay_s
        return max(min(self._ack_last_s + d, self._ack_first_s + 4 * d),
                   self._last_digest_s + self.cfg.min_digest_interval_s)

    def _probe_due(self) -> float | None:
        return self._next_probe_s if self._inflight else None

    def _schedule_digest(self, at_s: float) -> None:
        at_s = max(at_s, self._last_digest_s + self.cfg.min_digest_interval_s)
        self._digest_due = at_s if self._digest_due is None else min(self._digest_due, at_s)

    def _on_digest(self, p: sp.Digest, now_s: float) -> None:
        if self.peer_boot is not None and p.boot != self.peer_boot:
            self.stats.peer_restarts += 1
            self.events.emit(now_s, "PEER_RESTARTED", boot=p.boot, replica_lost=bool(p.flags & sp.FRESH))
            if p.flags & sp.FRESH and self.belief:  # its replica is lost: all of my layer goes again
                self.stats.full_resends += 1
                self.events.emit(now_s, "FULL_RESEND", tiles=len(self.rep.own))
            self.attach_profile = self.attach_profile or bool(p.flags & sp.FRESH)
            self.want_holdings = True
            self._peer_synced = False
            self._inflight.clear()
            self._last_holdings_s = float("-inf")
            self._digest_due = now_s  # ask for its holdings at once
        elif self.peer_boot is None and now_s - self._last_holdings_s >= self.cfg.holdings_retry_s:
            self._queue_holdings(now_s)  # first contact since my start: the peer will ask for them
        self.peer_boot = p.boot
        self._accepted(p.serial)
        if p.flags & sp.KNOWS_PROFILE and not self._peer_profile_stale:  # it holds my profile
            self.attach_profile = False
        for s in p.acked():
            for t, v in self._sent_tiles.get(s, ()):
                rec = self.rep.own.get(t)
                if rec is not None and v == rec.version:  # it holds my latest version
                    self.belief[t] = (rec.version, rec.digest)
                    self._inflight.pop(t, None)
                    self._lost.discard(t)
        if p.held_hash is not None:
            self._peer_synced = p.held_hash == self.rep.layer_hash(self.agent)
        if p.held_hash is None:
            pass  # an acknowledgement alone: what it proves is above
        elif p.held_hash == self.rep.layer_hash(self.agent):
            self.belief = {t: (r.version, r.digest) for t, r in self.rep.own.items()}
            self._inflight.clear()
            self._lost.clear()
            self._mismatches = 0
        elif not any(self._needed(t) for t in self.rep.own) and not self.want_holdings:
            self._mismatches += 1
            if self._mismatches >= 2:  # the peer holds something else than I believe
                self.events.emit(now_s, "HASH_MISMATCH")
                self.want_holdings = True
                self._mismatches = 0
        if p.flags & sp.WANT_HOLDINGS and now_s - self._last_holdings_s >= self.cfg.holdings_retry_s:
            self._queue_holdings(now_s)
        if p.flags & sp.ANSWER_NOW:
            self._answer = True
            self._digest_due = now_s
        for t in p.wants:
            if t in self.rep.held and now_s - self._returned_at.get(t, float("-inf")) >= self.cfg.holdings_retry_s:
                self._returns.add(t)
        self._probe_gap = self.cfg.probe_s
        if p.flags & sp.ECHO_VALID:
            echo_t = self._sent_at.get(p.echo_serial)
            if echo_t is not None:
                for t, (v, ts) in list(self._inflight.items()):
                    if ts + self.cfg.reorder_slack_s <= echo_t and self.rep.own[t].version == v and self._needed(t):
                        self._lost.add(t)
                        del self._inflight[t]

    def _on_holdings(self, p: sp.Holdings, now_s: float) -> None:
        per = self._holdings_per_page()
        n = self.rep.n_tiles
        if p.n_pages != -(-n // per) or any(not p.page * per <= t < min((p.page + 1) * per, n)
                                            for t, _v, _d in p.entries):
            self._bad(now_s, "HOLDINGS page does not fit the map")
            return
        if not self.want_holdings:
            return
        if p.profile != self.rep.profile.pid:  # the peer cannot decode my tiles yet
            self.attach_profile = self._peer_profile_stale = True
            return
        self._holdings_in[p.page] = p.entries  # pages of any set combine: each is its tiles' state
        if len(self._holdings_in) < p.n_pages:
            return
        entries = [e for page in sorted(self._holdings_in) for e in self._holdings_in[page]]
        self._holdings_in.clear()
        self.want_holdings = False
        self.attach_profile = self._peer_profile_stale = False
        self.fresh = False
        self.belief = {t: (v, d) for t, v, d in entries}
        self._inflight.clear()
        self._lost.clear()
        for t, v, _d in entries:
            self.rep.counter = max(self.rep.counter, v)
            mine = self.rep.own.get(t)
            if mine is None or v > mine.version:
                self.wants.add(t)
        for t, v, d in entries:
            mine = self.rep.own.get(t)
            if mine is not None and v == mine.version and d != mine.digest:  # a version used twice
                self.rep.counter += 1
                self.rep.own[t] = TileRec(self.rep.counter, mine.digest, mine.blob, mine.z)
                self.rep.touch(self.agent)
        self.events.emit(now_s, "HOLDINGS", tiles=len(entries), wanted=len(self.wants))

    def _holdings_per_page(self) -> int:
        return (self.cfg.mtu_bytes - sp.HOLDINGS_BASE) // sp.ENTRY_BYTES

    def _queue_holdings(self, now_s: float) -> None:
        """HOLDINGS of my copy of the peer's layer: page ``k`` lists the tiles ``k * per`` up to
        ``(k + 1) * per`` held, so a page is complete alone and pages of any set combine."""
        per = self._holdings_per_page()
        n_pages = -(-self.rep.n_tiles // per)
        self._set_id = (self._set_id + 1) & 0xFFFF
        self._holdings_out = []
        for k in range(n_pages):
            held = sorted(self.rep.held.items())
            pg = tuple((t, r.version, r.digest) for t, r in held if k * per <= t < (k + 1) * per)
            pid = self.peer_profile.pid if self.peer_profile is not None else 0
            self._holdings_out.append(sp.encode(sp.Holdings(self.agent, self.frame, 0, self._set_id, k, n_pages, pid,
                                                            pg)))
        self._last_holdings_s = now_s

    # ---------------------------------------------------------------- sending
    def _stalled(self, now_s: float) -> bool:
        ref = self._last_rx_s if self._last_rx_s is not None else self._started_s
        return ref is not None and now_s - ref > self.cfg.stall_s

    def _to_send(self) -> list[int]:
        """My tiles to send now (needed, and not in flight or proved lost), highest priority first."""
        cands = [t for t in self.rep.own if t not in self.wants and self._needed(t)
                 and (t in self._lost or t not in self._inflight or self._inflight[t][0] != self.rep.own[t].version)]

        def key(t: int) -> tuple[float, int]:
            ty, tx = divmod(t, self.rep.ntx)
            return (-(self.priority(ty, tx) if self.priority is not None else 0.0), t)
        return sorted(cands, key=key)

    def _batch(self, tiles: list[int], layer: dict[int, TileRec]) -> list[sp.TileEntry]:
        """The first of ``tiles`` (in order) that fit one TILE of ``mtu_bytes``."""
        out: list[sp.TileEntry] = []
        room = self.cfg.mtu_bytes - sp.TILE_BASE
        for t in tiles:
            rec = layer[t]
            e = sp.TileEntry(t, rec.version, rec.blob)
            if e.size > room:
                break
            out.append(e)
            room -= e.size
        return out

    def _digest_reason(self, now_s: float) -> bool:
        for due in (self._digest_due, self._ack_due(), self._probe_due()):
            if due is not None and now_s >= due:
                return True
        if now_s >= max(self._last_digest_s, self._last_tx_s) + self._keepalive_s():
            return True
        return bool((self.want_holdings or self.wants) and now_s >= self._last_digest_s + self.cfg.holdings_retry_s)

    def _keepalive_s(self) -> float:
        """``keepalive_s`` while anything is unsettled; while the peer holds all of my layer as I
        believe and nothing of its is owed an acknowledgement, ``0.8 stall_s`` (still inside the
        peer's stall time: an idle team keeps its link alive at a fraction of the bytes)."""
        settled = (not self.want_holdings and not self.wants and not self._inflight and self._ack_first_s is None
                   and self._peer_synced)
        return max(self.cfg.keepalive_s, 0.8 * self.cfg.stall_s) if settled else self.cfg.keepalive_s

    def _stamp(self, now_s: float) -> int:
        self._serial = (self._serial + 1) & 0xFFFF
        self._sent_at[self._serial] = now_s
        self._sent_at.move_to_end(self._serial)
        if len(self._sent_at) > 4096:
            self._sent_at.popitem(last=False)
        return self._serial

    def _make_digest(self, now_s: float) -> bytes:
        prof = self.rep.profile if self.want_holdings and self.attach_profile else None
        fixed = sp.DIGEST_BASE + sp.HASH_BYTES + 1 + (PROFILE_BYTES if prof is not None else 0)
        wants = tuple(sorted(self.wants))[: min(255, (self.cfg.mtu_bytes - fixed) // sp.WANT_BYTES)]
        probe = (self._probe_due() or float("inf")) <= now_s
        stalled = self._stalled(now_s)
        ask = probe or stalled
        echo = self._peer_serial
        # Acknowledgements, probes of tiles in flight and their answers leave the layer hash out:
        # the serials acknowledged prove what they prove. Keepalives, probes of a silent link and
        # asks for holdings carry it (what proves the peer holds all of my layer, or not).
        ack_only = (self._ack_first_s is not None or probe or self._answer or self._digest_due is not None) and not (
            stalled or self.want_holdings or self.wants)
        flags = ((sp.WANT_HOLDINGS if self.want_holdings else 0) | (sp.FRESH if self.fresh else 0)
                 | (sp.ANSWER_NOW if ask else 0) | (sp.ECHO_VALID if echo is not None else 0)
                 | (sp.KNOWS_PROFILE if self.peer_profile is not None else 0))
        d = sp.Digest(self.agent, self.frame, self._stamp(now_s), self.boot, echo or 0,
                      self._ack_bits(echo) if echo is not None else 0, flags,
                      None if ack_only else self.rep.layer_hash(self.peer), wants, prof)
        answer = self._answer
        self._digest_due = None
        self._ack_first_s = None
        self._answer = False
        self._last_digest_s = now_s
        if probe or stalled:
            self._probe_gap = min(2 * self._probe_gap, self.cfg.probe_max_s)
        self._next_probe_s = None
        self.stats.digests_out += 1
        self.stats.digests_answer += int(answer)
        self.stats.digests_probe += int(probe or stalled)
        pkt = sp.encode(d)
        self.stats.digest_bytes_out += len(pkt)
        if prof is not None:
            self.stats.profiles_out += 1
            self.stats.profile_bytes_out += PROFILE_BYTES
        return pkt

    def _tile_packet(self, owner: int, entries: list[sp.TileEntry], now_s: float) -> bytes:
        prof = self.rep.profile if owner == self.agent else self.peer_profile
        pid = prof.pid if prof is not None else 0
        pkt = sp.encode(sp.Tile(self.agent, self.frame, self._stamp(now_s), owner, pid, tuple(entries)))
        self.stats.tile_bytes_out += len(pkt)
        self.stats.tile_body_bytes_out += sum(len(e.blob) for e in entries)
        if owner == self.agent:
            self._sent_tiles[self._serial] = tuple((e.tile, e.version) for e in entries)
            if len(self._sent_tiles) > 4096:
                self._sent_tiles.popitem(last=False)
        return pkt

    def poll(self, now_s: float, max_bytes: int | None = None, hold_tiles: bool = False) -> list[bytes]:
        """The datagrams to send now, paced to ``rate_bps``; with ``max_bytes`` (a radio shared
        with other traffic: what is left of its budget) a packet is made only while one of
        ``mtu_bytes`` still fits. ``hold_tiles``: my tiles wait (a round is being published in
        steps: its tiles go when it ends, sharing TILEs); the rest goes."""
        if self._started_s is None:
            self._started_s = now_s
        self._now = now_s
        out: list[bytes] = []
        used = 0
        while self.pacer.ready(now_s):
            if max_bytes is not None and used + self.cfg.mtu_bytes > max_bytes:
                break
            pkt = self._next_packet(now_s, hold_tiles)
            if pkt is None:
                break
            self.pacer.consume(len(pkt), now_s)
            used += len(pkt)
            self.stats.packets_out += 1
            self.stats.bytes_out += len(pkt)
            self._last_tx_s = now_s
            out.append(pkt)
        if self._next_probe_s is None and self._inflight and self._digest_due is None:
            last = self._last_tile_s if self._last_tile_s is not None else now_s
            self._next_probe_s = max(last, self._last_digest_s) + self._probe_gap
        return out

    def _next_packet(self, now_s: float, hold_tiles: bool) -> bytes | None:
        stalled = self._stalled(now_s)
        if stalled:
            self._next_probe_s = None
            if now_s >= self._last_digest_s + self.cfg.probe_max_s:
                return self._make_digest(now_s)
            return None
        if self._answer or self._digest_reason(now_s):
            return self._make_digest(now_s)
        if self._holdings_out:
            self.stats.holdings_out += 1
            pkt = self._holdings_out.pop(0)
            self.stats.holdings_bytes_out += len(pkt)
            return pkt
        if self._returns:
            back = self._batch(sorted(self._returns), self.rep.held)
            for e in back:
                self._returns.discard(e.tile)
                self._returned_at[e.tile] = now_s
            self.stats.returns_out += len(back)
            return self._tile_packet(self.peer, back, now_s)
        if self.want_holdings or hold_tiles:
            return None  # what the peer holds of my layer is unknown, or a round is under way
        entries = self._batch(self._to_send(), self.rep.own)
        if not entries:
            return None
        for e in entries:
            prev = self._inflight.get(e.tile)
            if e.tile in self._lost or (prev is not None and prev[0] == e.version):
                self.stats.resent_tiles += 1
                self.stats.resent_bytes_out += e.size
            self._lost.discard(e.tile)
            self._inflight[e.tile] = (e.version, now_s)
        self._next_probe_s = None
        self.stats.tiles_out += len(entries)
        pkt = self._tile_packet(self.agent, entries, now_s)
        self._last_tile_s = now_s + 8.0 * len(pkt) / self.cfg.rate_bps  # the probe counts from its end on the air
        return pkt

    def next_deadline_s(self) -> float | None:
        """When :meth:`poll` next has work (None: only a datagram or a publish can make some)."""
        free = self.pacer.free_at_s
        if self._stalled(self._now):
            return max(self._last_digest_s + self.cfg.probe_max_s, free)
        cands = [max(self._last_digest_s, self._last_tx_s) + self._keepalive_s()]
        cands += [d for d in (self._digest_due, self._ack_due(), self._probe_due()) if d is not None]
        if self.want_holdings or self.wants:
            cands.append(self._last_digest_s + self.cfg.holdings_retry_s)
        ref = self._last_rx_s if self._last_rx_s is not None else self._started_s
        if ref is not None:
            cands.append(ref + self.cfg.stall_s + 1e-6)
        if self._answer or self._holdings_out or self._returns or (
                not self.want_holdings and self._to_send()):
            cands.append(free)
        return max(min(cands), free)
