"""Lockstep run of the two-way map sync between the team's agents (docs/sync.md).

Two :class:`fsw.comm.team.map_sync.MapSync` ends, the RECON-bot (agent 0, channel side ``a``)
and the Cliff-bot (agent 1, side ``b``), over the bench's seeded radio channel
(:class:`hil_sim.link.radio_channel.RadioChannel`: loss, bit errors, duplication, reordering,
outages) on one simulated clock that jumps from event to event. Each agent has a map of its
own that grows as it looks around (:class:`SyncScene`: a seeded terrain, one view disc per
agent per round, a few real changes of the ground); every ``round_s`` it publishes its map to
its sync end, and every few rounds it checkpoints the sync state with the map. A :class:`Kill` takes an agent down
(SIGKILL: whatever arrives is lost) and restarts it from its last checkpoint.

:func:`run_sync` returns :class:`SyncResult`; :func:`sync_figures` the team section's figures
(``sync_hash_equal``, ``sync_rounds``, ``sync_bytes``, ``sync_minimal_bytes``,
``sync_full_resends``), for any caller that drives the two ends, the team mission included.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, fields

import numpy as np
from numpy.typing import NDArray

from fsw.comm.team import sync_checkpoint
from fsw.comm.team.map_sync import F32, MapSync, Priority
from fsw.comm.team.sync_config import SyncConfig, SyncStats
from hil_sim.link.radio_channel import RadioChannel, RadioChannelConfig

F64 = NDArray[np.float64]
AGENTS = (0, 1)
SIDES = ("a", "b")


@dataclass(frozen=True)
class Kill:
    """Agent ``agent`` is killed at ``at_s`` and restarts ``down_s`` later from its last checkpoint
    (``from_checkpoint=False``: with nothing, its replica lost)."""

    agent: int
    at_s: float
    down_s: float = 5.0
    from_checkpoint: bool = True


@dataclass(frozen=True)
class SyncScene:
    """A seeded terrain and what each agent sees in each round: ``views[agent][round]`` is the
    (row, col) centre of a disc of ``radius`` cells; ``changes[round]`` are (row, col, radius,
    metres) patches of ground that change then (a rock falls, a step collapses)."""

    truth: F64
    views: tuple[tuple[tuple[int, int], ...], ...]
    radius: int
    changes: dict[int, tuple[tuple[int, int, int, float], ...]]
    cell_m: float = 0.03
    wheel_m: float = 0.2
    observed: tuple[tuple[F32, ...], ...] | None = None  # per agent per round: its map (replaces views)

    @property
    def rounds(self) -> int:
        return len(self.views[0])

    def truth_at(self, rnd: int) -> F64:
        z = self.truth.copy()
        yy, xx = np.mgrid[: z.shape[0], : z.shape[1]]
        for r in sorted(k for k in self.changes if k <= rnd):
            for cy, cx, rad, dz in self.changes[r]:
                z[(yy - cy) ** 2 + (xx - cx) ** 2 <= rad * rad] += dz
        return z


def make_scene(seed: int, n: int = 128, rounds: int = 30, radius: int = 20) -> SyncScene:
    """A terrain of ``n`` x ``n`` cells (hills, a cliff step, rocks) and two agents' views: the
    RECON-bot walking the plateau side, the Cliff-bot the face side, crossing in the middle."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:n, :n].astype(float)
    z = 0.5 * np.tanh((yy - n / 2) / 3.0)  # the step
    for _ in range(6):
        cy, cx, s, a = rng.uniform(0, n), rng.uniform(0, n), rng.uniform(n / 10, n / 4), rng.uniform(-0.4, 0.4)
        z += a * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * s * s))
    for _ in range(12):
        cy, cx, s = rng.uniform(0, n), rng.uniform(0, n), rng.uniform(1.5, 4)
        z += rng.uniform(0.1, 0.5) * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * s * s))
    views = []
    for band in ((0.1, 0.6), (0.4, 0.9)):
        pts = []
        y, x = rng.uniform(band[0] * n, band[1] * n), rng.uniform(0, n)
        for _ in range(rounds):
            y = float(np.clip(y + rng.normal(0, n / 10), band[0] * n, band[1] * n))
            x = float(np.clip(x + rng.normal(0, n / 8), 0, n - 1))
            pts.append((int(y), int(x)))
        views.append(tuple(pts))
    changes = {int(r): tuple((int(rng.integers(0, n)), int(rng.integers(0, n)), int(rng.integers(3, 8)),
                              float(rng.choice([-1, 1]) * rng.uniform(0.3, 0.6))) for _ in range(2))
               for r in rng.choice(np.arange(1, rounds), size=max(1, rounds // 8), replace=False)}
    return SyncScene(z, tuple(views), radius, changes)


class _Agent:
    """One agent's map (what it has seen, NaN elsewhere) and its noise (fixed, so seeing a cell
    again gives the same value)."""

    def __init__(self, scene: SyncScene, agent: int, seed: int) -> None:
        self.scene, self.agent = scene, agent
        self.noise = np.random.default_rng([seed, agent]).normal(0.0, 0.01, scene.truth.shape)
        self.z = np.full(scene.truth.shape, np.nan, np.float32)

    def look(self, rnd: int) -> None:
        if self.scene.observed is not None:
            m = self.scene.observed[self.agent][rnd]
            known = np.isfinite(m)
            self.z[known] = m[known]
            return
        cy, cx = self.scene.views[self.agent][rnd]
        yy, xx = np.mgrid[: self.z.shape[0], : self.z.shape[1]]
        disc = (yy - cy) ** 2 + (xx - cx) ** 2 <= self.scene.radius ** 2
        truth = self.scene.truth_at(rnd)
        self.z[disc] = (truth + self.noise)[disc].astype(np.float32)

    def adopt(self, sync: MapSync, tile: int, z: F32) -> None:
        """A tile of its own given back by the peer after a restart: what it had lost."""
        sl = sync.tile_slice(tile)
        known = np.isfinite(z)
        self.z[sl][known] = z[known]


@dataclass
class SyncResult:
    hash_equal: bool  # the replicas' hashes equal at the end
    rounds: int  # sync rounds with new views (the mission's)
    extra_rounds: int  # rounds after them, with nothing new, until the replicas were equal (or gave up)
    round_times_s: list[float]  # when each round published
    lag_s: list[float | None]  # per round: publish to equal replicas (None: not before the next round)
    equal_times_s: list[float]  # moments the replicas became equal (from unequal)
    round_s: float
    stats: dict[int, SyncStats]  # per agent, summed over its restarts
    air_bytes: int
    full_resends: int
    events: list[tuple[int, float, str]] = field(default_factory=list)

    @property
    def sync_bytes(self) -> int:
        """Bytes of the sync's packets that reached the other agent (both ways; copies the
        channel duplicated are not counted, copies the protocol sent again are)."""
        return sum(s.bytes_in for s in self.stats.values())

    @property
    def minimal_bytes(self) -> int:
        """Bytes of the minimal deltas: every published tile version's packet, once."""
        return sum(s.minimal_bytes for s in self.stats.values())

    def rounds_to_equal_after(self, t_s: float) -> int | None:
        """Sync rounds (``round_s`` each, at least 1) from ``t_s`` (the link's return, a restart)
        until the replicas' hashes are first equal again; None: never."""
        later = [t for t in self.equal_times_s if t >= t_s]
        return max(1, math.ceil((later[0] - t_s) / self.round_s - 1e-9)) if later else None


def _add(total: SyncStats, s: SyncStats) -> None:
    for f in fields(SyncStats):
        setattr(total, f.name, getattr(total, f.name) + getattr(s, f.name))


def run_sync(scene: SyncScene, channel: RadioChannelConfig, seed: int = 0, *, cfg: SyncConfig | None = None,
             round_s: float = 10.0, kills: Sequence[Kill] = (), settle_rounds: int = 3,
             corridor_first: bool = True, checkpoint_every: int = 3, max_steps: int = 2_000_000) -> SyncResult:
    """Run ``scene.rounds`` sync rounds (then up to ``settle_rounds`` more with nothing new seen);
    each agent checkpoints its map and sync state every ``checkpoint_every`` rounds."""
    cfg = cfg or SyncConfig()
    ch = RadioChannel(channel, seed)
    agents = {a: _Agent(scene, a, seed) for a in AGENTS}
    boots = dict.fromkeys(AGENTS, 0)
    pos = {a: scene.views[a][0] for a in AGENTS}

    def priority_for(a: int) -> Priority | None:
        peer = 1 - a

        def prio(ty: int, tx: int) -> float:  # the receiver's corridor first: nearest its view
            tc = cfg.tile_cells
            cy, cx = pos[peer]
            return -float(np.hypot(ty * tc + tc / 2 - cy, tx * tc + tc / 2 - cx))
        return prio if corridor_first else None

    def make(a: int) -> MapSync:
        return MapSync(cfg, a, 1 - a, scene.truth.shape, scene.cell_m, scene.wheel_m, boot=boots[a],
                       priority=priority_for(a),
                       on_adopt=lambda t, z, a=a: agents[a].adopt(ends[a], t, z))

    ends: dict[int, MapSync] = {}
    for a in AGENTS:
        ends[a] = make(a)
    totals = {a: SyncStats() for a in AGENTS}
    checkpoints: dict[int, tuple[bytes, F32]] = {}
    down: dict[int, Kill] = {}
    pending = sorted(kills, key=lambda k: k.at_s)
    events: list[tuple[int, float, str]] = []
    n_rounds = scene.rounds + settle_rounds
    equal_times: list[float] = []
    was_equal = True
    round_times: list[float] = []
    lags: list[float | None] = []
    rnd = 0
    t = t_pub = 0.0
    for _ in range(max_steps):
        while pending and t >= pending[0].at_s:
            k = pending.pop(0)
            down[k.agent] = k
            _add(totals[k.agent], ends[k.agent].stats)
            events += [(k.agent, e.time_s, e.name) for e in ends[k.agent].events.pop_all()]
            events.append((k.agent, t, "KILLED"))
        for k in [k for k in down.values() if t >= k.at_s + k.down_s]:
            a = k.agent
            del down[a]
            boots[a] += 1
            ck = checkpoints.get(a) if k.from_checkpoint else None
            if ck is not None:
                agents[a].z = ck[1].copy()
                ends[a] = sync_checkpoint.restore(ck[0], cfg, scene.cell_m, scene.wheel_m, boot=boots[a],
                                          priority=priority_for(a),
                                          on_adopt=lambda tt, z, a=a: agents[a].adopt(ends[a], tt, z))
            else:
                agents[a].z = np.full(scene.truth.shape, np.nan, np.float32)
                ends[a] = make(a)
            events.append((a, t, "RESTARTED"))
        if rnd < n_rounds and t >= rnd * round_s:
            round_times.append(t)
            for a in AGENTS:
                if a in down:
                    continue
                if rnd < scene.rounds:
                    pos[a] = scene.views[a][rnd]
                    agents[a].look(rnd)
                ends[a].publish(agents[a].z, t)
                if rnd % checkpoint_every == 0:
                    checkpoints[a] = (sync_checkpoint.save(ends[a]), agents[a].z.copy())
            rnd += 1
            lags.append(None)
            t_pub = t
        for a, side in zip(AGENTS, SIDES, strict=True):
            for d in ch.receive(side, t):
                if a not in down:
                    ends[a].receive(d, t)
        for a, side in zip(AGENTS, SIDES, strict=True):
            if a not in down:
                for d in ends[a].poll(t):
                    ch.send(side, d, t)
        equal = not down and ends[0].replica_hash() == ends[1].replica_hash()
        if equal and not was_equal:
            equal_times.append(t)
        was_equal = equal
        if lags and lags[-1] is None and equal:
            lags[-1] = round(t - t_pub, 3)
        if rnd >= n_rounds and not down and not pending:
            if ends[0].replica_hash() == ends[1].replica_hash() and ch.next_arrival_s() is None:
                break
            if t > (n_rounds + settle_rounds) * round_s:
                break
        nxt = [x for x in (*(ends[a].next_deadline_s() for a in AGENTS if a not in down), ch.next_arrival_s(),
                           *(k.at_s + k.down_s for k in down.values()), pending[0].at_s if pending else None,
                           rnd * round_s if rnd < n_rounds else None) if x is not None]
        t_next = min(nxt) if nxt else t + round_s
        t = t_next if t_next > t else t + 1e-3
    for a in AGENTS:
        _add(totals[a], ends[a].stats)
        events += [(a, e.time_s, e.name) for e in ends[a].events.pop_all()]
    return SyncResult(
        hash_equal=ends[0].replica_hash() == ends[1].replica_hash(), rounds=scene.rounds,
        extra_rounds=max(0, rnd - scene.rounds), round_times_s=round_times,
        lag_s=lags, equal_times_s=equal_times, round_s=round_s, stats=totals,
        air_bytes=ch.stats("a").air_bytes + ch.stats("b").air_bytes,
        full_resends=sum(s.full_resends for s in totals.values()), events=events)


def scene_from_maps(recon_maps: Sequence[NDArray[np.floating]], cliff_maps: Sequence[NDArray[np.floating]],
                    cell_m: float, wheel_m: float) -> SyncScene:
    """A scene of the maps each agent held after each imaging cycle (same count and shape, NaN
    unknown): what a team mission hands to :func:`run_sync`. Each agent's position for the
    priority order is the centre of what it saw new in that cycle."""
    if len(recon_maps) != len(cliff_maps) or not recon_maps:
        raise ValueError("both agents need a map for every cycle, and at least one cycle")
    obs = tuple(tuple(np.asarray(m, np.float32) for m in ms) for ms in (recon_maps, cliff_maps))
    shape = obs[0][0].shape
    if any(m.shape != shape for ms in obs for m in ms):
        raise ValueError("every cycle's map must have the same shape")
    views = []
    for ms in obs:
        pts, seen = [], np.zeros(shape, bool)
        for m in ms:
            new = np.isfinite(m) & ~seen
            seen |= np.isfinite(m)
            ys, xs = np.nonzero(new if new.any() else seen) if seen.any() else (np.array([0]), np.array([0]))
            pts.append((int(np.mean(ys)), int(np.mean(xs))))
        views.append(tuple(pts))
    return SyncScene(np.zeros(shape), tuple(views), 0, {}, cell_m, wheel_m, obs)


def team_sync_figures(recon_maps: Sequence[NDArray[np.floating]], cliff_maps: Sequence[NDArray[np.floating]],
                      channel: RadioChannelConfig, seed: int, *, cell_m: float, wheel_m: float,
                      round_s: float = 10.0, cfg: SyncConfig | None = None) -> dict[str, object]:
    """The team section's sync figures for a mission: both agents' maps after each imaging cycle
    (``recon_maps[k]``, ``cliff_maps[k]``), synced over ``channel`` one round per cycle."""
    scene = scene_from_maps(recon_maps, cliff_maps, cell_m, wheel_m)
    return sync_figures(run_sync(scene, channel, seed, cfg=cfg, round_s=round_s))


def sync_figures(res: SyncResult) -> dict[str, object]:
    """The team section's sync figures (docs/sync.md, "Figures")."""
    return {"sync_hash_equal": res.hash_equal, "sync_rounds": res.rounds, "sync_bytes": res.sync_bytes,
            "sync_minimal_bytes": res.minimal_bytes, "sync_full_resends": res.full_resends,
            "sync_air_bytes": res.air_bytes}
