"""The cliff-team scenario (docs/world.md): seeded, validated, and its targets judged on the truth."""

from __future__ import annotations

import numpy as np
import pytest

from fsw.core.geometry import MapGrid
from fsw.core.team.climber_ground import ClimberConfig
from fsw.core.team.face_planner import plan_targets
from fsw.core.team.tether import TetherConfig, anchor_points
from fsw.framework.params import ConfigError
from hil_sim.world import ScenarioError, load_scenario


@pytest.mark.slow
def test_cliff_team_world_has_the_team() -> None:
    w = load_scenario("cliff-team?face_slope_deg=75&drop_m=5", 3)
    assert w.team is not None and w.drawn == {"face_slope_deg": 75.0, "drop_m": 5.0}
    assert w.team.anchors_xy.shape == (2, 2) and 2 <= len(w.team.targets_xyz) <= 4
    # Anchors and the start stand on the plateau; targets on the face, below the lip and
    # above the floor.
    assert w.on_plateau(w.team.anchors_xy[:, 0], w.team.anchors_xy[:, 1]).all()
    assert w.on_plateau(*w.team.cliffbot_start_xy)
    z = w.team.targets_xyz[:, 2]
    assert ((z < -0.15 * 5.0) & (z > -0.95 * 5.0)).all()
    again = load_scenario("cliff-team?face_slope_deg=75&drop_m=5", 3)
    assert again is w or np.array_equal(again.ground, w.ground)


@pytest.mark.slow
def test_cliff_team_draws_slope_and_drop_from_the_seed() -> None:
    drawn = [load_scenario("cliff-team", s).drawn for s in (0, 1)]
    for d in drawn:
        assert 55.0 <= d["face_slope_deg"] <= 85.0 and 2.0 <= d["drop_m"] <= 8.0
    assert drawn[0] != drawn[1]


@pytest.mark.parametrize("spec", ["cliff-team?face_slope_deg=95", "cliff-team?targets=9",
                                  "cliff-team?nonsense=1", "cliff-team?rock_d_min_m=2&rock_d_max_m=1"])
def test_cliff_team_bad_overrides_are_refused(spec: str) -> None:
    with pytest.raises((ScenarioError, ConfigError, ValueError)):
        load_scenario(spec, 0)


@pytest.mark.slow
def test_brute_force_planner_on_the_truth_judges_every_target() -> None:
    w = load_scenario("cliff-team?face_slope_deg=70&drop_m=4", 2)
    grid = MapGrid.from_config(w.map_grid)
    z = w.ground_on_grid(grid)
    tc, cc = TetherConfig(), ClimberConfig()
    p = plan_targets(z, grid, anchor_points(z, grid, w.team.anchors_xy, tc), w.team.cliffbot_start_xy,
                     w.team.targets_xyz[:, :2], tc, cc)
    assert p.start_reason == ""
    assert len(p.reasons) == len(w.team.targets_xyz)
    for path, reason in zip(p.paths, p.reasons, strict=True):
        assert (path is None) == (reason != "")
    assert any(r == "" for r in p.reasons)
