"""The two-way map sync in flight: one agent's sync end as its radio task runs it (docs/sync.md,
"In flight").

:class:`FlightSync` holds a :class:`~fsw.comm.team.map_sync.MapSync` end and what a radio task
needs round it, sans-I/O like the end itself:

* **Rounds.** :meth:`FlightSync.offer` takes the agent's own map once per round (the RECON-bot's
  after each imaging step, the Cliff-bot's after each look); :meth:`FlightSync.round_job` is the
  round as a slack job (each tile encoded is a step). A map offered while a round is under way
  waits, and only the newest waits; while a round runs its tiles wait for its end (they share
  TILEs), the rest of the end's packets go. A cell the agent's map no longer knows (its map was lost
  in a restart) keeps the height its layer last had: the layer forgets nothing it sent.
* **Order.** New tiles go out by their value to the receiver's task (:func:`corridor_priority`:
  nearest the Cliff-bot's corridor first, the polyline from where it stands through its
  targets), then by tile number.
* **Air time.** Every packet the radio sends is charged to one pacer at the radio's rate
  (:meth:`FlightSync.charge`), and the sync's packets are made only while that pacer is free and
  a packet of ``mtu_bytes`` fits what is left of the activation's byte budget: the traffic sent
  before it (fixes, then the map link) goes first.
* **Checkpoint.** :meth:`FlightSync.state` is the end's checkpoint (``sync_checkpoint.save``), its
  boot id and its counters; :meth:`FlightSync.restore` restarts the end from one with the next
  boot id (the peer learns of the restart and the two exchange holdings: no full resend).
"""

from __future__ import annotations

from collections.abc import Generator
from dataclasses import asdict, fields

import numpy as np
from numpy.typing import NDArray

from fsw.comm.link import Pacer
from fsw.comm.team import sync_checkpoint
from fsw.comm.team import sync_packets as sp
from fsw.comm.team.map_sync import F32, MapSync
from fsw.comm.team.sync_config import SyncConfig, SyncStats
from fsw.core.codec.mapcodec import CodecConfig
from fsw.core.geometry import MapGrid

F64 = NDArray[np.float64]
STATE_VERSION = 1


def corridor_priority(grid: MapGrid, tile_cells: int, points: F64) -> F64:
    """Each tile's value to the Cliff-bot's task, ``(n_tile_rows, n_tile_cols)``: minus the distance
    (m) from the tile's centre to the polyline through ``points`` (``(N, 2)``, map frame: where
    the Cliff-bot stands, then its targets); all 0 without points."""
    nty, ntx = -(-grid.ny // tile_cells), -(-grid.nx // tile_cells)
    pts = np.asarray(points, float).reshape(-1, 2)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) == 0:
        return np.zeros((nty, ntx))
    side = tile_cells * grid.cell
    cx = grid.x0 + (np.arange(ntx) + 0.5) * side
    cy = grid.y0 + (np.arange(nty) + 0.5) * side
    X, Y = np.meshgrid(cx, cy)
    best = np.hypot(X - pts[0, 0], Y - pts[0, 1])
    for a, b in zip(pts[:-1], pts[1:], strict=True):
        d = b - a
        L2 = float(d @ d)
        u = np.zeros_like(X) if L2 == 0 else np.clip(((X - a[0]) * d[0] + (Y - a[1]) * d[1]) / L2, 0.0, 1.0)
        best = np.minimum(best, np.hypot(X - (a[0] + u * d[0]), Y - (a[1] + u * d[1])))
    return np.asarray(-best, float)


class FlightSync:
    """One agent's sync end in its radio task (module docstring)."""

    def __init__(self, cfg: SyncConfig, agent: int, peer: int, grid: MapGrid, wheel_m: float,
                 codec: CodecConfig, rate_bps: float, catchup_s: float) -> None:
        self.cfg, self.agent, self.peer, self.grid = cfg, agent, peer, grid
        self.wheel_m, self.codec = wheel_m, codec
        self.air = Pacer(rate_bps, catchup_s)  # every packet of the radio, the sync's included
        self.origin = (float(grid.x0), float(grid.y0))
        self.boot = 0
        self.end = self._make(None)
        self.before = SyncStats()  # the counters of the end's earlier boots
        self.prio = np.zeros((self.end.rep.nty, self.end.rep.ntx))
        self.waiting: F32 | None = None  # the newest map offered, its round not started
        self.busy = False  # a round under way
        self.offered = 0
        self._tiles_in = 0

    def _make(self, state: bytes | None) -> MapSync:
        if state is None:
            end = MapSync(self.cfg, self.agent, self.peer, self.grid.shape, self.grid.cell, self.wheel_m,
                          boot=self.boot, codec=self.codec, priority=self._priority, origin=self.origin)
        else:
            end = sync_checkpoint.restore(state, self.cfg, self.grid.cell, self.wheel_m, boot=self.boot,
                                          codec=self.codec, priority=self._priority, origin=self.origin)
            if end.agent != self.agent or end.peer != self.peer or end.shape != self.grid.shape:
                raise ValueError(f"a sync checkpoint of agent {end.agent} on a {end.shape} map, not agent "
                                 f"{self.agent} on {self.grid.shape}")
        end.pacer = self.air
        return end

    def _priority(self, ty: int, tx: int) -> float:
        return float(self.prio[ty, tx])

    def set_corridor(self, points: F64) -> None:
        """The Cliff-bot's corridor (where it stands, then its targets): the order of new tiles."""
        self.prio = corridor_priority(self.grid, self.cfg.tile_cells, points)

    # -- rounds -------------------------------------------------------------------------------
    def offer(self, z: F32 | F64) -> None:
        """The agent's own map (heights, NaN unknown) for the next round."""
        a = np.asarray(z, np.float32)
        if a.shape != self.grid.shape:
            raise ValueError(f"map of shape {a.shape} is not the grid's {self.grid.shape}")
        self.waiting = a.copy()
        self.offered += 1

    def round_job(self, now_s: float) -> Generator[None, None, int] | None:
        """The waiting round as a slack job (None: none waits, or one is under way); the task
        submits it and calls :meth:`round_done` when it ends."""
        if self.waiting is None or self.busy:
            return None
        z, self.waiting = self.waiting, None
        had = self.end.replica_map(self.agent)  # what the layer holds: kept where the map forgets
        z = np.where(np.isfinite(z), z, had)
        self.busy = True
        return self.end.publish_steps(z, now_s)

    def round_done(self) -> None:
        self.busy = False

    # -- the radio ----------------------------------------------------------------------------
    @staticmethod
    def is_sync_packet(datagram: bytes) -> bool:
        return sp.is_sync_packet(datagram)

    def receive(self, datagram: bytes, now_s: float) -> None:
        self.end.receive(datagram, now_s)

    def charge(self, nbytes: int, now_s: float) -> None:
        """A packet of another kind the radio sent: its air time is the sync's wait."""
        self.air.consume(nbytes, now_s)

    def poll(self, now_s: float, max_bytes: int) -> list[bytes]:
        """The end's packets; while a round is under way its tiles wait for the round's end, so
        the round's tiles share TILEs (one tile is published per slack step)."""
        return self.end.poll(now_s, max_bytes=max_bytes, hold_tiles=self.busy)

    def peer_tiles_since(self) -> bool:
        """Whether tiles of the peer's layer arrived since the last call."""
        n = self.end.stats.tiles_in
        new, self._tiles_in = n != self._tiles_in, n
        return new

    def held(self) -> dict[int, tuple[int, F32]]:
        """The peer's layer as held: tile -> (version, cells)."""
        return {t: (r.version, r.z) for t, r in self.end.held.items()}

    def tile_slice(self, t: int) -> tuple[slice[int, int, None], slice[int, int, None]]:
        return self.end.tile_slice(t)

    @property
    def bound_m(self) -> float:
        """The tiles' height error bound (m)."""
        return self.end.rep.bound_m

    # -- checkpoint and figures ---------------------------------------------------------------
    def stats(self) -> SyncStats:
        """The end's counters over all its boots."""
        total = SyncStats()
        for f in fields(SyncStats):
            setattr(total, f.name, getattr(self.before, f.name) + getattr(self.end.stats, f.name))
        return total

    def state(self) -> dict[str, object]:
        """The end's checkpoint (JSON-able): the sync state, its boot id, its counters."""
        return {"v": STATE_VERSION, "boot": self.boot, "sync": sync_checkpoint.save(self.end).decode(),
                "stats": asdict(self.stats())}

    def restore(self, st: object) -> None:
        """Restart the end from :meth:`state` with the next boot id; ``ValueError`` (one line) if
        the state is not one."""
        try:
            if not isinstance(st, dict) or st.get("v") != STATE_VERSION:
                raise ValueError("not a flight sync state of this version")
            boot = int(st["boot"])
            counts = st["stats"]
            if not isinstance(counts, dict):
                raise TypeError("stats is not an object")
            before = SyncStats(**{f.name: int(counts.get(f.name, 0)) for f in fields(SyncStats)})
            sync = st["sync"]
            if not isinstance(sync, str):
                raise TypeError("sync is not text")
            self.boot = (boot + 1) & 0xFFFF
            end = self._make(sync.encode())
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"not a usable sync state: {exc}") from None
        self.end = end
        before.rounds = 0  # the end's checkpoint carries its rounds on
        self.before = before
        self._tiles_in = 0
        self.waiting, self.busy = None, False

    def figures(self) -> dict[str, object]:
        """This end's counters for the summary (``sync_ends``)."""
        s = self.stats()
        return {"agent": self.agent, "boot": self.boot, "rounds": s.rounds, "tiles_published": s.tiles_published,
                "bytes_in": s.bytes_in, "bytes_out": s.bytes_out, "minimal_bytes": s.minimal_bytes,
                "resent_tiles": s.resent_tiles, "full_resends": s.full_resends, "peer_restarts": s.peer_restarts,
                "bad_packets": s.bad_packets, "hash": self.end.replica_hash(),
                "bytes_out_by_kind": {"tile": s.tile_bytes_out, "tile_body": s.tile_body_bytes_out,
                                      "tile_resent": s.resent_bytes_out, "digest": s.digest_bytes_out,
                                      "holdings": s.holdings_bytes_out, "profile": s.profile_bytes_out},
                "profile": f"{self.end.profile.pid:08x}"}


def team_figures(a: FlightSync | None, b: FlightSync | None) -> dict[str, object]:
    """The team section's sync figures from the two flown ends (docs/sync.md, "Figures"): without
    both ends (an agent that does not sync) ``sync_hash_equal`` is None and the counts 0."""
    if a is None or b is None:
        return {"sync_source": "none", "sync_hash_equal": None, "sync_rounds": 0, "sync_bytes": 0,
                "sync_minimal_bytes": 0, "sync_full_resends": 0, "sync_air_bytes": 0}
    sa, sb = a.stats(), b.stats()
    return {"sync_source": "flown", "sync_hash_equal": a.end.replica_hash() == b.end.replica_hash(),
            "sync_rounds": sa.rounds + sb.rounds, "sync_bytes": sa.bytes_in + sb.bytes_in,
            "sync_minimal_bytes": sa.minimal_bytes + sb.minimal_bytes,
            "sync_full_resends": sa.full_resends + sb.full_resends, "sync_air_bytes": sa.bytes_out + sb.bytes_out,
            "sync_ends": [a.figures(), b.figures()]}


def overlay_newer(base: F64, sync: FlightSync, seen: dict[int, int], datum_m: float,
                  tol_m: float) -> tuple[F64, int]:
    """``base`` (a map the peer sent whole: the Cliff-bot's received map) with the peer's tiles of
    versions not in ``seen`` (tile -> the last version considered; updated) that say something
    new: a cell ``base`` does not know, or one moved by more than ``tol_m`` (both maps' error
    bounds). Such a tile wins on every cell it knows; ``base``'s other cells stay. Heights of
    the tiles are shifted by ``datum_m``. Returns the map and how many tiles won."""
    z = np.array(base, np.float64)
    n = 0
    for t, (version, cells) in sorted(sync.held().items()):
        if seen.get(t, -1) >= version:
            continue
        seen[t] = version
        sl = sync.tile_slice(t)
        new = np.asarray(cells, np.float64) + datum_m
        cur = z[sl]
        known = np.isfinite(new)
        with np.errstate(invalid="ignore"):
            moved = known & (~np.isfinite(cur) | (np.abs(new - cur) > tol_m))
        if moved.any():
            cur[known] = new[known]
            n += 1
    return z, n
