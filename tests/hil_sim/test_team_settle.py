"""The bench's forward kinematics on a rough near-vertical face (``fsw.core.team.tether_settle.settle``):
where Gauss-Newton cycles, the search finds where both tethers are taut, so the bench does not
count a slack tether that is not there."""

from __future__ import annotations

import numpy as np
import pytest

from fsw.core.geometry import MapGrid
from fsw.core.team import tether, tether_settle
from hil_sim.world import load_scenario


def test_settle_finds_the_taut_pose_where_gauss_newton_cycles(monkeypatch: pytest.MonkeyPatch) -> None:
    world = load_scenario("cliff-team", 24)  # an 81 deg face; a pose its mission passed
    assert world.team is not None
    grid = MapGrid.from_config(world.map_grid)
    z = world.ground_on_grid(grid)
    cfg = tether.TetherConfig()
    anchors = tether.anchor_points(z, grid, world.team.anchors_xy, cfg)
    lengths, guess = (2.195, 3.005), np.array([1.811, -1.171])
    got = tether_settle.settle(z, grid, anchors, lengths, guess, cfg)
    assert got is not None
    xy, st = got
    assert np.max(np.abs(np.asarray(st.lengths_m) - lengths)) < 10 * 1e-3 + 0.25 * grid.cell
    assert np.hypot(*(xy - guess)) < 0.1 and min(st.statics.tensions_n) > cfg.t_min_n
    monkeypatch.setattr(tether_settle, "_settle_search", lambda *a, **k: None)
    assert tether_settle.settle(z, grid, anchors, lengths, guess, cfg) is None  # Gauss-Newton alone fails here
