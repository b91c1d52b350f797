"""The ground the Cliff-bot stands on, known by contact (docs/team.md, "The planner").

No camera sees the ground under a robot's body: the body hides it from the RECON-bot's mast
and from the Cliff-bot's own pair, and what the RECON-bot maps there is the body's own box.
Yet the Cliff-bot stands there, so that ground holds it. :func:`fill_under_body` fits a plane
to the known cells of a ring around the body (least squares, trimmed: starting from the cells
near the ring's median height, cells off the plane by more than 3 robust sigma, at least
``max_rms_m``, are dropped and the plane fitted again, so a few cells of the body's edge or
of the face below the lip do not tilt it) and trusts it only when it is known well enough
and flat enough: at least ``min_ring_cells`` inlier cells spread over at least three of four
quadrants, most of the ring's known cells inliers, and an RMS residual within ``max_rms_m``
(a ring across a lip or a rock is not a plane, and nothing is filled). Then the unknown
cells within ``radius_m`` of where the body stands take the plane, and so do the known cells
within ``body_m`` standing above it by more than ``max_rms_m``: the body's box as the
RECON-bot mapped it. Other known cells are never changed (the planner judges them).

:func:`body_height` is the height of the ground under the body where the map does not know
it (what the Cliff-bot's own views are placed on, docs/team.md, "Both agents sense"): the
median of the known cells within ``ring_m`` when they are enough and all round it; else the
height at which its two taut tethers on the map, paid out to the winches' lengths, fit
(:func:`tether_heights`); else that median, else the Anchorbots' ground.

:class:`StoodGround` keeps the ground the body has stood on once it has moved on: the body
measured it by standing on it, and no camera sees it the while (the RECON-bot's map holds the
body's box or nothing there, and its own head looks past its body). Each pose it held gives
the cells under it (``fsw.core.team.climber_ground.standing_cells``) with the heights its map gave
them then, those filled by contact marked so; a later map gets them back where it does not know
them, and a cell known by contact also where the later map stands above it by more than the
flatness the contact was trusted to (the body's box, mapped while it stood there).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import MapGrid
from fsw.core.team.tether import TetherConfig, ZMap, height_at
from fsw.core.team.tether_batch import taut_tethers

F64 = NDArray[np.float64]
B = NDArray[np.bool_]
TETHER_FIT_M = 0.03  # both tethers' lengths within this of the paid-out ones (winch tolerance and map error)


def fill_under_body(z: ZMap, grid: MapGrid, xy: F64, radius_m: float, *, body_m: float = 0.0,
                    ring_m: float = 0.3, min_ring_cells: int = 12, max_rms_m: float = 0.03) -> tuple[F64, int]:
    """``z`` with the ground under a body standing at ``xy`` known by contact (module docstring),
    and how many cells were filled or replaced (0 when the ring cannot be trusted).
    ``body_m``: the radius within which cells above the ring's plane are the body (at least
    ``radius_m``); the ring lies beyond it."""
    out = np.array(z, dtype=np.float64, copy=True)
    x0, y0 = float(xy[0]), float(xy[1])
    body_m = max(body_m, radius_m)
    if not (np.isfinite(x0) and np.isfinite(y0) and radius_m > 0 and ring_m > 0 and np.isfinite(body_m)):
        return out, 0
    reach = body_m + ring_m
    iy0, ix0, _ = grid.cell_index(np.array([x0 - reach, x0 + reach]), np.array([y0 - reach, y0 + reach]))
    r0, r1 = max(0, int(min(iy0))), min(grid.ny, int(max(iy0)) + 1)
    c0, c1 = max(0, int(min(ix0))), min(grid.nx, int(max(ix0)) + 1)
    if r0 >= r1 or c0 >= c1:
        return out, 0
    rows, cols = np.mgrid[r0:r1, c0:c1]
    dx = grid.x0 + (cols + 0.5) * grid.cell - x0
    dy = grid.y0 + (rows + 0.5) * grid.cell - y0
    d = np.hypot(dx, dy)
    patch = out[r0:r1, c0:c1]
    known = np.isfinite(patch)
    ring = known & (d > body_m) & (d <= reach)
    coef = _ring_plane(dx[ring], dy[ring], patch[ring], min_ring_cells, max_rms_m)
    if coef is None:
        return out, 0
    plane = coef[0] * dx + coef[1] * dy + coef[2]
    fill = (~known & (d <= radius_m)) | (known & (d <= body_m) & (patch > plane + max_rms_m))
    patch[fill] = plane[fill]
    return out, int(fill.sum())


def _ring_plane(dx: F64, dy: F64, h: F64, min_cells: int, max_rms_m: float, rounds: int = 4) -> F64 | None:
    """The trimmed least-squares plane ``h = a dx + b dy + c`` of the ring's known cells, or None
    when it cannot be trusted (module docstring)."""
    n = len(h)
    if n < min_cells:
        return None
    a = np.column_stack([dx, dy, np.ones(n)])
    dev = np.abs(h - np.median(h))  # start from the cells near the ring's median height
    inl: B = dev <= 3.0 * 1.4826 * float(np.median(dev)) + max_rms_m
    coef: F64 = np.zeros(3)
    for _ in range(rounds):
        if int(inl.sum()) < min_cells:
            return None
        coef = np.asarray(np.linalg.lstsq(a[inl], h[inl], rcond=None)[0], np.float64)
        res = h - a @ coef
        mad = float(np.median(np.abs(res[inl] - np.median(res[inl]))))
        keep = np.abs(res) <= max(3.0 * 1.4826 * mad, max_rms_m)
        if np.array_equal(keep, inl):
            break
        inl = keep
    if int(inl.sum()) < min_cells or inl.mean() < 0.6:
        return None
    res = (h - a @ coef)[inl]
    rms = float(np.sqrt(np.mean(res**2)))
    quadrants = {(bool(p), bool(q)) for p, q in zip(dx[inl] >= 0, dy[inl] >= 0, strict=True)}
    if len(quadrants) < 3 or not np.isfinite(rms) or rms > max_rms_m:
        return None
    return np.asarray(coef, np.float64)


def tether_heights(z: ZMap, grid: MapGrid, anchors: F64, xy: F64, lengths: tuple[float, float], cfg: TetherConfig,
                   normal: F64, hide_m: float, lo_m: float, hi_m: float, step_m: float = 0.02) -> list[float]:
    """The ground heights under a body at ``xy`` at which its two tethers, taut over the map
    (:func:`fsw.core.team.tether.tether_path`; the cells within ``hide_m`` of ``xy``, its own
    box, hidden), from the exits ``anchors`` to its attachment ``attach_m`` along ``normal``,
    are the paid-out ``lengths`` within :data:`TETHER_FIT_M`: the local minima of the larger
    of the two length residuals over heights ``lo_m .. hi_m`` every ``step_m``. Near a level
    tether two heights fit (above and below the exit); a tether over the lip fits one."""
    if not (np.isfinite(lo_m) and np.isfinite(hi_m) and hi_m > lo_m and all(map(np.isfinite, lengths))):
        return []
    zz = np.array(z, dtype=np.float64, copy=True)
    X, Y = grid.centers()
    zz[np.hypot(X - xy[0], Y - xy[1]) <= hide_m] = np.nan
    hs = np.arange(lo_m, hi_m + 0.5 * step_m, step_m)
    bots = np.column_stack([np.full(len(hs), float(xy[0])), np.full(len(hs), float(xy[1])), hs]) + cfg.attach_m * normal
    ends = np.tile(np.asarray(anchors, float)[:2], (len(hs), 1))
    got = np.array([p[0] for p in taut_tethers(zz, grid, ends, np.repeat(bots, 2, axis=0), cfg.sample_m)])
    r = np.max(np.abs(got.reshape(-1, 2) - np.asarray(lengths, float)[None, :]), axis=1)
    pad = np.concatenate([[np.inf], r, [np.inf]])
    low = (r <= pad[:-2]) & (r <= pad[2:]) & (r <= TETHER_FIT_M)
    out: list[float] = []
    k = 0
    while k < len(hs):  # a run of equal minima (a flat valley) counts once, at its middle
        if low[k]:
            j = k
            while j + 1 < len(hs) and low[j + 1]:
                j += 1
            out.append(float(0.5 * (hs[k] + hs[j])))
            k = j + 1
        else:
            k += 1
    return out


def body_height(z: ZMap, grid: MapGrid, xy: F64, anchors: F64, cfg: TetherConfig, *,
                lengths: tuple[float, float] | None = None, normal: F64 | None = None, hide_m: float = 0.4,
                ring_m: float = 0.5, min_ring_cells: int = 12) -> tuple[float, str]:
    """The ground height under a body at ``xy`` and where it came from (module docstring):
    ``"map"`` (the map knows it there), ``"ring"`` (the median of at least ``min_ring_cells``
    known cells within ``ring_m``, in at least three of four quadrants), ``"tethers"``
    (:func:`tether_heights`, the winches' paid-out ``lengths``; of two fits the one nearer the
    ring's median, or the Anchorbots' ground without one), ``"thin ring"`` (the median of too
    few cells, no tether fit) or ``"anchors"`` (the mean of the Anchorbots' ground: the exits
    ``anchors`` less ``anchor_exit_m``)."""
    h = height_at(z, grid, xy)
    if np.isfinite(h):
        return h, "map"
    X, Y = grid.centers()
    dx, dy = X - float(xy[0]), Y - float(xy[1])
    d = np.hypot(dx, dy)
    zf = np.asarray(z, np.float64)
    near = (d < ring_m) & np.isfinite(zf)
    quadrants = {(bool(p), bool(q)) for p, q in zip(dx[near] >= 0, dy[near] >= 0, strict=True)}
    if int(near.sum()) >= min_ring_cells and len(quadrants) >= 3:
        return float(np.median(zf[near])), "ring"
    ground = float(np.mean(np.asarray(anchors, float)[:, 2])) - cfg.anchor_exit_m
    prior = float(np.median(zf[near])) if near.any() else ground
    if lengths is not None:
        around = np.isfinite(zf) & (d < 3.0)
        lo = min(prior, float(zf[around].min()) if around.any() else prior) - 1.0
        hi = float(np.max(np.asarray(anchors, float)[:, 2])) + 0.5
        up = np.array([0.0, 0.0, 1.0]) if normal is None else np.asarray(normal, float)
        fits = tether_heights(z, grid, anchors, xy, lengths, cfg, up, hide_m, lo, hi)
        if fits:
            return min(fits, key=lambda f: abs(f - prior)), "tethers"
    return prior, ("thin ring" if near.any() else "anchors")


@dataclass
class StoodGround:
    """The ground under every pose the body held (module docstring): a height per cell (NaN
    where it never stood) and whether that height came from contact (the plane under its body)
    rather than from a sensor's map."""

    z: F64
    by_contact: B

    @staticmethod
    def empty(shape: tuple[int, int]) -> StoodGround:
        return StoodGround(np.full(shape, np.nan), np.zeros(shape, bool))

    def record(self, z: ZMap, under: B, contact: B) -> None:
        """The body stands on ``under`` (cells) of map ``z``, whose cells ``contact`` were filled by
        contact: remember their heights (the latest pose wins where two overlap)."""
        zf = np.asarray(z, np.float64)
        at = under & np.isfinite(zf)
        self.z[at] = zf[at]
        self.by_contact[at] = contact[at]

    def restore(self, z: ZMap, max_rms_m: float) -> tuple[F64, B]:
        """``z`` with the ground stood on given back (module docstring), and the cells given."""
        out = np.array(z, dtype=np.float64, copy=True)
        stood = np.isfinite(self.z)
        with np.errstate(invalid="ignore"):
            give = stood & (~np.isfinite(out) | (self.by_contact & (out > self.z + max_rms_m)))
        out[give] = self.z[give]
        return out, give
