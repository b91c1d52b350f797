"""The map store's background writer (fsw/drivers/map_store.py; issue 15: no fsync on the
executive's thread in real time)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fsw.core.geometry import MapGrid
from fsw.core.map.checkpoint import CheckpointConfig
from fsw.core.map.elevation_map import ElevationMap
from fsw.drivers.map_store import MapStore


def _map() -> ElevationMap:
    m = ElevationMap(MapGrid(x0=0.0, y0=0.0, cell=0.1, nx=8, ny=6))
    m.merge(np.array([[0.35, 0.25, 0.1], [0.55, 0.45, 0.2]]), cov=np.tile(np.eye(3) * 1e-4, (2, 1, 1)))
    return m


def test_background_writes_equal_inline_writes(tmp_path: Path) -> None:
    inline = MapStore(CheckpointConfig(directory=str(tmp_path / "a"), keep=2))
    bg = MapStore(CheckpointConfig(directory=str(tmp_path / "b"), keep=2), background=True)
    try:
        for k in range(4):
            inline.save_next(_map(), float(k))
            bg.save_next(_map(), float(k))
            assert bg.seq == inline.seq == k + 1 and bg.last_size == inline.last_size > 0
        bg.flush()
        assert [p.name for p in bg.paths()] == [p.name for p in inline.paths()] == \
            ["map_0000000003.ckpt", "map_0000000004.ckpt"]
        assert all(a.read_bytes() == b.read_bytes() for a, b in zip(inline.paths(), bg.paths(), strict=True))
        assert bg.load_latest().meta is not None and bg.take_error() is None
    finally:
        bg.close()


def test_a_failed_background_write_is_reported_once(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    bg = MapStore(CheckpointConfig(directory=str(blocker / "sub")), background=True)
    try:
        bg.save_next(_map(), 1.0)
        bg.flush()
        err = bg.take_error()
        assert err is not None and "map_0000000001.ckpt" in err
        assert bg.take_error() is None
    finally:
        bg.close()
