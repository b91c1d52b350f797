"""The map sync in flight (docs/sync.md, "In flight"): ``fsw.comm.team.sync_end`` on a stepped
clock, two ends over a lossless in-memory exchange (the lossy channel is test_team_sync.py's)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fsw.comm import link_packets
from fsw.comm.team import fix_packets
from fsw.comm.team import sync_packets as sp
from fsw.comm.team.sync_config import SyncConfig
from fsw.comm.team.sync_end import FlightSync, corridor_priority, overlay_newer, team_figures
from fsw.core.codec.mapcodec import CodecConfig
from fsw.core.geometry import MapGrid

GRID = MapGrid(0.0, 0.0, 0.03, 64, 64)  # 4 x 4 tiles of 16 cells
CODEC = CodecConfig(error_bound_wheels=0.25)


def _end(agent: int) -> FlightSync:
    return FlightSync(SyncConfig(enabled=True), agent, 1 - agent, GRID, 0.12, CODEC, 9600.0, 0.05)


def _ground(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.cumsum(rng.normal(0.0, 0.004, GRID.shape), axis=1).astype(np.float32)


def _round(e: FlightSync, z: np.ndarray, now: float) -> None:
    e.offer(z)
    job = e.round_job(now)
    assert job is not None
    for _ in job:
        pass
    e.round_done()


def _run(a: FlightSync, b: FlightSync, t0: float, seconds: float, budget: int = 512) -> float:
    """Both ends at 10 Hz, each datagram delivered at once; returns the clock."""
    t = t0
    while t < t0 + seconds:
        for src, dst in ((a, b), (b, a)):
            for d in src.poll(t, budget):
                dst.receive(d, t)
        t = round(t + 0.1, 3)
    return t


def test_the_packet_types_of_one_radio_do_not_collide() -> None:
    link_types = set(range(1, 10))
    fix_types = {fix_packets.FIX_REQUEST, fix_packets.FIX, fix_packets.NO_FIX}
    assert sp.SYNC_TYPES.isdisjoint(link_types | fix_types) and fix_types.isdisjoint(link_types)
    e = _end(0)
    _round(e, _ground(0), 0.0)
    pkts = e.poll(0.0, 512)
    assert pkts and all(FlightSync.is_sync_packet(p) and not fix_packets.is_fix_packet(p) for p in pkts)
    assert all(p[0] == link_packets.MAGIC for p in pkts)
    bad = bytearray(pkts[0])
    bad[-1] ^= 0x40  # every sync packet is CRC-checked: a damaged one is counted, never raised
    b = _end(1)
    b.receive(bytes(bad), 0.1)
    assert b.end.stats.bad_packets == 1 and not b.end.held


def test_the_budget_and_the_shared_air_come_first() -> None:
    e = _end(0)
    _round(e, _ground(0), 0.0)
    assert e.poll(0.0, 511) == []  # a packet of mtu_bytes would not fit what is left of the budget
    e.charge(1200, 0.0)  # a second of other traffic (the map link) on the same radio
    assert e.poll(0.5, 512) == []
    assert e.poll(1.01, 512)


def test_a_rounds_tiles_wait_for_its_end_and_share_tiles() -> None:
    a, b = _end(0), _end(1)
    t = _run(a, b, 0.0, 2.0)  # the ends learn what the other holds
    a.offer(_ground(0))
    job = a.round_job(t)
    assert job is not None
    next(job)  # one tile published, the round under way: it waits
    for _ in range(5):
        for d in a.poll(t, 512):
            assert not isinstance(sp.decode(d), sp.Tile)
            b.receive(d, t)
        t = round(t + 0.1, 3)
    for _ in job:
        pass
    a.round_done()
    tiles = [p for p in map(sp.decode, a.poll(t, 512)) if isinstance(p, sp.Tile)]
    assert len(tiles) == 1 and len(tiles[0].tiles) > 1  # the round's tiles together, as many as fit


def test_the_corridor_goes_first() -> None:
    prio = corridor_priority(GRID, 16, np.array([[0.2, 0.2], [1.7, 0.2]]))  # along the first tile row
    assert prio.shape == (4, 4) and np.all(prio[0] > prio[1]) and np.all(prio[1] > prio[3])
    a, b = _end(0), _end(1)
    a.set_corridor(np.array([[1.7, 1.7]]))  # the far corner tile first
    _round(a, _ground(0), 0.0)
    tiles: list[int] = []
    t = 0.0
    while len(tiles) < 3 and t < 10.0:  # (the ends first learn what the other holds)
        for d in a.poll(t, 512):
            p = sp.decode(d)
            tiles += [e.tile for e in p.tiles] if isinstance(p, sp.Tile) else []
            b.receive(d, t)
        for d in b.poll(t, 512):
            a.receive(d, t)
        t += 0.1
    assert tiles[:3] == [15, 11, 14]


def test_both_ends_converge_and_a_restart_from_the_checkpoint_resends_nothing_whole() -> None:
    a, b = _end(0), _end(1)
    za, zb = _ground(1), _ground(2)
    za[:, 40:] = np.nan  # each agent knows its part
    zb[:, :24] = np.nan
    _round(a, za, 0.0)
    _round(b, zb, 0.0)
    t = _run(a, b, 0.0, 60.0)
    assert a.end.replica_hash() == b.end.replica_hash()
    saved = json.loads(json.dumps(b.state()))  # what the Cliff-bot's checkpoint file holds
    sent_before = b.stats().tiles_published
    zb2 = zb.copy()
    zb2[:, 24:30] += 0.2  # it sees more after the checkpoint, then is killed
    _round(b, zb2, t)
    _run(a, b, t, 3.0)
    b2 = _end(1)
    b2.restore(saved)
    assert b2.boot == 1 and b2.stats().tiles_published == sent_before  # its counters go on
    za2 = za.copy()
    za2[:8, :8] += 0.3  # the RECON-bot maps on meanwhile
    _round(a, za2, t + 3.0)
    _run(a, b2, t + 3.0, 60.0)
    assert a.end.replica_hash() == b2.end.replica_hash()
    figs = team_figures(a, b2)
    assert figs["sync_source"] == "flown" and figs["sync_hash_equal"] is True and figs["sync_full_resends"] == 0
    assert a.stats().peer_restarts == 1 and b2.end.stats.adopted > 0  # its lost tiles came back
    with pytest.raises(ValueError, match="not a usable sync state"):
        _end(1).restore({"v": 1, "boot": 0, "stats": {}, "sync": "{"})


def test_a_cell_the_agent_forgot_keeps_its_last_height() -> None:
    a, b = _end(0), _end(1)
    z = _ground(3)
    _round(a, z, 0.0)
    lost = np.full(GRID.shape, np.nan, np.float32)  # its map lost in a restart
    _round(a, lost, 1.0)
    assert a.stats().tiles_published == 16  # nothing published again, nothing unknown
    _run(a, b, 0.0, 30.0)
    assert np.isfinite(b.end.replica_map(0)).all()


def test_newer_recon_tiles_win_where_they_say_something_new() -> None:
    a, b = _end(0), _end(1)
    z = _ground(4)
    z[:, 32:] = np.nan
    _round(a, z, 0.0)
    _run(a, b, 0.0, 30.0)
    link = np.where(np.isfinite(z), z, np.nan).astype(np.float64) + 1.0  # the link's map, in a datum 1 m up
    seen = {t: v for t, (v, _z) in b.held().items()}  # held when the link's map came: no newer
    same, n = overlay_newer(link, b, seen, 1.0, 0.06)
    assert n == 0 and np.array_equal(same, link, equal_nan=True)
    z2 = z.copy()
    z2[:16, 32:48] = 0.5  # a tile the link's map does not know
    z2[16:32, :16] += 0.01  # one within the bounds: nothing new
    _round(a, z2, 40.0)
    _run(a, b, 40.0, 30.0)
    got, n = overlay_newer(link, b, seen, 1.0, 0.06)
    assert n == 1 and np.allclose(got[:16, 32:48], 1.5, atol=0.03)
    assert np.array_equal(got[16:32, :16], link[16:32, :16])
    again, n = overlay_newer(got, b, seen, 1.0, 0.06)  # each version is weighed once
    assert n == 0
