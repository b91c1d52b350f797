"""The truth's brute force under the winches' length tolerance (hil_sim.team.team_eval,
docs/team.md, "The planner": the truth's verdict): a target the tethers hold at the exact lengths but not
where the winches may stop is not reachable under the same tether limits."""

from __future__ import annotations

import pytest

from fsw.core.geometry import MapGrid
from fsw.core.team.climber_ground import ClimberConfig
from fsw.core.team.tether import TetherConfig, anchor_points
from fsw.sections import CliffbotMissionConfig
from hil_sim.team.team_eval import truth_verdict, winch_errors
from hil_sim.world import load_scenario

pytestmark = pytest.mark.slow


def test_a_target_held_at_the_exact_lengths_but_slack_within_the_winches_tolerance_is_slack() -> None:
    """Seed 13's third target: its tether A holds about 5.4 N against the 5 N floor at the
    exact lengths, and goes slack where a winch stops within its tolerance."""
    world = load_scenario("cliff-team", 13)
    assert world.team is not None
    grid = MapGrid.from_config(world.map_grid)
    t, c, m = TetherConfig(), ClimberConfig(), CliffbotMissionConfig()
    anchors = anchor_points(world.ground_on_grid(grid), grid, world.team.anchors_xy, t)
    exact = truth_verdict(world, grid, anchors, t, c)
    tol = truth_verdict(world, grid, anchors, t, c, winch_errors(m.length_tol_m, m.margin_sigmas))
    assert exact.reasons[2] == "" and tol.reasons[2] == "slack"
    # the tolerance only takes away: what it reaches, the exact lengths reach too, no shorter
    for a, b, la, lb in zip(exact.reasons, tol.reasons, exact.lengths_m, tol.lengths_m, strict=True):
        assert not b or b == a or not a
        if not b:
            assert not a and la <= lb


def test_the_truths_way_is_found_where_its_map_first_lacks_ground() -> None:
    """``truth_way_unknown``: on the true ground itself every node's ground is known; on it with
    a band of unknown cells across the way, the first node that reaches the band is named."""
    import numpy as np

    from hil_sim.team.truth_way import truth_way_unknown

    world = load_scenario("cliff-team", 3)
    assert world.team is not None
    grid = MapGrid.from_config(world.map_grid)
    t, c = TetherConfig(), ClimberConfig()
    z = world.ground_on_grid(grid)
    anchors = anchor_points(z, grid, world.team.anchors_xy, t)
    same = lambda xy: np.asarray(xy, float).reshape(-1, 2)  # noqa: E731
    known = truth_way_unknown(world, grid, z, anchors, t, c, same)
    k = next(i for i, w in enumerate(known) if w is not None)  # a target the planner reaches on the truth
    assert known[k]["first_unknown"] is None and known[k]["nodes"] >= 2
    y_end = float(world.team.targets_xyz[k, 1])
    y_start = float(world.team.cliffbot_start_xy[1])
    y_mid = 0.5 * (y_start + y_end)  # a band across the way, halfway down
    _, Y = grid.centers()
    holed = np.where(np.abs(Y - y_mid) < 0.05, np.nan, z)
    got = truth_way_unknown(world, grid, holed, anchors, t, c, same)[k]
    assert got is not None and 0 < got["first_unknown"] < got["nodes"] - 1
    assert 0 < got["unknown_cells"] < got["footprint_cells"] and 0.0 <= got["slope_deg"] <= 90.0
