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


@pytest.mark.parametrize(("before", "after", "at", "moved"), [
    # paid out past a step of the face: the body slides down it (a pose of held-out scene 55's mission)
    ((4.4881, 3.8226), (4.4954, 3.8346), (3.078, -1.428), -1.0),
    # hauled in below the step: the body is pulled up over it (the same mission's leg home)
    ((4.2974, 3.9102), (4.2854, 3.8994), (2.859, -1.574), 1.0),
])
def test_where_the_equilibrium_vanishes_at_a_step_the_body_slides_to_the_nearest_one(
        before: tuple[float, float], after: tuple[float, float], at: tuple[float, float], moved: float) -> None:
    """Lengths a centimetre on from a taut pose, past a fold of the statics: settle from the
    last pose finds no taut place, yet one exists 0.2 m down (or up) the face. The bench moves
    the body there (``cliffbot_rig.slide``), with both tethers taut, instead of counting slack."""
    from hil_sim.team.cliffbot_rig import slide

    world = load_scenario("cliff-team", 55)
    assert world.team is not None
    grid = MapGrid.from_config(world.map_grid)
    z = world.ground_on_grid(grid)
    cfg = tether.TetherConfig()
    anchors = tether.anchor_points(z, grid, world.team.anchors_xy, cfg)
    xy = np.array(at)
    assert tether_settle.settle(z, grid, anchors, before, xy, cfg) is not None  # it rested there
    assert tether_settle.settle(z, grid, anchors, after, xy, cfg) is None  # that equilibrium is gone
    got = slide(z, grid, anchors, after, xy, cfg)
    assert got is not None
    place, st = got
    assert np.max(np.abs(np.asarray(st.lengths_m) - after)) < 10 * 1e-3 + 0.25 * grid.cell
    assert 0.15 < np.hypot(*(place - xy)) < 0.3 and moved * (place[1] - xy[1]) > 0.15  # down, or up, the face
    assert cfg.t_min_n < min(st.statics.tensions_n) and max(st.statics.tensions_n) < cfg.t_max_n
    # 3 m more of both tethers: their taut place is 0.7 m down, a fall, not a slide: slack
    assert slide(z, grid, anchors, (before[0] + 3.0, before[1] + 3.0), xy, cfg) is None
