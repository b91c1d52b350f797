"""The two-way map sync's packets and one end's rules (fsw.comm.team.map_sync; docs/sync.md)."""

from __future__ import annotations

import zlib

import numpy as np
import pytest

from fsw.comm.link_packets import PacketError
from fsw.comm.team import sync_checkpoint
from fsw.comm.team import sync_packets as sp
from fsw.comm.team.map_sync import MapSync
from fsw.comm.team.sync_config import SyncConfig

CELL, WHEEL = 0.03, 0.2
SHAPE = (48, 48)  # 3 x 3 tiles of 16 cells


def terrain(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[: SHAPE[0], : SHAPE[1]].astype(float)
    z = 0.3 * np.sin(yy / 7.0) + 0.2 * np.cos(xx / 5.0) + rng.normal(0, 0.01, SHAPE)
    return z.astype(np.float32)


def end(agent: int = 0, mtu: int = 512, **kw: object) -> MapSync:
    """One end; a small ``mtu`` puts the tiles (about 50 bytes each) in several TILEs."""
    cfg = SyncConfig(mtu_bytes=mtu)
    return MapSync(cfg, agent, 1 - agent, SHAPE, CELL, WHEEL, **kw)  # type: ignore[arg-type]


def pump(a: MapSync, b: MapSync, t0: float, t1: float, drop: float = 0.0, seed: int = 0) -> float:
    """Both ends on one stepped clock, packets delivered after 10 ms (``drop``: loss)."""
    rng = np.random.default_rng(seed)
    flight: list[tuple[float, MapSync, bytes]] = []
    t = t0
    while t < t1:
        for e, peer in ((a, b), (b, a)):
            for d in e.poll(t):
                assert len(d) <= e.cfg.mtu_bytes
                if rng.random() >= drop:
                    flight.append((t + 0.01, peer, d))
        for item in [f for f in flight if f[0] <= t]:
            flight.remove(item)
            item[1].receive(item[2], t)
        nxt = [x for x in (a.next_deadline_s(), b.next_deadline_s(), *(f[0] for f in flight)) if x is not None]
        t = max(t + 1e-3, min([*nxt, t1]))
    return t


def test_packets_round_trip_and_every_corruption_is_a_packet_error() -> None:
    pkts: list[sp.SyncPacket] = [
        sp.Tile(1, 0, 7, 1, 0xDEADBEEF, (sp.TileEntry(5, 42, b"tile bytes"),)),
        sp.Tile(1, 0, 8, 0, 0xDEADBEEF, (sp.TileEntry(5, 42, b"tile"), sp.TileEntry(9, 3 << 20, b"b" * 200))),
        sp.Digest(0, 2, 9, 3, 6, 0b101, sp.WANT_HOLDINGS | sp.ECHO_VALID | sp.HAS_WANTS | sp.HAS_HASH, b"\x01" * 6,
                  (7, 8)),
        sp.Digest(0, 2, 9, 3, 6, 0, sp.WANT_HOLDINGS | sp.HAS_PROFILE, None, (), end(0).profile),
        sp.Holdings(1, 0, 3, 4, 0, 2, 0xFEEDF00D, ((1, 2, 3), (4, 5, 6))),
    ]
    for p in pkts:
        d = sp.encode(p)
        assert sp.decode(d) == p
        assert sp.is_sync_packet(d)
        for i in range(len(d)):  # every single-byte change is refused with a PacketError
            bad = bytearray(d)
            bad[i] ^= 0x5A
            with pytest.raises(PacketError):
                sp.decode(bytes(bad))
        for n in range(len(d)):
            with pytest.raises(PacketError):
                sp.decode(d[:n])
    old = bytearray(sp.encode(pkts[0]))
    old[1] = 0x10 | sp.TILE  # the version-1 TILE (one tile, fixed-width fields) is another format
    old[-4:] = zlib.crc32(bytes(old[:-4])).to_bytes(4, "little")
    with pytest.raises(PacketError, match="version-2"):
        sp.decode(bytes(old))
    with pytest.raises(ValueError):
        sp.encode(sp.Tile(1, 0, 7, 1, 0, ()))  # a TILE carries at least one tile


def test_a_tile_decodes_alone_with_its_profile_and_waits_for_the_holdings_to_name_it() -> None:
    a, b = end(0), end(1)
    b.publish(terrain(1), 0.0)
    first = b.poll(0.0)
    asks = [sp.decode(d) for d in first]
    assert isinstance(asks[0], sp.Digest) and asks[0].flags & sp.WANT_HOLDINGS and asks[0].profile == b.profile
    assert not any(isinstance(p, sp.Tile) for p in asks)  # no tile before the peer holds the profile
    empty = sp.encode(sp.Holdings(0, 0, 5, 1, 0, 1, 0, ()))  # holdings naming no profile: asked again
    b.receive(empty, 0.1)
    assert b.want_holdings and b.attach_profile
    b.want_holdings = False  # as if the holdings named its profile: tiles may go
    pkts = [d for t in (1.0, 2.0) for d in b.poll(t) if isinstance(sp.decode(d), sp.Tile)]
    p = sp.decode(pkts[0])
    assert isinstance(p, sp.Tile) and p.profile == b.profile.pid
    a.receive(pkts[0], 2.1)  # its profile is not known yet: dropped, not acknowledged
    assert not a.held and a.stats.unknown_profile_tiles == 1
    a.receive(first[0], 2.2)  # the DIGEST with the profile, then one tile (sent again) decodes alone
    e = p.tiles[0]
    a.receive(sp.encode(sp.Tile(1, 0, p.serial + 100, 1, p.profile, (e,))), 2.3)
    assert a.peer_profile == b.profile
    assert np.array_equal(a.held[e.tile].z, b.own[e.tile].z, equal_nan=True)
    ys, xs = a.tile_slice(e.tile)
    assert np.nanmax(np.abs(a.held[e.tile].z - terrain(1)[ys, xs])) <= WHEEL
    assert a.stats.bad_packets == 0


def test_a_profile_of_another_frame_or_grid_is_refused_and_its_tiles_never_merged() -> None:
    a = end(0)
    other = MapSync(SyncConfig(mtu_bytes=128), 1, 0, SHAPE, CELL, WHEEL, origin=(0.5, 0.0))  # the grid shifted 0.5 m
    other.publish(terrain(1), 0.0)
    ask = other.poll(0.0)[0]
    other.want_holdings = False
    tiles = [d for t in (1.0, 2.0) for d in other.poll(t) if isinstance(sp.decode(d), sp.Tile)]
    assert len(tiles) >= 2
    for d in [ask, *tiles]:
        a.receive(d, 3.0)
    assert not a.held and a.peer_profile is None
    assert a.stats.profile_mismatches == 1 + len(tiles) and a.stats.bad_packets == 0
    assert [e for e in a.events.pop_all() if e.name == "FRAME_MISMATCH"]
    a.receive(sp.encode(sp.Digest(1, 0, 99, 0, 0, 0, sp.WANT_HOLDINGS, bytes(6))), 4.0)
    holdings = [sp.decode(d) for t in (4.0, 5.0) for d in a.poll(t) if isinstance(sp.decode(d), sp.Holdings)]
    assert holdings and all(h.profile == 0 for h in holdings)  # it names no profile of the peer


def test_a_digest_acknowledges_the_serials_it_received() -> None:
    d = sp.Digest(0, 0, 1, 0, 100, 0b1001, sp.ECHO_VALID, None)
    assert sp.decode(sp.encode(d)) == d and d.acked() == [100, 99, 96]
    assert sp.Digest(0, 0, 1, 0, 100, 0b1, 0, None).acked() == []  # no echo: nothing acknowledged
    a, b = end(0, mtu=128), end(1, mtu=128)
    a.publish(terrain(0), 0.0)
    b.receive(a.poll(0.0)[0], 0.1)  # a's DIGEST with its profile
    a.want_holdings = b.want_holdings = False  # both know what the other holds
    tiles = [p for t in (1.0, 2.0, 3.0) for p in map(sp.decode, a.poll(t)) if isinstance(p, sp.Tile)]
    assert len(tiles) >= 3 and all(len(p.tiles) == 2 for p in tiles[:-1])  # two tiles a packet
    for p in tiles[:-2] + tiles[-1:]:  # the one before last is lost
        b.receive(sp.encode(p), 3.5)
    ack = next(sp.decode(d) for t in (4.0, 5.0) for d in b.poll(t) if isinstance(sp.decode(d), sp.Digest))
    assert isinstance(ack, sp.Digest) and ack.held_hash is None  # an acknowledgement alone
    a.receive(sp.encode(ack), 5.1)
    lost = {e.tile for e in tiles[-2].tiles}
    assert set(a.belief) == {e.tile for p in tiles for e in p.tiles} - lost  # one serial acknowledges a packet
    assert lost.isdisjoint(a.belief) and lost <= a._lost  # the echo of a later packet proves them lost


def test_a_tile_with_a_body_that_does_not_decode_drops_its_whole_packet() -> None:
    a, b = end(0), end(1)
    b.publish(terrain(1), 0.0)
    a.receive(b.poll(0.0)[0], 0.5)  # b's DIGEST with its profile
    b.want_holdings = False
    p = next(p for p in map(sp.decode, b.poll(1.0)) if isinstance(p, sp.Tile))
    assert len(p.tiles) == 9  # every tile of the map in one TILE
    forged = sp.Tile(1, 0, p.serial, 1, p.profile, (*p.tiles[:-1], sp.TileEntry(p.tiles[-1].tile, 7, b"junk")))
    a.receive(sp.encode(forged), 1.5)
    assert not a.held and a.stats.bad_packets == 1 and p.serial not in a._rx_serials  # nothing taken in or acknowledged
    a.receive(sp.encode(p), 1.6)
    assert set(a.held) == {e.tile for e in p.tiles} and a._peer_serial == p.serial


def test_a_settled_idle_pair_keeps_its_link_alive_at_a_slower_pace() -> None:
    a, b = end(0), end(1)
    a.publish(terrain(0), 0.0)
    b.publish(terrain(1), 0.0)
    pump(a, b, 0.0, 30.0)
    assert a.replica_hash() == b.replica_hash()
    sent = a.stats.digests_out + b.stats.digests_out
    pump(a, b, 30.0, 130.0)  # 100 s with nothing new
    idle = a.stats.digests_out + b.stats.digests_out - sent
    assert 2 * 100 / (0.8 * a.cfg.stall_s) - 2 <= idle <= 2 * 100 / (0.8 * a.cfg.stall_s) + 2  # not every 10 s
    assert not a._stalled(130.0) and not b._stalled(130.0)
    b.publish(terrain(1) + np.float32(3 * WHEEL), 130.0)  # something new: settled no more
    pump(a, b, 130.0, 160.0)
    assert a.replica_hash() == b.replica_hash()


def test_only_tiles_changed_beyond_the_wheel_bound_are_published() -> None:
    s = end()
    z = terrain()
    z[:, 20:] = np.nan  # tiles of columns 0 and 1 partly known, column 2 unknown
    assert s.publish(z, 0.0) == 6
    assert s.publish(z + np.float32(0.5 * WHEEL), 10.0) == 0  # moved within the bound: nothing
    z2 = z.copy()
    z2[3, 3] += np.float32(1.5 * WHEEL)  # one cell beyond the bound: its tile alone
    assert s.publish(z2, 20.0) == 1
    z3 = z2.copy()
    z3[40, 40] = 0.1  # a newly known cell: a new tile
    assert s.publish(z3, 30.0) == 1
    assert s.stats.tiles_published == 8 and s.counter == 8
    with pytest.raises(ValueError, match="shape"):
        s.publish(np.zeros((5, 5)), 40.0)


def test_tiles_go_out_in_the_receivers_priority_order() -> None:
    want = [8, 5, 7, 4, 2, 6, 1, 3, 0]  # by distance from the bottom-right tile, then tile id

    def prio(ty: int, tx: int) -> float:
        return -float(np.hypot(2 - ty, 2 - tx))

    for mtu in (512, 128):  # in one TILE, or two tiles a TILE
        s = end(priority=prio, mtu=mtu)
        s.publish(terrain(), 0.0)
        s.want_holdings = False  # the peer's holdings are known (empty): tiles may go
        order = []
        t = 0.0
        while len(order) < 9:
            for d in s.poll(t):
                p = sp.decode(d)
                if isinstance(p, sp.Tile):
                    order += [e.tile for e in p.tiles]
            t = s.next_deadline_s() or t + 0.1
        assert order == want


def test_bad_and_foreign_packets_are_counted_and_dropped() -> None:
    a, b = end(0), end(1)
    b.publish(terrain(1), 0.0)
    pump(a, b, 0.0, 5.0)
    h = a.replica_hash()
    good = sp.encode(sp.Tile(1, 0, 999, 1, b.profile.pid, (sp.TileEntry(0, 10**6, b"not a tile body"),)))
    junk = [b"", b"\xa5", bytes(300), good, sp.encode(sp.Tile(2, 0, 5, 2, b.profile.pid, (sp.TileEntry(0, 1, b"x"),))),
            sp.encode(sp.Digest(1, 9, 1, 0, 0, 0, 0, bytes(6))),
            sp.encode(sp.Holdings(1, 0, 1, 1, 0, 7, a.profile.pid, ((0, 1, 2),)))]
    a.events.pop_all()
    for d in junk:
        a.receive(d, 6.0)
    assert a.replica_hash() == h
    assert a.stats.bad_packets == 5 and a.stats.foreign_packets == 2
    bad = [e for e in a.events.pop_all() if e.name == "BAD_PACKET"]
    assert len(bad) == 1 and "too short" in bad[0].args["last"]  # one event a second, with the reason
    a.receive(bytes(300), 7.5)
    assert [e.args["dropped"] for e in a.events.pop_all() if e.name == "BAD_PACKET"] == [5]


def test_two_ends_converge_and_a_checkpoint_restores_the_same_replica() -> None:
    a, b = end(0), end(1)
    a.publish(terrain(0), 0.0)
    b.publish(np.where(np.arange(SHAPE[1]) < 30, terrain(1), np.nan).astype(np.float32), 0.0)
    pump(a, b, 0.0, 20.0, drop=0.2, seed=3)
    assert a.replica_hash() == b.replica_hash()
    assert np.array_equal(a.replica_map(1), b.replica_map(1), equal_nan=True)
    assert np.isfinite(a.fused_map()).sum() == SHAPE[0] * SHAPE[1]
    r = sync_checkpoint.restore(sync_checkpoint.save(a), SyncConfig(), CELL, WHEEL, boot=1)
    assert r.replica_hash() == a.replica_hash() and r.counter > a.counter
    with pytest.raises(ValueError, match="not a usable map-sync checkpoint"):
        sync_checkpoint.restore(b"{not json", SyncConfig(), CELL, WHEEL, boot=1)
    with pytest.raises(ValueError, match="not a usable map-sync checkpoint"):
        sync_checkpoint.restore(sync_checkpoint.save(a).replace(b'"v": 2', b'"v": 9'), SyncConfig(), CELL, WHEEL,
                                boot=1)


def test_forged_packets_with_valid_checksums_never_raise() -> None:
    """Corruptions that pass the packet's CRC (recomputed) are counted or ignored, never raised,
    and never change a tile into one of another shape."""
    a, b = end(0), end(1)
    b.publish(terrain(2), 0.0)
    a.receive(b.poll(0.0)[0], 0.5)  # b's DIGEST with its profile: the forged bodies are decoded
    assert a.peer_profile == b.profile
    b.want_holdings = False
    pkts = [d for d in b.poll(1.0) + b.poll(2.0)]
    tiles = [e for p in map(sp.decode, pkts) if isinstance(p, sp.Tile) for e in p.tiles]
    assert tiles
    rng = np.random.default_rng(7)
    for i in range(300):
        t = tiles[i % len(tiles)]
        blob = bytearray(t.blob)
        for _ in range(int(rng.integers(1, 4))):
            blob[int(rng.integers(0, len(blob)))] = int(rng.integers(0, 256))
        entry = sp.TileEntry(int(rng.integers(0, 12)), 5000 + i, bytes(blob))
        forged = sp.Tile(1, 0, 1000 + i, 1, b.profile.pid, (entry,))
        a.receive(sp.encode(forged), 2.0)
        d = sp.encode(sp.Digest(1, 0, 2000 + i, 0, int(rng.integers(0, 1 << 16)), int(rng.integers(0, 1 << 32)),
                                int(rng.integers(0, 32)), rng.bytes(6), (int(rng.integers(0, 99)),)))
        a.receive(d, 2.0)
        h = sp.encode(sp.Holdings(1, 0, 3000 + i, 0, int(rng.integers(0, 2)), 1, a.profile.pid,
                                  ((int(rng.integers(0, 99)), i, 0),)))
        a.receive(h, 2.0)
    for t_id, rec in a.held.items():
        ys, xs = a.tile_slice(t_id)
        assert rec.z.shape == (ys.stop - ys.start, xs.stop - xs.start)
    assert a.stats.bad_packets > 0
    assert all(t < 9 for t in a.wants | set(a.belief))
