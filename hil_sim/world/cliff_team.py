"""The ``cliff-team`` scenario: the paper's four robots at a cliff (docs/algorithm.md §8).

A level plateau (``z = 0``) where the RECON-bot drives ends at an irregular edge line near
``y = edge_y_m``. Below it a rough face ``face_slope_deg`` steep drops ``drop_m`` (values of
-1 are drawn from the seed: slope in 55-85 deg, drop in 2-8 m), broken by ``ledges``
(shelves of 0.15-0.4 m at random depths); a *rock jumble* (a dense patch of Viking-model
rocks, ``jumble_k``) sits on the face; the floor below carries a few rocks. Two Anchorbots
stand on the plateau ``anchor_setback_m`` behind the edge, ``anchor_spacing_m`` apart,
each with a tether winch; the Cliff-bot starts on the plateau between them, just behind
the edge. ``targets`` science targets (2-4) are drawn on the face, between 20 % and 90 % of
the drop, away from the jumble (some may still be out of the tethers' reach: the
brute-force planner on the truth says which).

The face is built from its depth profile: horizontal distance past the edge as a function
of depth, ``d(z) = |z| / tan(a) + sum of the ledge widths above z``, inverted for ``z(d)``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import NDArray

from hil_sim.team.team_truth import TeamTruth
from hil_sim.world.build import edge_curve, finish_world, truth_grid
from hil_sim.world.config import CliffTeamConfig, ScenarioConfig, ScenarioError
from hil_sim.world.mars import place_viking_rocks
from hil_sim.world.noise import fractal_noise
from hil_sim.world.world import World

F64 = NDArray[np.float64]


def _drawn(value: float, lo: float, hi: float, rng: np.random.Generator) -> float:
    return float(rng.uniform(lo, hi)) if value < 0 else float(value)


def face_profile(drop_m: float, slope_deg: float, ledges: list[tuple[float, float]]) -> tuple[F64, F64]:
    """``(d, z)`` samples of the face's depth profile: horizontal distance past the edge and
    height, with ``ledges`` as ``(depth, width)`` shelves; ``d`` increasing."""
    z = -np.linspace(0.0, drop_m, 2001)
    d = -z / math.tan(math.radians(slope_deg))
    for depth, width in ledges:
        d = d + width * (-z > depth)
    # A ledge makes d jump at its depth: a shelf of constant z over that run.
    dd = np.concatenate([[0.0], d])
    zz = np.concatenate([[0.0], z])
    order = np.argsort(dd, kind="stable")
    return dd[order], zz[order]


def build_cliff_team(cfg: ScenarioConfig, seed: int) -> World:
    ct = cfg.cliff_team or CliffTeamConfig()
    rng = np.random.default_rng([seed, 27])
    slope = _drawn(ct.face_slope_deg, 55.0, 85.0, rng)
    drop = _drawn(ct.drop_m, 2.0, 8.0, rng)
    grid = truth_grid(cfg)
    gx, gy = grid.mesh()
    y_edge = edge_curve(grid.xs, rng, ct.edge_y_m, ct.edge_wiggle_m, ct.edge_wavelength_m)
    d = (y_edge.astype(np.float32)[None, :] - gy).astype(np.float64)  # distance past the edge
    ledges = [(float(rng.uniform(0.2, 0.85) * drop), float(rng.uniform(0.15, 0.4))) for _ in range(ct.ledges)]
    prof_d, prof_z = face_profile(drop, slope, ledges)
    run = float(prof_d[-1])
    if grid.y0 > ct.edge_y_m - run - 1.0:
        raise ScenarioError(f"cliff-team: the world ends at y = {grid.y0} m, the face runs to "
                            f"y = {ct.edge_y_m - run:.1f} m: lower world.y_min_m")
    rough = fractal_noise(gx.shape, grid.cell_m, rng, beta=2.2, min_wavelength_m=0.1, max_wavelength_m=1.0)
    face = np.interp(d + ct.face_roughness_m * rough, prof_d, prof_z, left=0.0, right=-drop)
    relief = fractal_noise(gx.shape, grid.cell_m, rng, beta=2.8, min_wavelength_m=0.05, max_wavelength_m=3.0)
    floor = -drop - math.tan(math.radians(ct.floor_slope_deg)) * np.maximum(d - run, 0.0) + 0.03 * relief
    ground = np.where(d <= 0, 0.0, np.where(d > run, floor, face)).astype(np.float32)
    # The jumble: a patch of dense rocks on the face, at mid depth, beside the Cliff-bot's
    # fall line; a few rocks on the floor.
    cb_x = cfg.cliffbot.x_m
    jx = cb_x + float(rng.choice([-1.0, 1.0])) * float(rng.uniform(0.4, 1.2))
    jy = ct.edge_y_m - run * float(rng.uniform(0.35, 0.65))
    jax, jay = float(rng.uniform(0.5, 0.9)), max(0.25, 0.35 * run)
    inside = ((gx - jx) / jax) ** 2 + ((gy - jy) / jay) ** 2 < 1.0
    on_face = (d > 0.05) & (d < run - 0.05)
    weight = np.where(inside & on_face, 1.0, np.where(d > run + 0.3, ct.floor_k / max(ct.jumble_k, 1e-6), 0.0))
    rock_id = np.full(ground.shape, -1, np.int32)
    if ct.jumble_k > 0:
        # Rocks stand off the ground along its normal: on the face a rock of height h adds
        # h / cos(slope) to the heightfield.
        rocks = np.zeros_like(ground)
        place_viking_rocks(rocks, grid.x0, grid.y0, grid.cell_m, ct.jumble_k, rng, ct.rock_d_min_m,
                           ct.rock_d_max_m, weight=np.clip(weight, 0, 1).astype(np.float32), rock_id=rock_id)
        ground += (rocks / np.where(on_face, math.cos(math.radians(slope)), 1.0)).astype(np.float32)
    on_top = d <= 0
    ground[on_top] = 0.0
    rock_id[on_top] = -1
    # Anchors and the Cliff-bot's start on the plateau.
    ay = ct.edge_y_m + ct.anchor_setback_m
    anchors = np.array([[cb_x - 0.5 * ct.anchor_spacing_m, ay], [cb_x + 0.5 * ct.anchor_spacing_m, ay]])
    start = np.array([cb_x, cfg.cliffbot.y_m])
    if float(np.interp(cb_x, grid.xs, y_edge)) >= start[1] - 0.3:
        raise ScenarioError(f"cliff-team: the Cliff-bot's start y = {start[1]} m is not on the plateau "
                            "(edge_wiggle_m too large, or move [cliffbot] y_m back)")
    # Targets: on the face, 20-90 % of the drop, inside the anchors' span (widened), not in the jumble.
    targets = []
    tries = 0
    while len(targets) < ct.targets and tries < 1000:
        tries += 1
        tx = cb_x + float(rng.uniform(-0.75, 0.75)) * ct.anchor_spacing_m
        depth = float(rng.uniform(0.2, 0.9)) * drop
        ty = float(np.interp(tx, grid.xs, y_edge)) - float(np.interp(depth, -prof_z, prof_d))
        if ((tx - jx) / (jax + 0.4)) ** 2 + ((ty - jy) / (jay + 0.4)) ** 2 < 1.0:
            continue
        if any(math.hypot(tx - p[0], ty - p[1]) < 0.8 for p in targets):
            continue
        iy = int((ty - grid.y0) / grid.cell_m)
        ix = int((tx - grid.x0) / grid.cell_m)
        if not (0 <= iy < grid.ny and 0 <= ix < grid.nx):
            continue
        targets.append((tx, ty, float(ground[iy, ix])))
    if len(targets) < ct.targets:
        raise ScenarioError(f"cliff-team: only {len(targets)} of {ct.targets} targets fit on the face")
    edge = np.column_stack([grid.xs, y_edge])[:: max(1, round(0.02 / grid.cell_m))]
    world = finish_world(cfg, "cliff-team", seed, grid, ground, rng, edge_xy=edge, plateau_z=0.0,
                         rock_id=rock_id, plateau_tol_m=0.005)
    team = TeamTruth(anchors, start, np.asarray(targets, float), (jx, jy, jax, jay), slope, drop, ct.edge_y_m)
    return dataclasses.replace(world, team=team, drawn={"face_slope_deg": slope, "drop_m": drop})
