"""The ``lab`` scenario: the paper's indoor test bed (docs/algorithm.md §7, paper Figure 6).

A flat plateau at ``z = 0`` where the rover drives (start at the origin heading ``+x``); an
irregular step edge about ``drop_m`` high running along ``+x`` near ``y = edge_y_m`` (a random
wiggle plus a bay cut into the plateau, so the edge is neither straight nor convex); below it
a recessed sandpit (``x`` from ``pit_x_min_m`` to ``pit_x_max_m``, ``y`` from ``pit_y_min_m``
to the edge) with rippled sand, a few pebbles, three rock piles and, in its left (low ``x``)
region, uniform sand with no texture at all where stereo cannot match (``[texture]
textureless_regions``; the paper: "the left region of the sandpit yields poor data (due to
lack of stereo correspondence)": its Method 3 chases it, Method 5 loses interest,
docs/algorithm.md §3.4, §7).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from hil_sim.world.build import dilate, edge_curve, finish_world, textureless_mask, truth_grid
from hil_sim.world.config import LabConfig, ScenarioConfig
from hil_sim.world.mars import place_viking_rocks
from hil_sim.world.noise import fractal_noise
from hil_sim.world.rocks import stamp_rocks
from hil_sim.world.world import World

F32 = NDArray[np.float32]


def build_lab(cfg: ScenarioConfig, seed: int) -> World:
    lab = cfg.lab or LabConfig()
    rng = np.random.default_rng([seed, 1])
    grid = truth_grid(cfg)
    gx, gy = grid.mesh()
    xs = grid.xs
    # The edge line y_e(x): wiggle plus a bay into the plateau (toward +y).
    y_edge = edge_curve(xs, rng, lab.edge_y_m, lab.edge_wiggle_m, lab.edge_wavelength_m)
    y_edge += lab.bay_depth_m * np.exp(-(((xs - lab.bay_x_m) / (0.5 * lab.bay_width_m)) ** 4))
    # Distance into the pit from its nearest wall; the walls are steep ramps face_width_m wide.
    d_wall = np.minimum.reduce([
        gx - lab.pit_x_min_m, lab.pit_x_max_m - gx, gy - lab.pit_y_min_m,
        y_edge.astype(np.float32)[None, :] - gy,
    ])
    sand = fractal_noise(gx.shape, grid.cell_m, rng, beta=2.5, min_wavelength_m=0.04,
                         max_wavelength_m=1.5)
    floor = np.float32(-lab.drop_m) + np.float32(lab.sand_relief_m) * sand
    ramp = -lab.drop_m * np.maximum(d_wall, 0.0) / lab.face_width_m  # the face, steep
    ground = np.where(d_wall > 0, np.maximum(floor, ramp), 0.0).astype(np.float32)
    deep = d_wall > lab.face_width_m + 0.05  # pit floor clear of the walls
    textureless = deep & textureless_mask(grid, cfg.texture.textureless_regions, seed)
    rock_id = np.full(ground.shape, -1, np.int32)
    # Pebbles on the sand (not on the textureless patch), then the three piles.
    pebbles = (deep & ~dilate(textureless, int(0.15 / grid.cell_m))).astype(np.float32)
    n_peb = place_viking_rocks(ground, grid.x0, grid.y0, grid.cell_m, 0.015, rng, 0.03, 0.12,
                               weight=pebbles, rock_id=rock_id)
    _piles(ground, grid, lab, rng, rock_id, n_peb)
    outside = ~(d_wall > 0)
    ground[outside] = 0.0  # the plateau and the lab floor stay exactly level
    rock_id[outside] = -1
    edge = _edge_polyline(xs, y_edge, lab)
    return finish_world(cfg, "lab", seed, grid, ground, rng, edge_xy=edge, plateau_z=0.0,
                        rock_id=rock_id, textureless=textureless, plateau_tol_m=0.005)


def _piles(ground: F32, grid, lab: LabConfig, rng: np.random.Generator,  # type: ignore[no-untyped-def]
           rock_id: NDArray[np.int32], first_id: int) -> None:
    """Each pile: a low mound of gravel with three layers of rocks stacked on it, scaled so
    its top stands ``height`` above the sand."""
    gx, gy = grid.mesh()
    for x, y, radius, height in lab.piles:
        r2 = ((gx - x) ** 2 + (gy - y) ** 2) / (radius * radius)
        layer = (0.35 * np.exp(-2.5 * r2) * (r2 < 1.5)).astype(np.float32)
        for level, (count, spread) in enumerate(((28, 0.95), (14, 0.6), (6, 0.3))):
            rr = radius * spread * np.sqrt(rng.random(count))
            th = rng.uniform(0, 2 * np.pi, count)
            d = rng.uniform(0.08, 0.26, count) * (1.0 - 0.15 * level)
            h = d * rng.uniform(0.4, 0.6, count)
            stamp_rocks(layer, grid.x0, grid.y0, grid.cell_m, x + rr * np.cos(th),
                        y + rr * np.sin(th), d, h, rng, rock_id=rock_id, first_id=first_id)
            first_id += count
        ground += layer * np.float32(height / max(float(layer.max()), 1e-6))

def _edge_polyline(xs: np.ndarray, y_edge: np.ndarray, lab: LabConfig) -> np.ndarray:
    """The top of the step, walked along +x (plateau on the left: safe_side_sign = +1)."""
    keep = (xs >= lab.pit_x_min_m) & (xs <= lab.pit_x_max_m)
    step = max(1, int(round(0.02 / float(xs[1] - xs[0]))))
    return np.column_stack([xs[keep][::step], y_edge[keep][::step]])
