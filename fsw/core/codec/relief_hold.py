"""The relief hold: no cell the receiver reads under the hazard threshold decodes at or over it
(docs/algorithm.md §6.3; docs/quadtree.md, "Hazards: what the wheel must not lose", its relief both ways;
``[codec] relief_ceiling``).

The hazard rule (:mod:`fsw.core.codec.hazard`) keeps every hazard's relief but lets any other
cell's relief grow by up to ``2e`` (the cell a bound higher, the lowest ground of its disc a
bound lower), so ground just under the threshold reaches the receiver as a rock. The receiver's
planner reads relief across the ground, ``relief x cos(slope)`` over its footprint
(:func:`across_ground`): a bump on a steep face is a hazard in height but not a rock there.
Where a cell under that threshold could decode at or over it (:func:`relief_ceiling`), the cell
is held lower and the ground its opening rests on no lower (:func:`hold_limits`); the hold only
narrows the rule's intervals, never a hazard's, its support's or a step's own, and gives way to
a step (:func:`cell_offsets` solves it with the steps, a few rounds).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from fsw.core.codec.hazard import HazardCells, erode, known_gradient_mean, step_offsets

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
B = NDArray[np.bool_]
Heights = NDArray[np.float32] | NDArray[np.float64]  # an elevation map, metres (NaN: unknown)

HOLD_ROUNDS = 4  # rounds of the relief hold, and tries of its step solve per round (cell_offsets)
RESTING_BLOCK = 2048  # cells whose resting discs are searched at once (_resting_disc; memory ~ block x disc)


def cell_offsets(z: Heights, cells: HazardCells, *, bound_m: float, rise_m: float,
                 step_slack_m: float, threshold_m: float, cell_m: float,
                 relief_disc: NDArray[np.uint8] | None = None, guard_m: float = 0.0,
                 under: F64 | None = None) -> tuple[F64, F64]:
    """Per known cell, how far below and above its height its decoded height may lie: the
    hazard and step rule (:func:`step_offsets`) and, given the ``relief_disc`` kernel, the
    relief held both ways: no cell the receiver reads under ``threshold_m`` across the ground
    (:func:`across_ground`) brought to it (:func:`hold_limits`, ``guard_m`` below it). The hold
    only narrows intervals and is solved with the steps, a few rounds (each may raise a step
    chain's windows, which moves the relief it reads). ``under``: that threshold per cell in
    height, ``threshold_m / across_ground`` (:func:`relief_threshold`), when already worked out."""
    floor = ceiling = None
    last: tuple[F64, F64] | None = None  # a round's limits before its solve freed any step cell
    lo, hi = step_offsets(cells, bound_m=bound_m, rise_m=rise_m, step_slack_m=step_slack_m, threshold_m=threshold_m)
    short0 = _short_steps(cells, lo, hi, threshold_m, step_slack_m)
    for _ in range(HOLD_ROUNDS):
        if relief_disc is None:
            break
        if under is None:
            under = relief_threshold(z, cell_m, threshold_m, relief_disc)
        limits = hold_limits(z, cells.relief, lo, hi, kernel=relief_disc, threshold_m=under,
                             step_slack_m=step_slack_m, guard_m=guard_m)
        if limits is None:
            break
        floor = limits[0] if floor is None else np.maximum(floor, limits[0])
        ceiling = limits[1] if ceiling is None else np.minimum(ceiling, limits[1])
        if last is not None and np.array_equal(floor, last[0]) and np.array_equal(ceiling, last[1]):
            break  # the limits of the last round again: its solve, and every later round, would repeat it
        last = (floor.copy(), ceiling.copy())
        for attempt in range(HOLD_ROUNDS):  # the last try frees every step cell: the rule's own solve
            lo, hi = step_offsets(cells, bound_m=bound_m, rise_m=rise_m, step_slack_m=step_slack_m,
                                  threshold_m=threshold_m, floor=floor, ceiling=ceiling)
            # The steps come first: a step the limits cut short frees its top and the chain of
            # feet below it of them (and, if that is not enough, every step cell).
            cut = _short_steps(cells, lo, hi, threshold_m, step_slack_m) & ~short0
            if not cut.any():
                break
            assert cells.step_top is not None and cells.step_foot is not None
            freed = _chains_below(cells, cut) if attempt < HOLD_ROUNDS - 2 else \
                np.concatenate([cells.step_top, cells.step_foot])
            floor.ravel()[freed] = -np.inf
            ceiling.ravel()[freed] = np.inf
    return lo, hi


def _chains_below(cells: HazardCells, pairs: B) -> NDArray[np.int64]:
    """Flat indices of the tops of the step ``pairs`` and of every foot down their chains (a
    foot that is itself a top, its foot, ...)."""
    assert cells.step_top is not None and cells.step_foot is not None
    foot_of = np.full(cells.relief.size, -1, np.int64)
    foot_of[cells.step_top] = cells.step_foot
    seen = np.zeros(cells.relief.size, bool)
    cur = cells.step_top[pairs]
    while cur.size:
        seen[cur] = True
        cur = foot_of[cur]
        cur = cur[cur >= 0]
        cur = cur[~seen[cur]]
    return np.flatnonzero(seen)


def _short_steps(cells: HazardCells, lo: F64, hi: F64, threshold_m: float, slack_m: float) -> B:
    """Per step pair of ``cells``, whether the offsets leave its decoded drop short of
    ``max(threshold, step - slack)`` (:func:`step_offsets`)."""
    if cells.step_top is None or cells.step_foot is None:
        return np.zeros(0, bool)
    need = np.maximum(threshold_m - cells.step.ravel()[cells.step_top].astype(np.float64), -slack_m)
    return np.asarray(lo.ravel()[cells.step_top] < hi.ravel()[cells.step_foot] + need - 1e-12)


def hold_limits(z: Heights, relief_m: F32, lo: F64, hi: F64, *, kernel: NDArray[np.uint8],
                threshold_m: F64, step_slack_m: float, guard_m: float) -> tuple[F64, F64] | None:
    """One round of the relief hold (docs/algorithm.md §6.3, "Relief both ways"): the floors and
    ceilings (offsets) under which no cell whose relief (``relief_m``) is under its threshold
    (``threshold_m``, per cell) can decode at or over it, as far as the current offsets
    ``[lo, hi]`` leave room; None when none is needed.

    A cell's relief may grow by up to ``2e`` (itself ``e`` higher, the lowest ground of its disc
    ``e`` lower). Where its :func:`relief_ceiling` reaches the threshold, the cell is held lower
    by the excess, as far as a lattice step of interval (``step_slack_m``) allows; what remains
    holds the ground of the disc its opening rests on (the disc, among those covering it, whose
    lowest cell is highest) no lower than the cell's top less the threshold. Limits only narrow
    intervals (:func:`step_offsets` keeps every hazard's, support's and step's own), so where a
    cell's interval and its ground's are already a lattice step wide (a hazard that is never
    lower on ground a step chain holds low) the relief may still grow past its threshold.
    """
    z64 = np.asarray(z, np.float64)
    known = np.isfinite(z64)
    lowest, opened = _ground(z64, lo, kernel)
    ceil = _ceiling(z64, hi, known, opened).astype(np.float64)
    with np.errstate(invalid="ignore"):
        over = known & (relief_m < threshold_m) & (ceil >= threshold_m - guard_m)
    if not over.any():
        return None
    # The cell itself: its top lowered by the excess, keeping a lattice step of interval.
    top = np.maximum(lo + step_slack_m, hi - (ceil - threshold_m + 2.0 * guard_m))
    ceiling = np.where(over, top, np.inf)
    short = over & (hi - top < ceil - threshold_m + 2.0 * guard_m)  # the cell alone is not enough
    floor = np.full(z64.shape, -np.inf)
    if short.any():
        # Its ground: the disc its opening rests on held no lower than (top - threshold).
        centre = _resting_disc(lowest, opened, short, kernel)
        target = np.full(z64.size, -np.inf)
        sy, sx = np.nonzero(short)
        np.maximum.at(target, centre, (z64 + top - threshold_m + 2.0 * guard_m)[sy, sx])
        need = cv2.dilate(target.reshape(z64.shape), kernel, borderType=cv2.BORDER_CONSTANT,
                          borderValue=float("-inf"))
        floor = np.where(known, need - np.where(known, z64, 0.0), -np.inf)
    return floor, ceiling


def relief_ceiling(z: Heights, lo: F64, hi: F64, kernel: NDArray[np.uint8]) -> F32:
    """The highest relief (top-hat over ``kernel``) any map inside the offsets ``[lo, hi]`` can
    decode with, per cell (NaN on unknown cells): the cell at its highest against the opening
    of every cell at its lowest. The opening is monotone in the heights, and a float32 value
    inside an interval lies between the float32 roundings of its ends, so the decoded map's
    relief, computed as :func:`relief` computes it, is never above this."""
    z64 = np.asarray(z, np.float64)
    return _ceiling(z64, hi, np.isfinite(z64), _ground(z64, lo, kernel)[1])


def _ground(z64: F64, lo: F64, kernel: NDArray[np.uint8]) -> tuple[F32, F32]:
    """The map at its lowest (``z + lo``) under ``kernel``: per cell, the lowest known cell of the
    disc centred there (-inf where no disc is centred: unknown cells), and the highest of those
    over the discs covering it (the opening, before unknown cells are masked). One erosion and
    one dilation serve both the relief ceiling and the resting discs of a round."""
    level = (z64 + lo).astype(np.float32)
    lowest = erode(level, kernel)
    lowest[~np.isfinite(level)] = -np.inf
    opened = cv2.dilate(lowest, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=float("-inf"))
    return lowest, np.asarray(opened, np.float32)


def _ceiling(z64: F64, hi: F64, known: B, opened: F32) -> F32:
    """The relief ceiling from the map at its highest (``z + hi``) and the opening at its lowest
    (:func:`_ground`), as :func:`fsw.core.codec.hazard.opening` would mask it (NaN unknown)."""
    top = (z64 + hi).astype(np.float32)
    ground = np.where(known, opened, np.float32(np.nan)).astype(np.float32)
    return (top - ground).astype(np.float32)


def relief_threshold(z: Heights, cell_m: float, threshold_m: float, kernel: NDArray[np.uint8]) -> F64:
    """Per cell, the relief in height that the receiver reads as ``threshold_m`` across the
    ground (``threshold_m / cos(slope)``, :func:`across_ground` over the relief disc): the relief
    hazards of a reduction with the hold (``hazard.classify(..., relief_threshold=...)``) and
    the threshold the hold keeps every other cell under."""
    return threshold_m / across_ground(z, cell_m, kernel.shape[0])


def across_ground(z: Heights, cell_m: float, k: int) -> F64:
    """Per cell, the cos of the ground's slope over a ``k`` x ``k`` window round it, from the mean
    of the central-difference gradients its known cells give (1 where none): what the receiver's
    planner multiplies a relief by to read it across the ground (``fsw.core.team.face_planner``,
    its footprint's slope: a bump on a steep face stands ``relief x cos(slope)`` off it)."""
    z64 = np.asarray(z, np.float64)
    if min(z64.shape) < 2:  # no gradient along a single row or column: read as level
        return np.ones(z64.shape)
    mx, my, _ = known_gradient_mean(z64, cell_m, k)
    return np.asarray(1.0 / np.sqrt(1.0 + mx * mx + my * my), np.float64)


def _resting_disc(lowest: F32, opened: F32, cells: B, kernel: NDArray[np.uint8]) -> NDArray[np.int64]:
    """Per cell of ``cells`` (row-major order), the flat index of the centre of the disc its
    opening rests on: the nearest centre within the disc around it (offsets in order of
    distance, ties in raster order) whose disc's lowest known cell (``lowest``, -inf where no
    disc is centred) is the highest (``opened``, that highest value: :func:`_ground`). Every
    cell's offsets are read at once, a block of cells at a time."""
    ny, nx = lowest.shape
    cy, cx = np.nonzero(cells)
    r = (kernel.shape[0] - 1) // 2
    dy, dx = np.nonzero(kernel)
    dy, dx = dy - r, dx - r
    order = np.argsort(dy * dy + dx * dx, kind="stable")
    dy, dx = dy[order], dx[order]
    at = np.empty(cy.size, np.int64)
    for b in range(0, cy.size, RESTING_BLOCK):
        yy, xx = cy[b:b + RESTING_BLOCK, None] + dy, cx[b:b + RESTING_BLOCK, None] + dx
        inside = (yy >= 0) & (yy < ny) & (xx >= 0) & (xx < nx)
        flat = np.where(inside, yy * nx + xx, 0)
        hit = inside & (lowest.ravel()[flat] == opened[cy[b:b + RESTING_BLOCK], cx[b:b + RESTING_BLOCK], None])
        at[b:b + RESTING_BLOCK] = flat[np.arange(flat.shape[0]), hit.argmax(axis=1)]
    return at
