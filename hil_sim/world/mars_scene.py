"""The ``mars`` scenario: Viking-lander rock statistics on gently rolling ground.

Below the rover's level plateau (``y`` above an irregular edge near ``edge_y_m``) a low scarp
(``scarp_drop_m``, 0 for none) leads down to rolling ground (``relief_m``) strewn with rocks
drawn from the Viking size-frequency model with coverage ``k`` (``mars.py``; docs/algorithm.md,
"Mars terrain statistics"). The scarp gives the edge-following mission something to follow;
with ``scarp_drop_m = 0`` the world has no edge (``edge_xy`` is empty).
"""

from __future__ import annotations

import math

import numpy as np

from hil_sim.world.build import edge_curve, finish_world, truth_grid
from hil_sim.world.config import MarsConfig, ScenarioConfig
from hil_sim.world.mars import place_viking_rocks
from hil_sim.world.noise import fractal_noise
from hil_sim.world.world import World

SCARP_SLOPE_DEG = 70.0


def build_mars(cfg: ScenarioConfig, seed: int) -> World:
    mc = cfg.mars or MarsConfig()
    rng = np.random.default_rng([seed, 3])
    grid = truth_grid(cfg)
    gx, gy = grid.mesh()
    y_edge = edge_curve(grid.xs, rng, mc.edge_y_m, mc.edge_wiggle_m, mc.edge_wavelength_m)
    d = y_edge.astype(np.float32)[None, :] - gy
    relief = fractal_noise(gx.shape, grid.cell_m, rng, beta=3.0,
                           min_wavelength_m=max(4 * grid.cell_m, 0.2),
                           max_wavelength_m=mc.relief_wavelength_m)
    low = np.float32(-mc.scarp_drop_m) + np.float32(mc.relief_m) * relief
    if mc.scarp_drop_m > 0:
        scarp = -math.tan(math.radians(SCARP_SLOPE_DEG)) * d
        below = np.minimum(np.maximum(scarp, low), 0.0)
    else:
        below = low
    ground = np.where(d > 0, below, 0.0).astype(np.float32)
    cb = cfg.cliffbot
    clear = np.hypot(gx - cb.x_m, gy - cb.y_m) < 0.6 * math.hypot(cb.length_m, cb.width_m) + 0.2
    run = mc.scarp_drop_m / math.tan(math.radians(SCARP_SLOPE_DEG))
    weight = ((d > run) & ~clear).astype(np.float32)
    rock_id = np.full(ground.shape, -1, np.int32)
    if mc.k > 0:
        place_viking_rocks(ground, grid.x0, grid.y0, grid.cell_m, mc.k, rng, mc.d_min_m,
                           mc.d_max_m, weight=weight, rock_id=rock_id)
    on_top = d <= 0
    ground[on_top] = 0.0
    rock_id[on_top] = -1
    if mc.scarp_drop_m > 0:
        edge = np.column_stack([grid.xs, y_edge])[:: max(1, round(0.02 / grid.cell_m))]
    else:
        edge = np.zeros((0, 2))
    return finish_world(cfg, "mars", seed, grid, ground, rng, edge_xy=edge, plateau_z=0.0,
                        rock_id=rock_id, plateau_tol_m=0.005)
