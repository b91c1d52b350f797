"""The two-way map sync's packets and one end's rules (fsw.comm.team.map_sync; docs/sync.md)."""

from __future__ import annotations

import numpy as np
import pytest

from fsw.comm.link_packets import PacketError
from fsw.comm.team import sync_packets as sp
from fsw.comm.team.map_sync import MapSync, SyncConfig

CELL, WHEEL = 0.03, 0.2
SHAPE = (48, 48)  # 3 x 3 tiles of 16 cells


def terrain(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[: SHAPE[0], : SHAPE[1]].astype(float)
    z = 0.3 * np.sin(yy / 7.0) + 0.2 * np.cos(xx / 5.0) + rng.normal(0, 0.01, SHAPE)
    return z.astype(np.float32)


def end(agent: int = 0, **kw: object) -> MapSync:
    return MapSync(SyncConfig(), agent, 1 - agent, SHAPE, CELL, WHEEL, **kw)  # type: ignore[arg-type]


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
        sp.Tile(1, 0, 7, 1, 5, 42, sp.blob_digest(b"tile bytes"), b"tile bytes"),
        sp.Digest(0, 2, 9, 3, 4, 5, 6, sp.WANT_HOLDINGS | sp.ECHO_VALID, 12, b"\x01" * 8, ((1, 2), (3, 4)), (7, 8)),
        sp.Holdings(1, 0, 3, 4, 0, 2, ((1, 2, 3), (4, 5, 6))),
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


def test_a_tile_whose_bytes_do_not_match_its_digest_is_refused() -> None:
    d = sp.encode(sp.Tile(1, 0, 7, 1, 5, 42, sp.blob_digest(b"other"), b"tile bytes"))
    with pytest.raises(PacketError, match="digest"):
        sp.decode(d)


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

    s = end(priority=prio)
    s.publish(terrain(), 0.0)
    s.want_holdings = False  # the peer's holdings are known (empty): tiles may go
    order = []
    t = 0.0
    while len(order) < 9:
        for d in s.poll(t):
            p = sp.decode(d)
            if isinstance(p, sp.Tile):
                order.append(p.tile)
        t = s.next_deadline_s() or t + 0.1
    assert order == want


def test_bad_and_foreign_packets_are_counted_and_dropped() -> None:
    a, b = end(0), end(1)
    b.publish(terrain(1), 0.0)
    pump(a, b, 0.0, 5.0)
    h = a.replica_hash()
    good = sp.encode(sp.Tile(1, 0, 999, 1, 0, 10**6, *(lambda x: (sp.blob_digest(x), x))(b"not a codec container")))
    junk = [b"", b"\xa5", bytes(300), good, sp.encode(sp.Tile(2, 0, 5, 2, 0, 1, sp.blob_digest(b"x"), b"x")),
            sp.encode(sp.Digest(1, 9, 1, 0, 1, 0, 0, 0, 0, bytes(8), (), ())),
            sp.encode(sp.Holdings(1, 0, 1, 1, 0, 7, ((0, 1, 2),)))]
    for d in junk:
        a.receive(d, 6.0)
    assert a.replica_hash() == h
    assert a.stats.bad_packets == 5 and a.stats.foreign_packets == 2


def test_two_ends_converge_and_a_checkpoint_restores_the_same_replica() -> None:
    a, b = end(0), end(1)
    a.publish(terrain(0), 0.0)
    b.publish(np.where(np.arange(SHAPE[1]) < 30, terrain(1), np.nan).astype(np.float32), 0.0)
    pump(a, b, 0.0, 20.0, drop=0.2, seed=3)
    assert a.replica_hash() == b.replica_hash()
    assert np.array_equal(a.replica_map(1), b.replica_map(1), equal_nan=True)
    assert np.isfinite(a.fused_map()).sum() == SHAPE[0] * SHAPE[1]
    r = MapSync.restore(a.checkpoint(), SyncConfig(), CELL, WHEEL, boot=1)
    assert r.replica_hash() == a.replica_hash() and r.counter > a.counter
    with pytest.raises(ValueError, match="not a usable map-sync checkpoint"):
        MapSync.restore(b"{not json", SyncConfig(), CELL, WHEEL, boot=1)
    with pytest.raises(ValueError, match="not a usable map-sync checkpoint"):
        MapSync.restore(a.checkpoint().replace(b'"v": 1', b'"v": 9'), SyncConfig(), CELL, WHEEL, boot=1)


def test_forged_packets_with_valid_checksums_never_raise() -> None:
    """Corruptions that pass every checksum (container CRC, tile digest, packet CRC recomputed)
    are counted or ignored, never raised, and never change a tile into one of another shape."""
    import struct
    import zlib

    a, b = end(0), end(1)
    b.publish(terrain(2), 0.0)
    b.want_holdings = False
    pkts = [d for d in b.poll(0.0) + b.poll(1.0)]
    tiles = [sp.decode(d) for d in pkts if isinstance(sp.decode(d), sp.Tile)]
    assert tiles
    rng = np.random.default_rng(7)
    for i in range(300):
        t = tiles[i % len(tiles)]
        assert isinstance(t, sp.Tile)
        blob = bytearray(t.blob)
        for _ in range(int(rng.integers(1, 4))):
            blob[int(rng.integers(0, len(blob) - 4))] = int(rng.integers(0, 256))
        blob[-4:] = struct.pack("<I", zlib.crc32(bytes(blob[:-4])))  # the container's own CRC
        forged = sp.Tile(1, 0, 1000 + i, 1, int(rng.integers(0, 12)), 5000 + i, sp.blob_digest(bytes(blob)),
                         bytes(blob))
        a.receive(sp.encode(forged), 2.0)
        d = sp.encode(sp.Digest(1, 0, 2000 + i, 0, i, 0, 0, int(rng.integers(0, 32)), int(rng.integers(0, 999)),
                                rng.bytes(8), ((int(rng.integers(0, 99)), i),), (int(rng.integers(0, 99)),)))
        a.receive(d, 2.0)
        h = sp.encode(sp.Holdings(1, 0, 3000 + i, 0, int(rng.integers(0, 2)), 1,
                                  ((int(rng.integers(0, 99)), i, 0),)))
        a.receive(h, 2.0)
    for t_id, rec in a.held.items():
        ys, xs = a.tile_slice(t_id)
        assert rec.z.shape == (ys.stop - ys.start, xs.stop - xs.start)
    assert a.stats.bad_packets > 0
    assert all(t < 9 for t in a.wants | set(a.belief))
