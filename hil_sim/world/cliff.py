"""The ``cliff`` scenario: a natural cliff like the paper's field test (docs/algorithm.md §7,
paper Figure 9).

A level plateau (``z = 0``) where the rover drives ends at an irregular, non-convex edge
line near ``y = edge_y_m``; a rough rock face about ``face_slope_deg`` (75 degrees) steep
drops ``drop_m``; below, the ground slopes gently away and carries a rock jumble: rocks
drawn from the Viking size-frequency model (``mars.py``) with a coverage that is highest at
the cliff foot (``jumble_k``) and decays with distance (``jumble_decay_m``) to
``background_k``. Flats of fine silt (``[texture] textureless_regions``, kept to the ground
past the cliff foot and free of rocks) give stereo no correspondence, as the regions that
made the paper's field result differ between Methods 4 and 5 (docs/algorithm.md §3.4, §7).
"""

from __future__ import annotations

import math

import numpy as np

from hil_sim.world.build import dilate, edge_curve, finish_world, textureless_mask, truth_grid
from hil_sim.world.config import CliffConfig, ScenarioConfig
from hil_sim.world.mars import place_viking_rocks
from hil_sim.world.noise import fractal_noise
from hil_sim.world.world import World


def build_cliff(cfg: ScenarioConfig, seed: int) -> World:
    cl = cfg.cliff or CliffConfig()
    rng = np.random.default_rng([seed, 2])
    grid = truth_grid(cfg)
    gx, gy = grid.mesh()
    y_edge = edge_curve(grid.xs, rng, cl.edge_y_m, cl.edge_wiggle_m, cl.edge_wavelength_m)
    d = y_edge.astype(np.float32)[None, :] - gy           # horizontal distance past the edge
    tan_face = math.tan(math.radians(cl.face_slope_deg))
    run = cl.drop_m / tan_face                            # horizontal extent of the face
    rough = fractal_noise(gx.shape, grid.cell_m, rng, beta=2.2, min_wavelength_m=0.12,
                          max_wavelength_m=1.0)
    face = -tan_face * (d + np.float32(cl.face_roughness_m) * rough)
    relief = fractal_noise(gx.shape, grid.cell_m, rng, beta=2.8, min_wavelength_m=0.05,
                           max_wavelength_m=3.0)
    floor = (-cl.drop_m - math.tan(math.radians(cl.floor_slope_deg)) * np.maximum(d - run, 0.0)
             + cl.floor_relief_m * relief)
    ground = np.where(d > 0, np.minimum(np.maximum(face, floor), 0.0), 0.0).astype(np.float32)
    # The rock jumble: Viking rocks, densest at the cliff foot; none on the plateau or under
    # the Cliff-bot.
    past_foot = np.maximum(d - run, 0.0)
    local_k = cl.background_k + cl.jumble_k * np.exp(-past_foot / cl.jumble_decay_m)
    local_k = np.where(d > 0.5 * run, local_k, 0.0)
    cb = cfg.cliffbot
    clear = np.hypot(gx - cb.x_m, gy - cb.y_m) < 0.6 * math.hypot(cb.length_m, cb.width_m) + 0.2
    silt = (d > run + 0.1) & textureless_mask(grid, cfg.texture.textureless_regions, seed)
    local_k = np.where(clear | dilate(silt, int(0.15 / grid.cell_m)), 0.0, local_k).astype(np.float32)
    k_max = float(local_k.max())
    rock_id = np.full(ground.shape, -1, np.int32)
    if k_max > 0:
        place_viking_rocks(ground, grid.x0, grid.y0, grid.cell_m, min(k_max, 0.5), rng,
                           cl.d_min_m, cl.d_max_m, weight=(local_k / k_max).astype(np.float32),
                           rock_id=rock_id)
    on_top = d <= 0
    ground[on_top] = 0.0  # the plateau stays level
    rock_id[on_top] = -1
    edge = np.column_stack([grid.xs, y_edge])[:: max(1, round(0.02 / grid.cell_m))]
    return finish_world(cfg, "cliff", seed, grid, ground, rng, edge_xy=edge, plateau_z=0.0,
                        rock_id=rock_id, textureless=silt, plateau_tol_m=0.005)
