"""``safer-hil bench planner``: the Cliff-bot planner's ground layers, timed (docs/algorithm.md §8).

On a cliff-team scene's true ground on the flight map grid (the map the planner and the
bench's team runs judge), times ``fsw.core.team.climber_ground.ground_layers`` (rocks, hazards,
known footprints, slope) and within it ``footprint_known`` (each cell's footprint, the
wheels' outline at the heading held there, gathered at that cell), against
:func:`footprint_known_whole_map`, the same definition as whole-map filters (a minimum filter
and an erosion over every cell of the map for each footprint), and says whether both give the
same cells. CPU time (process time) per
call: the median and best of ``--repeat`` runs after a warm-up.
"""

from __future__ import annotations

import argparse
from typing import Any

HELP = "the Cliff-bot planner's ground layers: CPU ms a call, footprint_known against whole-map filters"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", default="cliff-team", help="a cliff-team scenario (its true ground is timed)")
    p.add_argument("--seed", type=int, default=3, help="scenario seed")
    p.add_argument("--repeat", type=int, default=5, help="timed runs of each")


def footprint_known_whole_map(z_sensed: Any, grid: Any, cfg: Any, anchors: Any) -> Any:
    """``footprint_known``'s definition as whole-map filters: each footprint's minimum filter of
    the local slope and its erosion of the sensed cells over the whole map, kept on the cells
    that footprint is for (the reference the flight function must equal)."""
    import numpy as np
    from scipy import ndimage

    from fsw.core.team.climber_ground import FOOT_COS_LEVELS, _cos_level, footprint_box, map_yaw_bins, slope_levels

    zs = np.asarray(z_sensed, np.float64)
    sensed = np.isfinite(zs)
    hl, hw = cfg.body_half_length_m / grid.cell, cfg.body_half_width_m / grid.cell
    local, level, dbin = slope_levels(zs, grid.cell)
    ybin = map_yaw_bins(grid, anchors)
    level_known = np.zeros(sensed.shape, bool)
    for y in np.unique(ybin):
        eroded = ndimage.binary_erosion(sensed, structure=footprint_box(hl, hw, FOOT_COS_LEVELS, 0, int(y)),
                                        border_value=0)
        level_known |= (ybin == y) & eroded
    out = sensed & (level >= FOOT_COS_LEVELS) & level_known
    tilted = sensed & (level < FOOT_COS_LEVELS)
    for lv, b, y in {(int(a), int(d), int(h)) for a, d, h in zip(level[tilted], dbin[tilted], ybin[tilted],
                                                                   strict=True)}:
        foot = footprint_box(hl, hw, lv, b, y)
        least = ndimage.minimum_filter(local, footprint=foot, mode="constant", cval=np.inf)
        fits = _cos_level(np.where(np.isfinite(least), least, 0.0)) <= lv
        out |= tilted & (level == lv) & (dbin == b) & (ybin == y) & np.where(
            fits, ndimage.binary_erosion(sensed, structure=foot, border_value=0), level_known)
    return out


def _cpu_ms(fn: Any, repeat: int, warm: bool = True) -> tuple[float, float, Any]:
    """Median and best CPU ms of ``repeat`` calls, after a warm-up with ``warm`` (the flight
    functions fill their footprint caches on the first call); the last result."""
    import statistics
    import time

    got = fn() if warm else None
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        got = fn()
        times.append((time.process_time() - t0) * 1e3)
    return statistics.median(times), min(times), got


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from fsw.core.geometry import MapGrid
    from fsw.core.team.climber_ground import ClimberConfig, footprint_known, ground_layers
    from fsw.core.team.tether import TetherConfig, anchor_points
    from fsw.framework.params import ConfigError
    from hil_sim.world import load_scenario
    from hil_sim.world.config import ScenarioError

    if args.repeat < 1:
        print("safer-hil: error: need --repeat >= 1")
        return 2
    try:
        world = load_scenario(args.scenario, args.seed)
    except (ScenarioError, ConfigError, ValueError) as exc:
        print(f"safer-hil: error: scenario {args.scenario!r}: {exc}")
        return 2
    if world.team is None:
        print(f"safer-hil: error: scenario {args.scenario!r} has no team (use a cliff-team scenario)")
        return 2
    grid = MapGrid.from_config(world.map_grid)
    z = np.asarray(world.ground_on_grid(grid), np.float64)
    ccfg = ClimberConfig()
    anchors = anchor_points(z, grid, world.team.anchors_xy, TetherConfig())
    print(f"{args.scenario} seed {args.seed}: true ground on the flight map grid, {grid.ny}x{grid.nx} cells of "
          f"{grid.cell:g} m ({int(np.isfinite(z).sum())} known), footprint "
          f"{2 * ccfg.body_half_length_m:g} x {2 * ccfg.body_half_width_m:g} m; "
          f"CPU ms a call, median (best) of {args.repeat}")
    med, best, _ = _cpu_ms(lambda: ground_layers(z, grid, ccfg, anchors=anchors), args.repeat)
    print(f"  ground_layers (flight)                 {med:8.1f} ({best:8.1f})")
    med, best, flight = _cpu_ms(lambda: footprint_known(z, grid, ccfg, anchors), args.repeat)
    print(f"  footprint_known (flight)               {med:8.1f} ({best:8.1f})")
    # (the reference caches nothing: no warm-up, its 10 s a call are not spent twice)
    ref_med, ref_best, ref = _cpu_ms(lambda: footprint_known_whole_map(z, grid, ccfg, anchors), args.repeat,
                                     warm=False)
    print(f"  footprint_known by whole-map filters   {ref_med:8.1f} ({ref_best:8.1f})")
    same = bool(np.array_equal(flight, ref))
    print(f"  same cells: {'yes' if same else 'NO'} ({int(flight.sum())} known footprints); "
          f"the flight function {ref_med / max(med, 1e-9):.1f}x faster")
    return 0 if same else 1
