"""What the Cliff-bot's head scan would see from a standing, and the ground its next step needs
(docs/team.md, "Approach: making the unknown known"; docs/algorithm.md §8.1).

A place to look from is worth as much as the unknown ground it shows that the next step needs.
:func:`needed_cells` is that ground: the cells no sensor measured (unknown, or the plane under
the body carried on) in the footprints (:func:`fsw.core.team.climber_ground.standing_cells`: the
wheels' outline at the heading held there) of the lattice nodes next to a standing on the way
to a target, and under the straight lines in plan from those nodes to the two anchors (the
tethers' ground, which a node's verdict needs known: ``tether over unknown ground``).

:func:`scan_sees` is which of those cells the head's scan (``[cliffbot_sensing]``: each
pointing's pan, tilt and end of the body, :func:`fsw.core.team.cliffbot_head.head_end`) would
see from a standing: the cell in the pointing's field of view, within the camera's usable
range, its sight line not through the body's box (``body_half_m``, from ``BODY_LIFT_M`` above
its ground: the head stands lower than the box's top, so the box hides the ground beside the
body's middle from both ends). An unknown cell is taken at the mean height of the known ground
round it (the cells within ``HOLE_RADIUS_CELLS``, when at least ``HOLE_MIN_KNOWN`` of them are
known: a hole in ground the views mapped, such as a cell on a steep drop past a ledge, lies
where its neighbours lie, metres below the ledge a body stands on), else on the body's ground
plane there (the map's normal at the standing: the unknown ground beyond the known ground's
edge), a carried one at its carried height: a rating of the standing, not a promise (stereo may
still fail on a cell, or the ground may hide itself).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from fsw.core.geometry import MapGrid
from fsw.core.team.cliffbot_head import head_camera_pose, head_end
from fsw.core.team.climber_ground import ClimberConfig, body_yaw, standing_cells
from fsw.core.team.standing_plane import surface_normal
from fsw.core.team.tether import height_at
from fsw.sections import CliffbotSensingConfig

F64 = NDArray[np.float64]
B = NDArray[np.bool_]
BODY_LIFT_M = 0.05  # the body's box starts this far above its ground (fsw.tasks.cliffbot.sensing)
NEXT_RADIUS_NODES = 3  # the next step's nodes: within this many lattice spacings of the standing
OCCLUSION_SAMPLES = 32  # points along a sight line tested against the body's box
# an unknown cell with at least HOLE_MIN_KNOWN known cells within HOLE_RADIUS_CELLS (a square window)
# is a hole in mapped ground: it is rated at their mean height, not on the body's ground plane
HOLE_RADIUS_CELLS = 2
HOLE_MIN_KNOWN = 3


def needed_cells(z: F64, unseen: B, grid: MapGrid, ccfg: ClimberConfig, anchors: F64, here: F64,
                 target: F64) -> B:
    """The cells the next step from ``here`` toward ``target`` needs and no sensor measured
    (module docstring): ``unseen`` marks the cells whose height no sensor gave (the plane
    carried on), NaN in ``z`` the unknown ones. The next step's nodes are the lattice nodes
    within ``NEXT_RADIUS_NODES`` spacings of ``here`` that are nearer ``target`` than it by more
    than a spacing (the approach's rule)."""
    blind = ~np.isfinite(z) | unseen
    out = np.zeros(grid.shape, bool)
    step = ccfg.node_m
    reach = NEXT_RADIUS_NODES * step
    offsets = np.arange(-reach, reach + 0.5 * step, step)
    gap = float(np.hypot(*(here - target)))
    lines = np.linspace(0.0, 1.0, 1 + int(math.ceil(4.0 * float(np.max(np.hypot(*(anchors[:, :2] - here[None, :]).T)))
                                                     / grid.cell)))
    for dx in offsets:
        for dy in offsets:
            p = here + np.array([dx, dy])
            if math.hypot(dx, dy) > reach or float(np.hypot(*(p - target))) >= gap - step:
                continue
            out |= standing_cells(grid, p, ccfg, anchors) & blind
            for a in anchors[:, :2]:
                pts = p[None, :] + lines[:, None] * (a - p)[None, :]
                iy, ix, inside = grid.cell_index(pts[:, 0], pts[:, 1])
                iy, ix = iy[inside], ix[inside]
                hit = blind[iy, ix]
                out[iy[hit], ix[hit]] = True
    return out


def scan_sees(z: F64, grid: MapGrid, ccfg: ClimberConfig, anchors: F64, sc: CliffbotSensingConfig, xy: F64,
              cells: B) -> B:
    """Which of ``cells`` the head's scan would see from a body standing at ``xy`` (module
    docstring); none where the map does not know the ground under it."""
    seen = np.zeros(grid.shape, bool)
    gz = height_at(z, grid, xy)
    if not np.isfinite(gz) or not cells.any():
        return seen
    n = surface_normal(z, grid, xy, ccfg.footprint_m)
    n = np.array([0.0, 0.0, 1.0]) if n is None else n
    yaw = float(body_yaw(anchors, np.array([xy[0]]), np.array([xy[1]]))[0])
    iy, ix = np.nonzero(cells)
    X, Y = grid.x0 + (ix + 0.5) * grid.cell, grid.y0 + (iy + 0.5) * grid.cell
    on_plane = gz - (n[0] * (X - xy[0]) + n[1] * (Y - xy[1])) / n[2]
    around, count = _known_round(z)
    unknown_z = np.where(count[iy, ix] >= HOLE_MIN_KNOWN, around[iy, ix], on_plane)
    pts = np.column_stack([X, Y, np.where(np.isfinite(z[iy, ix]), z[iy, ix], unknown_z)])
    ground = np.array([float(xy[0]), float(xy[1]), gz])
    focal = (sc.width_px / 2.0) / math.tan(math.radians(sc.hfov_deg) / 2.0)
    half_w, half_h = (sc.width_px / 2.0) / focal, (sc.height_px / 2.0) / focal
    hidden = _behind_body(pts, ground, n, yaw, sc)
    got = np.zeros(len(pts), bool)
    for k, pan_deg in enumerate(sc.pan_deg):
        pan = math.radians(pan_deg)
        end = head_end(pan, sc.head_end_m, sc.place_of(k))
        pose = head_camera_pose(ground, n, yaw, pan, math.radians(sc.tilt_of(k)), sc.head_m, end)
        c = pose.world_to_camera(pts)
        rng = np.linalg.norm(c, axis=1)
        front = c[:, 2] > 1e-6
        depth = np.where(front, c[:, 2], 1.0)
        inside = front & (np.abs(c[:, 0] / depth) <= half_w) & (np.abs(c[:, 1] / depth) <= half_h)
        got |= inside & (rng >= sc.min_range_m) & (rng <= sc.max_range_m) & ~hidden[k]
    seen[iy[got], ix[got]] = True
    return seen


def look_rating(z: F64, unseen: B, grid: MapGrid, ccfg: ClimberConfig, anchors: F64, sc: CliffbotSensingConfig,
                here: F64, goal: F64, looked: list[F64], apart_m: float) -> Callable[[F64], tuple[int, int]]:
    """A place to look from, rated for the unknown ground the next step from ``here`` toward
    ``goal`` needs (:func:`needed_cells`): how many of those cells the head's scan would see
    from there (:func:`scan_sees`) and from no place in ``looked``; then, from a place at least
    ``apart_m`` from every one (a new sight line: a cell a look should have shown may have been
    hidden by the ground), how many of them at all."""
    need = needed_cells(z, unseen, grid, ccfg, anchors, here, goal)
    new = need.copy()
    for p in looked:
        new &= ~scan_sees(z, grid, ccfg, anchors, sc, p, need)

    def rating(xy: F64) -> tuple[int, int]:
        apart = all(float(np.hypot(*(xy - p))) >= apart_m for p in looked)
        seen = scan_sees(z, grid, ccfg, anchors, sc, xy, need)
        return int((seen & new).sum()), int(seen.sum()) if apart else 0
    return rating


def _known_round(z: F64) -> tuple[F64, F64]:
    """Per cell, the mean height of the known cells within ``HOLE_RADIUS_CELLS`` (a square window)
    and how many they are (0: the mean is meaningless)."""
    known = np.isfinite(z)
    size = 2 * HOLE_RADIUS_CELLS + 1
    count = ndimage.uniform_filter(known.astype(np.float64), size, mode="constant") * size * size
    total = ndimage.uniform_filter(np.where(known, z, 0.0), size, mode="constant") * size * size
    count = np.rint(count)
    return total / np.maximum(count, 1.0), count


def _behind_body(pts: F64, ground: F64, n: F64, yaw: float, sc: CliffbotSensingConfig) -> B:
    """Per pointing of the scan and point, whether the body's box (its half sizes ``body_half_m``,
    from ``BODY_LIFT_M`` above its ground up) lies on the sight line from the head."""
    fwd = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    fwd = fwd - float(fwd @ n) * n
    fwd /= max(float(np.linalg.norm(fwd)), 1e-9)
    side = np.cross(n, fwd)
    half = np.asarray(sc.body_half_m, float)
    s = np.linspace(0.0, 1.0, OCCLUSION_SAMPLES + 2)[1:-1]
    out = np.zeros((len(sc.pan_deg), len(pts)), bool)
    for k, pan_deg in enumerate(sc.pan_deg):
        end = head_end(math.radians(pan_deg), sc.head_end_m, sc.place_of(k))
        head = ground + sc.head_m * n + end * fwd
        ray = head[None, None, :] + s[None, :, None] * (pts[:, None, :] - head[None, None, :]) - ground
        along, across, up = ray @ fwd, ray @ side, ray @ n
        box = (np.abs(along) <= half[0]) & (np.abs(across) <= half[1]) & (up >= BODY_LIFT_M) & (up <= 2 * half[2])
        out[k] = box.any(axis=1)
    return out
