"""What the wheel must not lose: relief and step hazards of an elevation map (docs/algorithm.md §6).

The map codec may move every cell by its error bound ``e`` (one wheel diameter), which alone
lets a boulder be flattened from both sides: its peak sent ``e`` low and the ground around it
``e`` high. This module says which cells are critical and what each cell may become, so that
the reduction keeps every hazard's relief.

**Critical (choice).** Two measures, both against one wheel diameter ``w``:

* *relief*: the white top-hat of the height over a disc about the rover's size
  (``relief_disc_m``, default 1.05 m): a cell's height above the ground that disc rolls on. A
  connected set of cells with relief >= ``w`` is an obstacle (the reviewer's definition). The
  top-hat ignores the terrain's slow shape (slopes, the plateau) and measures what stands up
  from it, whatever the rock's shape.
* *step*: a cell's height above the lowest cell within one wheel diameter (``z`` minus the
  grey erosion over a disc of ``step_disc_wheels * w``): the step a wheel meets, so a cliff
  edge's lip and its face count although the top-hat of a wide plateau is zero.

Slope over the wheelbase is left to the Cliff-bot's planner: it is a low-frequency property
the height bound already keeps (a slope's error is at most ``2e`` over the wheelbase).

**What each cell may become.** Every known cell stays within ``e`` of its height; besides:

* a *relief hazard* (relief >= ``threshold``) decodes at least ``rise`` higher,
  ``[z + rise, z + e]``;
* a *support* cell (the lowest cell of a relief disc that covers a relief hazard, or a
  step's foot: one lowest cell of the step disc around it; not itself a hazard) decodes at
  most ``rise`` higher, ``[z - e, z + rise]``;
* a *step* (step >= ``threshold``) keeps a decoded drop to its foot ``>= max(threshold, step
  - step_slack)``; a cell that is both a foot and a top (a slope, a cliff's face) or a
  relief hazard that is a foot gets a window one ``step_slack`` wide (``step_offsets``).

The opening at a cell is the highest, over the discs covering it, of the disc's lowest cell;
for a relief hazard that lowest cell is a support cell, so its decoded opening is at most
``rise`` above the original, while the hazard itself is at least ``rise`` higher: **a relief
hazard's decoded relief is never below its original relief**, its height never lower, its
footprint and position unchanged to the cell. Any cell's relief drops by at most ``2e``.
Every step keeps a drop >= the threshold and loses at most ``step_slack``, except along a
chain of three or more relief hazards (a rock on a rock on a rock) whose steps are within
``step_slack`` of the threshold: at most ``e - rise + step_slack``.

**Relief both ways** (``[codec] relief_ceiling``): the rule lets any other cell's relief grow
by up to ``2e``, so ground just under the threshold could reach the receiver as a rock; the
relief hold (:mod:`fsw.core.codec.relief_hold`) narrows the intervals this module gives so it
does not; with it the relief hazards are read as the receiver reads a rock, across the ground
(``classify(..., relief_threshold=...)``): a cell under that threshold held never lower, on
ground held never higher, could still gain up to two lattice steps of relief.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
B = NDArray[np.bool_]

@dataclass(frozen=True)
class HazardRule:
    """Hazard scales in metres (the codec derives them from ``[codec]`` and the wheel)."""

    threshold_m: float  # relief or step that makes a cell critical (one wheel diameter)
    relief_disc_m: float  # top-hat disc diameter
    step_disc_m: float  # step window diameter


def disc(diameter_m: float, cell_m: float) -> NDArray[np.uint8]:
    """A digital disc (``x^2 + y^2 <= r^2``, odd side) of about ``diameter_m``."""
    r = max(1, int(np.floor(diameter_m / (2.0 * cell_m) + 0.5 + 1e-4)))  # float32 header values round alike
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    return (yy * yy + xx * xx <= r * r).astype(np.uint8)


def erode(z: F32, kernel: NDArray[np.uint8]) -> F32:
    """Grey erosion ignoring unknown (NaN) cells and cells past the map edge."""
    known = np.isfinite(z)
    fill = np.where(known, z, np.float32(np.inf)).astype(np.float32)
    out = cv2.erode(fill, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=float("inf"))
    return np.asarray(out, np.float32)


def opening(z: F32, kernel: NDArray[np.uint8], unknown_centres: bool = False) -> F32:
    """Grey opening ignoring unknown cells: per cell, the highest over the discs covering it
    of the disc's lowest known cell (NaN on unknown cells). The discs are those centred on
    known cells, or with ``unknown_centres`` on any cell of the map: a disc centred on unknown
    ground still holds the known cells it covers (the cell itself among them), and the ground a
    disc could rest on there is no lower than its lowest known cell as far as the map knows."""
    known = np.isfinite(z)
    e = erode(z, kernel)
    if not unknown_centres:
        e[~known] = -np.inf
    o = cv2.dilate(e, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=float("-inf"))
    return np.where(known, o, np.float32(np.nan)).astype(np.float32)


def known_gradient_mean(z: F64, cell_m: float, k: int) -> tuple[F64, F64, F64]:
    """The mean height gradient (``mx``, ``my``, per metre) over a ``k`` x ``k`` window round
    each cell, of the central differences known cells give (none beside an unknown cell), and
    the share ``n`` of the window that gave one (the means are 0 where it is 0)."""
    from scipy import ndimage

    gy, gx = np.gradient(z, cell_m)
    ok = np.isfinite(gx) & np.isfinite(gy)
    n = ndimage.uniform_filter(ok.astype(np.float64), k)
    mx = ndimage.uniform_filter(np.where(ok, gx, 0.0), k) / np.maximum(n, 1e-9)
    my = ndimage.uniform_filter(np.where(ok, gy, 0.0), k) / np.maximum(n, 1e-9)
    return mx, my, n


def relief(z: NDArray[np.floating], cell_m: float, disc_m: float, unknown_centres: bool = False) -> F32:
    """White top-hat of ``z`` over a disc of ``disc_m`` (>= 0; NaN on unknown cells);
    ``unknown_centres`` as for :func:`opening` (the same on a map that knows every cell)."""
    z32 = np.asarray(z, np.float32)
    return (z32 - opening(z32, disc(disc_m, cell_m), unknown_centres)).astype(np.float32)


def step(z: NDArray[np.floating], cell_m: float, disc_m: float) -> F32:
    """Height above the lowest known cell within a disc of ``disc_m`` (NaN on unknown cells)."""
    z32 = np.asarray(z, np.float32)
    return (z32 - erode(z32, disc(disc_m, cell_m))).astype(np.float32)


@dataclass(frozen=True)
class HazardCells:
    relief: F32
    step: F32
    relief_hazard: B
    step_hazard: B
    support: B  # relief support or a step's foot, not itself a relief hazard
    relief_support: B | None = None  # the lowest cell of a relief disc covering a relief hazard
    step_top: NDArray[np.int64] | None = None  # flat index of every cell with step >= threshold
    step_foot: NDArray[np.int64] | None = None  # flat index of its foot: one lowest known cell of its disc

    @cached_property
    def step_nodes(self) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
        """The cells the steps involve (flat indices, sorted) and, per step pair, the places of
        its top and its foot among them: worked out once, for every solve of :func:`step_offsets`."""
        assert self.step_top is not None and self.step_foot is not None
        nodes, inv = np.unique(np.concatenate([self.step_top, self.step_foot]), return_inverse=True)
        return nodes, inv[:self.step_top.size], inv[self.step_top.size:]


def _argmins(z32: F32, eroded: F32, centres: B, kernel: NDArray[np.uint8]) -> B:
    """Cells that are the lowest known cell of a disc centred on one of ``centres``
    (``eroded``: ``erode(z32, kernel)``)."""
    known = np.isfinite(z32)
    e = np.where(centres & known, eroded, np.float32(-np.inf)).astype(np.float32)
    reach = cv2.dilate(e, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=float("-inf"))
    return known & (reach == z32)


def _feet(z32: F32, eroded: F32, tops: B, kernel: NDArray[np.uint8]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Flat indices of ``tops`` and of one lowest known cell of the disc around each (the
    nearest such cell; ``eroded``: ``erode(z32, kernel)``)."""
    ny, nx = z32.shape
    ty, tx = np.nonzero(tops)
    target = eroded[ty, tx]
    foot = np.full(ty.size, -1, np.int64)
    r = (kernel.shape[0] - 1) // 2
    dy, dx = np.nonzero(kernel)
    dy, dx = dy - r, dx - r
    for k in np.argsort(dy * dy + dx * dx, kind="stable"):
        if not (foot < 0).any():
            break
        yy, xx = ty + dy[k], tx + dx[k]
        inside = (yy >= 0) & (yy < ny) & (xx >= 0) & (xx < nx) & (foot < 0)
        hit = np.zeros(ty.size, bool)
        hit[inside] = z32[yy[inside], xx[inside]] == target[inside]
        foot[hit] = yy[hit] * nx + xx[hit]
    keep = foot >= 0  # always true: the erosion's value is one of the disc's cells
    return (ty * nx + tx)[keep].astype(np.int64), foot[keep]


def classify(z: NDArray[np.floating], cell_m: float, rule: HazardRule,
             relief_threshold: F64 | None = None) -> HazardCells:
    """Relief, step, and the hazard and support cells of ``z`` (see the module docstring).

    Support cells are only those a hazard's relief or step depends on: the lowest cell of a
    relief disc covering a relief hazard, or the foot of a step (one lowest cell of the step
    disc around it). ``relief_threshold`` (per cell): the relief that makes a cell a relief
    hazard, where the receiver reads relief across the ground (the relief hold,
    :func:`fsw.core.codec.relief_hold.across_ground`); default the rule's threshold everywhere.
    Steps are always against the rule's threshold.
    """
    z32 = np.asarray(z, np.float32)
    known = np.isfinite(z32)
    rk = disc(rule.relief_disc_m, cell_m)
    er = erode(z32, rk)
    opened = cv2.dilate(np.where(known, er, np.float32(-np.inf)).astype(np.float32), rk,
                        borderType=cv2.BORDER_CONSTANT, borderValue=float("-inf"))
    rel = np.where(known, z32 - opened, np.float32(np.nan)).astype(np.float32)
    sk = disc(rule.step_disc_m, cell_m)
    es = erode(z32, sk)
    stp = (z32 - es).astype(np.float32)
    with np.errstate(invalid="ignore"):
        rel_h = known & (rel >= (rule.threshold_m if relief_threshold is None else relief_threshold))
        steps = known & (stp >= rule.threshold_m)
    # Centres of the relief discs that cover a relief hazard: within the disc's radius of one.
    r = (rk.shape[0] - 1) // 2
    if rel_h.any():
        dist = cv2.distanceTransform((~rel_h).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        near = dist <= r + 1e-3
    else:
        near = np.zeros_like(rel_h)
    rel_support = ~rel_h & _argmins(z32, er, near, rk)
    tops, feet = _feet(z32, es, steps, sk)
    is_foot = np.zeros(z32.size, bool)
    is_foot[feet] = True
    support = rel_support | (~rel_h & is_foot.reshape(z32.shape))
    return HazardCells(rel, stp, rel_h, steps & ~rel_h, support, rel_support, tops, feet)


def step_offsets(cells: HazardCells, *, bound_m: float, rise_m: float, step_slack_m: float,
                 threshold_m: float | None = None, floor: F64 | None = None,
                 ceiling: F64 | None = None) -> tuple[F64, F64]:
    """Per cell, how far below and above its height the decoded height may lie (``lo <= 0 <= hi``
    except where a hazard must rise).

    * a relief hazard ``[rise, e]`` (never lower), its relief support ``[-e, rise]`` (never higher);
    * a step: the decoded drop from its top ``t`` to its foot ``f`` (one lowest cell within
      the step disc) must stay ``>= max(w, s - slack)`` (``s`` its step, ``w`` the threshold):
      ``lo_t - hi_f >= need_t = max(w - s, -slack)``. A top that is no one's foot is ``[a, e]``
      with ``a >= rise``; a plain foot ``[-e, rise]``; a cell that is both a foot and a top (a
      slope, the cliff's face) or a relief hazard is the window ``[a, a + slack]``, ``a`` as
      low as its own step allows, so chains of steps down a face stay feasible: only steps
      within ``slack`` of ``w`` push the window up. Solved in order of height (a foot is
      lower than its top) by monotone relaxation; a window is capped at ``e`` (and a relief
      support's at ``rise``), where a step may be lost (the experiment counts it).

    Without ``threshold_m`` (or step pairs) the rule before: a step top that is also support
    is ``[rise - slack, rise]``.

    ``floor`` and ``ceiling`` (offsets per cell, the relief hold of :func:`cell_offsets`) narrow
    the intervals further where the rule leaves room: an interval stays at least ``slack`` wide,
    a window's lowest place rises to its floor (and its step chain above it with it).
    """
    e, r, sl = bound_m, rise_m, step_slack_m
    shape = cells.relief.shape
    rh, sh, sup = cells.relief_hazard.ravel(), cells.step_hazard.ravel(), cells.support.ravel()
    lo = np.full(rh.size, -e)
    hi = np.full(rh.size, e)
    lo[sh | rh] = r
    hi[sup] = r
    lo[sh & sup] = r - sl  # a step top that is also support: the window below its height
    if ceiling is not None:
        hi = np.minimum(hi, np.maximum(ceiling.ravel(), lo + sl))
    if floor is not None:
        lo = np.maximum(lo, np.minimum(floor.ravel(), hi - sl))
    if threshold_m is None or cells.step_top is None or cells.step_foot is None or cells.step_top.size == 0:
        return lo.reshape(shape), hi.reshape(shape)
    # Work on the cells the steps involve only (tops and feet).
    nodes, t, f = cells.step_nodes
    n_rh, n_sh = rh[nodes], sh[nodes]
    n_rsup = (cells.relief_support if cells.relief_support is not None else cells.support).ravel()[nodes]
    n_lo, n_hi = lo[nodes], hi[nodes]
    window = np.zeros(nodes.size, bool)
    window[f] = True
    window &= n_rh | n_sh  # a foot that must also stay up: [a, a + slack]
    w_lo, w_hi = np.where(n_rh, r, -e), np.where(n_rsup, r, e)  # a window's room
    if floor is not None:
        w_lo = np.maximum(w_lo, np.minimum(floor.ravel()[nodes], w_hi - sl))
    if ceiling is not None:
        w_hi = np.minimum(w_hi, np.maximum(ceiling.ravel()[nodes], w_lo + sl))
    base = np.where(window, w_lo, n_lo)
    cap = np.maximum(base, np.where(window, w_hi, n_hi) - sl)
    need = np.maximum(threshold_m - cells.step.ravel()[cells.step_top].astype(np.float64), -sl)
    foot_of = np.full(nodes.size, -1, np.int64)
    foot_of[t] = f
    for _ in range(3):
        a = _raise_windows(base, cap, window, n_hi, t, f, need, sl)
        h = np.where(window, a + sl, n_hi)
        short = a[t] < h[f] + need - 1e-12
        if not short.any():
            break
        # A top held down by its cap: the plain feet of its chain go as low as the bound allows.
        chain = np.zeros(nodes.size, bool)
        cur = np.unique(f[short])
        while cur.size:
            chain[cur] = True
            cur = foot_of[cur]
            cur = cur[(cur >= 0)]
            cur = cur[~chain[cur]]
        plain = chain & ~window & (foot_of < 0)
        if not (plain & (n_hi > np.maximum(-e + sl, n_lo + sl))).any():
            break
        n_hi = np.where(plain, np.maximum(np.minimum(n_hi, -e + sl), n_lo + sl), n_hi)
    lo[nodes] = a
    hi[nodes] = np.where(window, a + sl, n_hi)
    return lo.reshape(shape), hi.reshape(shape)


def _raise_windows(base: F64, cap: F64, window: B, hi: F64, t: NDArray[np.int64], f: NDArray[np.int64],
                   need: F64, slack: float) -> F64:
    """The least lower offsets ``a >= base`` (capped) with ``a_t >= hi_f + need`` for every step
    pair, a window's ``hi`` being ``a + slack``: monotone relaxation, one chain link per pass."""
    a = base.copy()
    for _ in range(512):
        h = np.where(window, a + slack, hi)
        want = np.full(a.size, -np.inf)
        np.maximum.at(want, t, h[f] + need)
        new = np.minimum(np.maximum(base, want), cap)
        if np.array_equal(new, a):
            break
        a = new
    return a


@dataclass(frozen=True)
class ObstacleCheck:
    """Obstacles (connected relief >= threshold) of an input map and what a decoded map kept."""

    n: int  # obstacles in the input
    kept: int  # of them, decoded relief (max over the footprint) >= threshold
    n_2x: int  # obstacles whose peak relief >= 2 x threshold
    kept_2x: int
    worst_peak_loss_m: float  # max over obstacles of input peak relief - decoded peak relief
    worst_relief_loss_m: float  # max over the input's hazard cells of relief - decoded relief
    footprint_kept: float  # fraction of input hazard cells with decoded relief >= threshold
    position_error_cells: float  # max over obstacles: input peak to nearest kept cell
    step_cells: int = 0  # cells whose step (over step_disc_m) >= threshold
    step_kept: float = 1.0  # fraction of them with a decoded step >= threshold
    worst_step_loss_m: float = 0.0  # max over them of step - decoded step
    new_obstacles: int = 0  # decoded obstacles that touch no input obstacle (conservative, false)


def check_obstacles(z: NDArray[np.floating], decoded: NDArray[np.floating], cell_m: float,
                    threshold_m: float, disc_m: float, step_disc_m: float | None = None,
                    reference: tuple[F32, F32] | None = None,
                    relief_threshold: F64 | None = None) -> ObstacleCheck:
    """Count the input's obstacles and those the decoded map kept (the issue's measure), and
    the step cells (``step_disc_m``, default the threshold: one wheel diameter) kept.
    ``reference``: the input's (relief, step), when already computed. ``relief_threshold``
    (per cell, as :func:`classify` takes it: a reduction whose relief hazards are read across
    the ground): reliefs are read across the ground, ``relief x threshold / relief_threshold``
    (the original map's slope for both maps), obstacles and losses included."""
    from scipy import ndimage

    sd = threshold_m if step_disc_m is None else step_disc_m
    r0, s0 = reference if reference is not None else (relief(z, cell_m, disc_m), step(z, cell_m, sd))
    r1 = relief(decoded, cell_m, disc_m)
    if relief_threshold is not None:
        across = threshold_m / np.asarray(relief_threshold, np.float64)
        r0, r1 = (r0 * across).astype(np.float32), (r1 * across).astype(np.float32)
    s1 = step(decoded, cell_m, sd)
    with np.errstate(invalid="ignore"):
        haz0 = r0 >= threshold_m
        haz1 = r1 >= threshold_m
        st0 = s0 >= threshold_m
    steps: dict[str, Any] = {
        "step_cells": int(st0.sum()),
        "step_kept": float((s1[st0] >= threshold_m).mean()) if st0.any() else 1.0,
        "worst_step_loss_m": float((s0 - s1)[st0].max()) if st0.any() else 0.0}
    lab1, n1 = ndimage.label(haz1, structure=np.ones((3, 3)))
    touching = np.unique(lab1[haz0 & haz1])
    steps["new_obstacles"] = int(n1 - np.count_nonzero(touching))
    lab, n = ndimage.label(haz0, structure=np.ones((3, 3)))
    if n == 0:
        return ObstacleCheck(0, 0, 0, 0, 0.0, 0.0, 1.0, 0.0, **steps)
    idx = np.arange(1, n + 1)
    r0f = np.where(haz0, r0, -np.inf)
    r1f = np.where(np.isfinite(r1), r1, -np.inf)
    peak0 = np.asarray(ndimage.maximum(r0f, lab, idx))
    peak1 = np.asarray(ndimage.maximum(r1f, lab, idx))
    kept = peak1 >= threshold_m
    big = peak0 >= 2 * threshold_m
    # Position: distance from each obstacle's input peak cell to the nearest decoded hazard cell.
    pos = np.asarray(ndimage.maximum_position(r0f, lab, idx))
    if haz1.any():
        dist = ndimage.distance_transform_edt(~haz1)
        pos_err = float(dist[pos[:, 0], pos[:, 1]].max())
    else:
        pos_err = float("inf")
    loss = (r0 - r1)[haz0]
    return ObstacleCheck(n=int(n), kept=int(kept.sum()), n_2x=int(big.sum()), kept_2x=int((kept & big).sum()),
                         worst_peak_loss_m=float((peak0 - peak1).max()),
                         worst_relief_loss_m=float(loss.max()) if loss.size else 0.0,
                         footprint_kept=float(haz1[haz0].mean()), position_error_cells=pos_err, **steps)
