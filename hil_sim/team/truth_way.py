"""Where a team mission's approach met unknown ground, judged on the TRUTH (docs/team.md,
"Running a team mission": the team section's ``truth_way``).

For each target, :func:`truth_way_unknown` takes the flight planner's shortest way on the true
ground (:func:`fsw.core.team.face_planner.plan_targets` at the exact lengths) and finds the first
node along it whose footprint the mission's final map does not wholly know: why an approach
stopped, in terms of the ground (the verdict itself is :mod:`hil_sim.team.team_eval`'s).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import MapGrid
from fsw.core.team.climber_ground import ClimberConfig
from fsw.core.team.face_planner import plan_targets
from fsw.core.team.tether import TetherConfig
from hil_sim.world.world import World

F64 = NDArray[np.float64]


def truth_way_unknown(world: World, grid: MapGrid, map_z: NDArray[np.floating], anchors: F64,
                      tcfg: TetherConfig, ccfg: ClimberConfig,
                      to_map: Callable[[F64], F64]) -> list[dict[str, Any] | None]:
    """Per target, the flight planner's shortest way from the Cliff-bot's start on the TRUE
    ground (:func:`fsw.core.team.face_planner.plan_targets` at the exact lengths, world frame;
    None where it finds none) and where along it the mission's map ``map_z`` (its frame:
    ``to_map`` takes world points to it) first lacks a cell within the footprint's radius of a
    node: ``{"nodes", "first_unknown" (the node's index, None: every node's ground known),
    "unknown_cells", "footprint_cells", "slope_deg" (the true ground's median slope there)}``."""
    assert world.team is not None
    z = np.asarray(world.ground_on_grid(grid), np.float64)
    start = np.asarray(world.team.cliffbot_start_xy, float)
    plan = plan_targets(z, grid, np.asarray(anchors, float), start, world.team.targets_xyz[:, :2], tcfg, ccfg)
    gy, gx = np.gradient(z, grid.cell)
    slope = np.degrees(np.arctan(np.hypot(gx, gy)))
    known = np.isfinite(np.asarray(map_z, np.float64))
    X, Y = grid.centers()
    out: list[dict[str, Any] | None] = []
    for path in plan.paths:
        if path is None:
            out.append(None)
            continue
        way: dict[str, Any] = {"nodes": len(path), "first_unknown": None}
        for i, (w, m) in enumerate(zip(path, to_map(np.asarray(path, float)), strict=True)):
            foot = np.hypot(X - m[0], Y - m[1]) <= ccfg.footprint_m
            unknown = int(np.count_nonzero(foot & ~known))
            if unknown:
                on_truth = np.hypot(X - w[0], Y - w[1]) <= ccfg.footprint_m
                way.update(first_unknown=i, unknown_cells=unknown, footprint_cells=int(foot.sum()),
                           slope_deg=round(float(np.nanmedian(slope[on_truth])), 1))
                break
        out.append(way)
    return out
