"""Fast P_V kernel: every target cell around one camera centre at once (docs/algorithm.md §3.1).

Computes the same quantity as ``visibility.pv_reference`` (read its module docstring for the
model), about 10x faster per cell, for all cells a station can see. Many candidate poses share a
camera centre and differ only in pan/tilt, so ``nbv`` calls this once per centre and then
masks the result by each pan/tilt's field of view.

Design (measured speed and accuracy in docs/nbv.md):

1. Polar rays. The full turn around the camera is cut into ``rays_for_cell`` angular bins
   (``rays_per_turn`` at ``ray_cell_m``, scaled as 1/cell);
   only bins that hold a target are traced. Along each bin's centre ray the exact grid
   traversal (sorted crossings of the x and y grid lines) gives the crossed cells in order
   and the horizontal distance ``r`` of each crossing segment's midpoint: the same samples
   the reference takes for a target lying on that ray.
2. Per sample, with ``g = (z_cam - z_target) / R`` the slope of a target's ray, the factor's
   argument is ``(z_cam - Ob - g r) / s = A - g B`` with ``A = (z_cam - Ob)/s`` and
   ``B = r/s`` that do not depend on the target: they are computed once per sample.
3. Each target cell uses its own slope ``g`` and distance ``R`` on the ray of its angular bin
   (at 4096 bins the bin ray passes within 4 mm of a target 5 m away; cells are 30 mm), and
   sums the samples in front of its own cell (segment midpoint ``< R - half-cell``).
4. Pruning: a sample whose argument exceeds ``prune_z`` for slope ``g`` contributes less than
   3e-5 to ``-log P_V``. Along a ray the running minimum of the slope ``(A - prune_z)/B``
   below which a sample is negligible tells, by a binary search, the first sample that can
   matter for a target; on known terrain that leaves a short window just in front of the
   target (plus the occluders), on unknown terrain most of the ray.
5. Targets are sorted by window length and processed in blocks of about 2^18 (target,
   sample) pairs (:func:`window_sums_steps`); a target's window is one contiguous run of its
   ray's samples, copied as a row of a sliding-window view (no gather per pair); ``log Phi``
   comes from a 1/256-step lookup table; everything is float32 numpy, no Python loop per
   cell or per ray.
"""

from __future__ import annotations

import math
from collections.abc import Generator

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import NDArray
from scipy.special import log_ndtr

from fsw.core.geometry import MapGrid
from fsw.core.planning.visibility import F32, F64, IDX, Terrain, VisibilityConfig, rays_for_cell
from fsw.core.steps import run_to_end

_XMIN, _XMAX, _NPER = -9.0, 6.0, 256  # log Phi table range (sigma) and steps per sigma
_TABLE = log_ndtr(np.arange(_XMIN, _XMAX, 1.0 / _NPER) + 0.5 / _NPER).astype(np.float32)
_TABLE[-1] = 0.0  # arguments >= _XMAX: factor 1
_NT = _TABLE.size
_BLOCK_PAIRS = 1 << 18  # (target, sample) pairs per step: a few ms
_RAYS_PER_STEP = 512  # rays traced per step: a few ms


def unique_inverse(values: NDArray[np.int64], size: int) -> tuple[NDArray[np.int64], NDArray[np.intp]]:
    """``np.unique(values, return_inverse=True)`` for integers in ``[0, size)``, without a sort:
    the sorted distinct values and each value's index among them."""
    present = np.zeros(size, bool)
    present[values] = True
    rank = np.cumsum(present, dtype=np.intp) - 1
    return np.flatnonzero(present).astype(np.int64), rank[values]


def stable_argsort(values: NDArray[np.int64] | NDArray[np.intp]) -> NDArray[np.intp]:
    """``np.argsort(values, kind="stable")`` of non-negative integers: the same permutation, by
    numpy's radix sort when they fit 16 bits."""
    if values.size and int(values.min()) >= 0 and int(values.max()) < 1 << 16:
        return np.argsort(values.astype(np.uint16), kind="stable")
    return np.argsort(values, kind="stable")


def bin_rays(grid: MapGrid, cam_xy: tuple[float, float], angles: F64, rmax_m: float
             ) -> tuple[F32, NDArray[np.int32]]:
    """Grid traversal of rays from ``cam_xy`` at ``angles`` out to ``rmax_m``.

    Returns ``rm`` (rays, L) the horizontal distance of each crossed segment's midpoint
    (nondecreasing along a ray) and ``cell`` the flat index of its cell, ``ncell`` where the
    segment is empty or outside the map.
    """
    c = grid.cell
    dx, dy = np.cos(angles), np.sin(angles)
    fx, fy = (cam_xy[0] - grid.x0) / c, (cam_xy[1] - grid.y0) / c
    n = int(math.ceil(rmax_m / c)) + 2
    m = np.arange(n, dtype=np.float32)[None, :]
    first_x = np.where(dx > 0, math.floor(fx) + 1 - fx, fx - math.floor(fx))[:, None]
    first_y = np.where(dy > 0, math.floor(fy) + 1 - fy, fy - math.floor(fy))[:, None]
    r = np.empty((angles.size, 2 * n), np.float32)
    with np.errstate(divide="ignore"):
        r[:, :n] = (first_x + m) * (c / np.abs(dx))[:, None]
        r[:, n:] = (first_y + m) * (c / np.abs(dy))[:, None]
    r.sort(axis=1, kind="stable")  # two sorted runs (x and y crossings): a merge
    ncol = int(np.searchsorted(r.min(axis=0), rmax_m)) + 1
    r = np.minimum(r[:, :ncol], np.float32(rmax_m))
    rm = np.empty_like(r)
    rm[:, 0] = 0.5 * r[:, 0]
    rm[:, 1:] = 0.5 * (r[:, :-1] + r[:, 1:])
    empty = np.empty(r.shape, bool)
    empty[:, 0] = r[:, 0] <= 1e-6
    empty[:, 1:] = (r[:, 1:] - r[:, :-1]) <= 1e-6
    u = fx + rm * (dx / c).astype(np.float32)[:, None]
    v = fy + rm * (dy / c).astype(np.float32)[:, None]
    out = empty | (u < 0) | (u >= grid.nx) | (v < 0) | (v >= grid.ny)
    cell = v.astype(np.int32) * grid.nx + u.astype(np.int32)
    cell[out] = grid.nx * grid.ny
    return rm, cell


def pv_fast(terrain: Terrain, cam_xyz: tuple[float, float, float], iy: IDX, ix: IDX,
            cfg: VisibilityConfig) -> F64:
    """P_V of the cells ``(iy, ix)`` seen from camera centre ``cam_xyz`` (no FOV culling)."""
    return run_to_end(pv_fast_steps(terrain, cam_xyz, iy, ix, cfg))


def pv_fast_steps(terrain: Terrain, cam_xyz: tuple[float, float, float], iy: IDX, ix: IDX,
                  cfg: VisibilityConfig) -> Generator[None, None, F64]:
    """:func:`pv_fast` as a generator that yields after each bounded step (a chunk of rays or
    a block of pairs, a few ms each) so a slack job can spread it over frames."""
    g = terrain.grid
    cx, cy, cz = (float(v) for v in cam_xyz)
    iy = np.asarray(iy, dtype=np.intp).ravel()
    ix = np.asarray(ix, dtype=np.intp).ravel()
    out = np.ones(iy.size)
    if iy.size == 0:
        return out
    ddx = g.x0 + (ix + 0.5) * g.cell - cx
    ddy = g.y0 + (iy + 0.5) * g.cell - cy
    big_r = np.hypot(ddx, ddy)
    theta = np.arctan2(ddy, ddx)
    nbin = rays_for_cell(cfg, g.cell)
    dth = 2.0 * math.pi / nbin
    used, ray = unique_inverse(np.rint(theta / dth).astype(np.int64) % nbin, nbin)
    half = 0.5 * g.cell / np.maximum(np.abs(np.cos(theta)), np.abs(np.sin(theta)))
    slope = (cz - terrain.elev_m[iy, ix]) / np.maximum(big_r, 1e-9)
    by_ray = stable_argsort(ray)
    rmax = float(big_r.max()) + g.cell
    inv, off, wgt = terrain.packed()
    base = np.zeros(iy.size, np.int64)
    win = np.zeros(iy.size, np.int64)
    parts: list[tuple[F32, F32, F32]] = []
    offset = 0
    yield None  # the set-up above is a step of its own (it sorts every target)
    for r0 in range(0, used.size, _RAYS_PER_STEP):
        r1 = min(used.size, r0 + _RAYS_PER_STEP)
        rm, cell = bin_rays(g, (cx, cy), np.asarray(used[r0:r1] * dth, np.float64), rmax)
        nray, ncol = rm.shape
        inv_s = inv[cell]
        a_s = (np.float32(cz) * inv_s + off[cell]) * np.float32(_NPER) - np.float32(_XMIN * _NPER)
        b_s = rm * inv_s * np.float32(_NPER)
        w_s = wgt[cell]
        # Running minimum of the slope below which a sample is negligible (step 4).
        with np.errstate(divide="ignore", invalid="ignore"):
            q = (a_s - np.float32((cfg.prune_z - _XMIN) * _NPER)) / b_s
        q[~np.isfinite(q) | (w_s == 0)] = np.inf
        np.minimum.accumulate(q, axis=1, out=q)
        t = by_ray[np.searchsorted(ray[by_ray], r0):np.searchsorted(ray[by_ray], r1)]
        lr = ray[t] - r0
        row_r = np.arange(nray) * (float(rm.max()) + 1.0)
        k = np.searchsorted((rm + row_r[:, None]).ravel(), row_r[lr] + big_r[t] - half[t])
        k -= lr * ncol
        row_q = np.arange(nray) * 4.0e6
        neg_q = np.clip(-q, -1.0e6, 1.0e6).astype(np.float64) + row_q[:, None]
        first = np.minimum(np.searchsorted(neg_q.ravel(), row_q[lr] - slope[t]) - lr * ncol, k)
        win[t] = k - first
        base[t] = offset + lr * ncol + first
        parts.append((a_s.ravel(), b_s.ravel(), w_s.ravel()))
        offset += nray * ncol
        yield None

    flat_a, flat_b, flat_w = (np.concatenate([p[i] for p in parts]) for i in range(3))
    yield None
    yield from window_sums_steps(flat_a, flat_b, flat_w, base, win, slope.astype(np.float32), out)
    return out


def window_sums_steps(flat_a: F32, flat_b: F32, flat_w: F32, base: NDArray[np.int64],
                      win: NDArray[np.int64], slope: F32, out: F64) -> Generator[None, None, None]:
    """Step 5 of the module docstring: ``out[t] = exp(sum_{j < win[t]} w log Phi(a - g b))``
    over the samples ``base[t] + j`` of the flat sample arrays (``a``, ``b`` in table units,
    ``w`` the exponent), ``g = slope[t]``; targets with an empty window keep their ``out``.
    Yields after each block of about ``_BLOCK_PAIRS`` pairs.

    Every target's window is a contiguous run of samples: its row is copied out of
    sliding-window views of the arrays (a row copy, not a gather per pair); the arrays are
    padded by the longest window so a row never runs off their end, and a row's columns past
    the target's own window get weight 0."""
    w_max = max(int(win.max(initial=0)), 1)
    rows_a, rows_b, rows_w = (sliding_window_view(np.concatenate([f, np.full(w_max, v, np.float32)]), w_max)
                              for f, v in ((flat_a, 1e9), (flat_b, 0.0), (flat_w, 0.0)))
    order = stable_argsort(win)
    win_sorted = win[order]
    s0, n = int(np.searchsorted(win_sorted, 1)), win.size
    while s0 < n:
        cost = np.arange(1, n - s0 + 1) * win_sorted[s0:]
        s1 = min(n, s0 + max(64, int(np.searchsorted(cost, _BLOCK_PAIRS, "right"))))
        idx = order[s0:s1]
        width = int(win_sorted[s1 - 1])
        b0 = base[idx]
        x = rows_b[b0, :width]  # a copy: x = a - g b, in place
        x *= -slope[idx, None]
        x += rows_a[b0, :width]
        np.clip(x, 0, _NT - 1, out=x)
        vals = np.take(_TABLE, x.astype(np.int32))
        w = rows_w[b0, :width]
        w[np.arange(width)[None, :] >= win[idx, None]] = 0.0
        out[idx] = np.exp(np.einsum("ij,ij->i", vals, w))
        s0 = s1
        yield None
