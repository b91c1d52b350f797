"""The ``terrain`` scenario family: seeded sloped, rocky ground below an irregular cliff edge,
for tests and experiments on ground nobody tuned the flight software to (issue 13 item 5).

``terrain?slope_deg=8&seed=3`` and the other keys of ``[terrain]`` (config/scenarios/terrain.toml,
docs/world.md) choose a member of the family; every choice left at its "draw" value (-1 or 0)
is drawn from the seed, so ``--seed`` alone gives a new terrain.

Construction, all on the 1 cm truth grid:

1. The edge: a smooth random line ``y(x)`` (``edge_wiggle_m`` std, ``edge_wavelength_m``)
   shifted so that its closest approach to the rover's wheels at the start (the footprint's
   side, ``FOOTPRINT_HALF_WIDTH_M`` right of the start), within ``+-1 m`` along ``x``, is
   ``edge_distance_m`` (drawn uniformly in 0.3..2 m by default). The plateau (where the rover
   starts) is the side at larger ``y``; a face of ``face_slope_deg`` drops ``drop_m``.
2. Ground: fractal rolling relief (``relief_m``) on both sides, then Viking-model rocks
   (docs/algorithm.md, "Mars terrain statistics"; Golombek and Rapp 1997, ``mars.py``): coverage
   ``k`` below the edge (diameters ``d_min_m``..``d_max_m``) and ``plateau_k`` on the plateau
   with diameters up to ``plateau_d_max_m`` (smaller than a wheel: drivable rubble).
3. Regional slope: the whole world is tilted by ``slope_deg`` (-1: drawn in 0..12 deg)
   toward ``slope_azimuth_deg`` (downhill direction, deg counter-clockwise from +x; drawn by
   default), so the rover
   starts rolled and pitched; heights are then shifted so the ground at the start is 0.
4. ``textureless_count`` irregular patches (semi-axes 0.4..1.2 m) of one albedo below the edge,
   free of rocks, where stereo finds no match (docs/algorithm.md §3.4).

``World.plateau`` is the whole safe side of the true edge (rocks on it included), so an edge
violation is a wheel past the edge, not a wheel on a rock or downhill on the slope.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from fsw.core.geometry import MapGridConfig
from hil_sim.world.build import dilate, edge_curve, finish_world, textureless_mask, truth_grid
from hil_sim.world.config import ScenarioConfig, ScenarioError, TerrainConfig
from hil_sim.world.mars import place_viking_rocks
from hil_sim.world.noise import fractal_noise
from hil_sim.world.world import World

EDGE_DISTANCE_RANGE_M = (0.3, 2.0)
SLOPE_MAX_DEG = 12.0
FOOTPRINT_HALF_WIDTH_M = 0.36  # config/fsw.toml [rover]: track_m / 2 + the 0.12 m wheel patch / 2
FOOTPRINT_HALF_LENGTH_M = 0.45  # config/fsw.toml [rover]: length_m / 2 (the bumper)
MAP_START_INSET_M = 1.0  # a map grid moved with a turned edge keeps the start this far inside
EDGE_DISTANCE_MIN_M = 0.15  # the least edge distance that may be asked for (a close edge)
PATCH_AXES_M = (0.4, 1.2)


def build_terrain(cfg: ScenarioConfig, seed: int) -> World:
    tc = cfg.terrain or TerrainConfig()
    rng = np.random.default_rng([seed, 13])
    draws = np.random.default_rng([seed, 13, 1])  # the drawn parameters: their own stream
    distance = tc.edge_distance_m or float(draws.uniform(*EDGE_DISTANCE_RANGE_M))
    if not EDGE_DISTANCE_MIN_M <= distance <= EDGE_DISTANCE_RANGE_M[1]:
        raise ScenarioError(
            f"terrain: edge_distance_m must be 0 (drawn) or in {EDGE_DISTANCE_MIN_M}..2, got {distance}")
    azimuth = tc.slope_azimuth_deg if tc.slope_azimuth_deg >= 0 else float(draws.uniform(0, 360))
    slope_deg = tc.slope_deg if tc.slope_deg >= 0 else float(draws.uniform(0.0, SLOPE_MAX_DEG))
    rs, cb = cfg.rover_start, cfg.cliffbot
    turn = math.radians(tc.edge_bearing_deg + 90.0 + rs.yaw_deg)  # see below
    if turn:  # the Cliff-bot below the edge wherever the edge is
        bx, by = _turned(np.array(cb.x_m), np.array(cb.y_m), rs.x_m, rs.y_m, turn)
        cb = dataclasses.replace(cb, x_m=float(bx), y_m=float(by))
        cfg = dataclasses.replace(cfg, cliffbot=cb, map=_turned_map(cfg, turn))
    grid = truth_grid(cfg)
    gx, gy = grid.mesh()
    curve = edge_curve(grid.xs, rng, 0.0, tc.edge_wiggle_m, tc.edge_wavelength_m)
    near = np.abs(grid.xs - rs.x_m) <= 1.0
    if not near.any():
        raise ScenarioError("terrain: the rover start is off the world")
    # The edge is built in a frame turned by ``turn`` about the start (none for an edge on the
    # right), where it runs along +u with the drop toward -v; ``reach`` is the footprint's
    # extent toward it (its side, its bumper, a corner).
    rel = math.radians(tc.edge_bearing_deg)
    reach = round(FOOTPRINT_HALF_LENGTH_M * abs(math.cos(rel)) + FOOTPRINT_HALF_WIDTH_M * abs(math.sin(rel)), 6)
    y_edge = curve + (rs.y_m - reach - distance - float(curve[near].max()))
    if turn == 0.0:
        d = y_edge.astype(np.float32)[None, :] - gy  # horizontal distance past the edge (> 0: below)
    else:
        u, v = _turned(gx, gy, rs.x_m, rs.y_m, -turn)
        d = (np.interp(u, grid.xs, y_edge) - v).astype(np.float32)
    tan_face = math.tan(math.radians(tc.face_slope_deg))
    run = tc.drop_m / tan_face
    relief = fractal_noise(gx.shape, grid.cell_m, rng, beta=3.0,
                           min_wavelength_m=max(4 * grid.cell_m, 0.2), max_wavelength_m=3.0)
    ground = np.float32(tc.relief_m) * relief
    face = -tan_face * d
    ground = np.where(d > 0, np.maximum(face, ground - np.float32(tc.drop_m)), ground)
    ground = np.asarray(ground, np.float32)
    # Textureless patches below the edge (never on the plateau or the face).
    regions = []
    for _ in range(tc.textureless_count):
        rx, ry = draws.uniform(*PATCH_AXES_M, 2)
        cx = float(draws.uniform(grid.xs[0] + rx, grid.xs[-1] - rx))
        cy = float(draws.uniform(grid.ys[0] + ry, min(float(y_edge.min()) - run - ry - 0.3,
                                                        grid.ys[-1] - ry)))
        if turn:
            cx, cy = (float(c) for c in _turned(np.array(cx), np.array(cy), rs.x_m, rs.y_m, turn))
        regions.append((cx, cy, float(rx), float(ry)))
    silt = (d > run + 0.1) & textureless_mask(grid, tuple(regions), seed)
    clear = np.hypot(gx - cb.x_m, gy - cb.y_m) < 0.6 * math.hypot(cb.length_m, cb.width_m) + 0.2
    rock_id = np.full(ground.shape, -1, np.int32)
    no_rock = clear | dilate(silt, int(0.15 / grid.cell_m))
    below = ((d > run) & ~no_rock).astype(np.float32)
    n = 0
    if tc.k > 0:
        n = place_viking_rocks(ground, grid.x0, grid.y0, grid.cell_m, tc.k, rng, tc.d_min_m,
                               tc.d_max_m, weight=below, rock_id=rock_id)
    on_top = d <= 0
    if tc.plateau_k > 0:
        start_clear = np.hypot(gx - rs.x_m, gy - rs.y_m) < 0.8  # the rover's own footprint
        top = (on_top & (d < -0.1) & ~start_clear).astype(np.float32)
        place_viking_rocks(ground, grid.x0, grid.y0, grid.cell_m, tc.plateau_k, rng, tc.d_min_m,
                           max(tc.plateau_d_max_m, 1.01 * tc.d_min_m), weight=top,
                           rock_id=rock_id, first_id=n)
    # The regional slope: downhill toward the azimuth, through the start.
    a = math.radians(azimuth)
    grade = math.tan(math.radians(slope_deg))
    ground -= np.float32(grade) * ((gx - rs.x_m) * math.cos(a) + (gy - rs.y_m) * math.sin(a))
    ix, iy = int((rs.x_m - grid.x0) / grid.cell_m), int((rs.y_m - grid.y0) / grid.cell_m)
    ground -= ground[iy, ix]
    edge = np.column_stack([grid.xs, y_edge])[:: max(1, round(0.02 / grid.cell_m))]
    if turn:
        edge = np.column_stack(_turned(edge[:, 0], edge[:, 1], rs.x_m, rs.y_m, turn))
    world = finish_world(cfg, "terrain", seed, grid, ground, rng, edge_xy=edge, plateau_z=0.0,
                         rock_id=rock_id, textureless=silt, plateau=np.asarray(on_top))
    world.drawn.update(slope_deg=slope_deg, slope_azimuth_deg=azimuth, edge_distance_m=distance)
    return world


def _turned_map(cfg: ScenarioConfig, turn: float) -> MapGridConfig:
    """The ``[map]`` grid moved with an edge turned by ``turn`` about the start: its centre turned
    with it, then shifted so the grid stays on the world and the start at least
    ``MAP_START_INSET_M`` inside it (an axis-aligned grid cannot turn with a diagonal edge)."""
    m, w, rs = cfg.map, cfg.world, cfg.rover_start
    sx, sy = m.nx * m.cell_m, m.ny * m.cell_m
    cx, cy = _turned(np.array(m.origin_x_m + sx / 2), np.array(m.origin_y_m + sy / 2), rs.x_m, rs.y_m, turn)
    ox = min(max(float(cx) - sx / 2, rs.x_m + MAP_START_INSET_M - sx, w.x_min_m), rs.x_m - MAP_START_INSET_M,
             w.x_max_m - sx)
    oy = min(max(float(cy) - sy / 2, rs.y_m + MAP_START_INSET_M - sy, w.y_min_m), rs.y_m - MAP_START_INSET_M,
             w.y_max_m - sy)
    return dataclasses.replace(m, origin_x_m=round(ox, 3), origin_y_m=round(oy, 3))


def _turned(x: np.ndarray, y: np.ndarray, x0: float, y0: float, angle: float) -> tuple[np.ndarray, np.ndarray]:
    """Points ``(x, y)`` turned by ``angle`` (rad, CCW) about ``(x0, y0)``."""
    c, s = math.cos(angle), math.sin(angle)
    dx, dy = x - x0, y - y0
    return x0 + c * dx - s * dy, y0 + s * dx + c * dy
