"""Map checkpoints (issue 4, item 5): atomic write, checksum, fallback to the previous one."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fsw.core.geometry import MapGrid
from fsw.core.map.checkpoint import CheckpointConfig, CheckpointError, decode, encode
from fsw.core.map.elevation_map import ElevationMap, FusionConfig
from fsw.drivers.map_store import MapStore

GRID = MapGrid(-0.5, -6.5, 0.03, 64, 48)


def filled_map(seed: int = 0) -> ElevationMap:
    rng = np.random.default_rng(seed)
    m = ElevationMap(GRID, FusionConfig(n_max=7))
    pts = np.column_stack([rng.uniform(-0.5, 1.4, 3000), rng.uniform(-6.5, -5.1, 3000),
                           rng.normal(0, 0.1, 3000)])
    m.merge(pts, var_z=np.full(3000, 1e-4), p_visible=np.full(GRID.shape, 0.7))
    return m


def assert_same(a: ElevationMap, b: ElevationMap) -> None:
    assert a.grid == b.grid and a.n_max == b.n_max
    for name in ("z", "var", "n", "interest", "misses", "outliers", "var_common"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def test_round_trip_is_exact() -> None:
    m = filled_map()
    back, meta = decode(encode(m, 42, 12.5))
    assert_same(m, back)
    assert (meta.seq, meta.time_s) == (42, 12.5)
    assert np.isnan(back.z).any() and np.isinf(back.var).any()  # unknown cells survive


@settings(max_examples=40, deadline=None)
@given(st.data())
def test_any_truncation_or_bit_flip_is_detected(data) -> None:
    """A truncated or corrupted checkpoint raises CheckpointError, never garbage or a crash."""
    blob = encode(filled_map(1), 1, 0.0)
    if data.draw(st.booleans()):
        cut = data.draw(st.integers(0, len(blob) - 1))
        bad = blob[:cut]
    else:
        pos = data.draw(st.integers(0, len(blob) - 1))
        bit = data.draw(st.integers(0, 7))
        bad = bytearray(blob)
        bad[pos] ^= 1 << bit
        bad = bytes(bad)
    with pytest.raises(CheckpointError):
        decode(bad)


def test_store_falls_back_to_previous_on_corruption(tmp_path: Path) -> None:
    """Issue 4, item 5: newest truncated -> previous used, and the reason is reported."""
    store = MapStore(CheckpointConfig(directory=str(tmp_path), keep=3))
    maps = [filled_map(s) for s in range(4)]
    for i, m in enumerate(maps):
        store.save(m, i, float(i))
    names = [p.name for p in store.paths()]
    assert names == ["map_0000000001.ckpt", "map_0000000002.ckpt", "map_0000000003.ckpt"]
    assert not list(tmp_path.glob("*.tmp"))  # no temporary left behind
    newest = store.paths()[-1]
    newest.write_bytes(newest.read_bytes()[:-100])  # power cut mid-write on a bad device
    res = store.load_latest()
    assert res.meta is not None and res.meta.seq == 2
    assert res.emap is not None
    assert_same(res.emap, maps[2])
    assert len(res.skipped) == 1 and "checksum" in res.skipped[0][1]
    # and a garbage file under a checkpoint name
    store.paths()[-2].write_bytes(b"not a checkpoint at all")
    res = store.load_latest()
    assert res.meta is not None and res.meta.seq == 1 and len(res.skipped) == 2


def test_store_with_nothing_good_loads_nothing(tmp_path: Path) -> None:
    store = MapStore(CheckpointConfig(directory=str(tmp_path / "none")))
    res = store.load_latest()
    assert res.emap is None and res.skipped == []
    (tmp_path / "none").mkdir()
    (tmp_path / "none" / "map_0000000005.ckpt").write_bytes(b"")
    res = store.load_latest()
    assert res.emap is None and "truncated" in res.skipped[0][1]


def test_failed_write_leaves_previous_intact(tmp_path: Path, monkeypatch) -> None:
    """Atomicity: if the write fails before the rename, the old checkpoint is untouched."""
    store = MapStore(CheckpointConfig(directory=str(tmp_path)))
    store.save(filled_map(0), 1, 0.0)

    def boom(fd: int) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", boom)
    with pytest.raises(OSError):
        store.save(filled_map(1), 2, 1.0)
    monkeypatch.undo()
    assert [p.name for p in store.paths()] == ["map_0000000001.ckpt"]
    assert not list(tmp_path.glob(".map_*"))
    res = store.load_latest()
    assert res.meta is not None and res.meta.seq == 1
