"""Data reduction of an elevation map into a quadtree of interest regions (docs/algorithm.md §6).

The paper's Figure 5, steps 1-4, on a 2.5D map ``z`` (metres, NaN = unknown):

1. **Low-pass filter** (§6.1): a NaN-aware Gaussian (normalised convolution), so stereo
   noise does not read as terrain.
2. **Adaptive decimation** (§6.2): a grey opening then closing with a square footprint one
   wheel diameter wide removes bumps and pits narrower than the wheel; only those whose
   height stays below ``decimation_height_m`` (default half a wheel) are removed, so a
   narrow but tall rock survives.
3. **Quadtree of interest regions** (§6.3): a quad splits into four iff the Shannon
   entropy (paper Eq. 1, ``H = -sum q_k log2 q_k``) of any child's elevation histogram
   (Eq. 2, ``q_k = f_k / N``, bins one wheel diameter wide) exceeds the quad's own.
   **(choice)** Two more reasons to split make the result safe to drive on: a quad that
   mixes known and unknown cells splits (unknown stays explicit), and a quad that no single
   value on the codec's lattice can represent within the error bound splits. That bound is
   checked against the *original* map, so filtering and decimation never loosen it.
4. **Base transmission data** (§6.4): per leaf, its level and position and the mean of the
   decimated elevation; unknown leaves carry NaN.

Quads at level ``l`` are ``2**l`` cells square and indexed ``(iy, ix)`` on the level grid of
shape ``ceil(ny / 2**l), ceil(nx / 2**l)``; the root is level ``L = ceil(log2(max(ny, nx)))``.
Cells beyond the map edge belong to no quad's statistics, so any map shape works.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
B = NDArray[np.bool_]


@dataclass(frozen=True)
class Quadtree:
    """The reduced map: split flags per level and the base transmission data per leaf.

    ``split[l]`` (bool, level-``l`` grid) is True for quads that exist and split; ``exists[l]``
    marks the quads present in the tree. Leaves are listed level by level from the root
    down, raster order within a level (the order the codec uses).
    """

    shape: tuple[int, int]
    n_levels: int  # root level L; levels are 0..L
    exists: tuple[B, ...]
    split: tuple[B, ...]
    leaf_level: NDArray[np.int8]
    leaf_iy: I64  # in level-grid units
    leaf_ix: I64
    leaf_known: B
    leaf_mean_m: F64  # mean decimated elevation; NaN for unknown leaves
    leaf_lo_m: F64  # every value in [lo, hi] is within the bound of all its known cells
    leaf_hi_m: F64

    @property
    def n_leaves(self) -> int:
        return int(self.leaf_level.size)

    @property
    def reduction_factor(self) -> float:
        """Map cells per transmitted leaf value (the paper's Figure 12 quantity)."""
        return self.shape[0] * self.shape[1] / max(1, self.n_leaves)

    def btd_bytes(self) -> int:
        """Size of the raw base transmission data: per leaf level u8, iy u16, ix u16, mean f32."""
        return 9 * self.n_leaves

    def leaf_id_map(self) -> NDArray[np.int32]:
        """(ny, nx) index of the leaf holding each cell (painted coarse to fine)."""
        grid = np.full((1, 1), -1, np.int32)
        for lvl in range(self.n_levels, -1, -1):
            h, w = self.exists[lvl].shape
            if grid.shape != (h, w):
                grid = np.repeat(np.repeat(grid, 2, axis=0), 2, axis=1)[:h, :w]
            sel = np.flatnonzero(self.leaf_level == lvl)
            grid[self.leaf_iy[sel], self.leaf_ix[sel]] = sel
        return grid

    def paint(self, values: F64) -> F64:
        """Full-resolution map holding each leaf's value (NaN where ``values`` is NaN)."""
        return values[self.leaf_id_map()]


def tree_depth(shape: tuple[int, int]) -> int:
    """Root level ``L``: the smallest with ``2**L >= max(ny, nx)``."""
    return int(max(0, int(np.ceil(np.log2(max(shape))))))


def lowpass(z: F32 | F64, sigma_cells: float) -> F64:
    """NaN-aware Gaussian low-pass (docs/algorithm.md §6.1); unknown cells stay NaN.

    Normalised convolution: blur of the known values over blur of the known mask (float32;
    the result steers the split rule and the leaf means, never the error bound).
    """
    known = np.isfinite(z)
    if sigma_cells <= 0:
        return np.where(known, z, np.nan).astype(np.float64)
    zf = np.where(known, z, 0.0).astype(np.float32)
    num = cv2.GaussianBlur(zf, (0, 0), sigma_cells, borderType=cv2.BORDER_REPLICATE)
    if known.all():
        return num.astype(np.float64)
    den = cv2.GaussianBlur(known.astype(np.float32), (0, 0), sigma_cells,
                           borderType=cv2.BORDER_REPLICATE)
    with np.errstate(invalid="ignore", divide="ignore"):
        sm = num / den
    return np.where(known, np.where(den > 1e-6, sm, zf), np.nan).astype(np.float64)


def decimate(p: F64, footprint_cells: int, max_height_m: float) -> F64:
    """Remove bumps and pits narrower than the wheel and lower than ``max_height_m`` (§6.2)."""
    known = np.isfinite(p)
    if footprint_cells < 2 or max_height_m <= 0 or not known.any():
        return p
    fill = np.where(known, p, np.nanmean(p)).astype(np.float32)
    kernel = np.ones((footprint_cells, footprint_cells), np.uint8)
    opened = cv2.morphologyEx(fill, cv2.MORPH_OPEN, kernel, borderType=cv2.BORDER_REPLICATE)
    closed = cv2.morphologyEx(opened, cv2.MORPH_CLOSE, kernel, borderType=cv2.BORDER_REPLICATE)
    small = np.abs(closed.astype(np.float64) - p) <= max_height_m
    return np.where(known & small, closed, p)


def _pool(a: NDArray[Any], fn: np.ufunc, fill: float) -> NDArray[Any]:
    """2x2 reduction over the last two axes (odd edges padded with ``fill``)."""
    h, w = a.shape[-2:]
    if h % 2 or w % 2:
        pad = [(0, 0)] * (a.ndim - 2) + [(0, h % 2), (0, w % 2)]
        a = np.pad(a, pad, constant_values=fill)
    return fn(fn(a[..., 0::2, 0::2], a[..., 1::2, 0::2]), fn(a[..., 0::2, 1::2], a[..., 1::2, 1::2]))


_C = np.arange(4097, dtype=np.float64)
_CLOGC = _C * np.log2(np.maximum(_C, 1.0))  # c log2 c for small counts


class EntropyPyramid:
    """Shannon entropy (bits, paper Eq. 1-2) of every quad's elevation-bin histogram.

    ``bins`` holds each known cell's bin index (bins one wheel diameter wide); unknown cells
    are not counted. Level 1 (2x2 quads) uses pairwise comparisons; from level 2 up the
    per-bin counts (layout ``(bin, iy, ix)``) are summed 2x2 from level to level, so each
    level costs a few vectorised operations on its own grid.
    """

    def __init__(self, bins: I64, known: B) -> None:
        ny, nx = bins.shape
        nb = int(bins[known].max()) + 1 if known.any() else 1
        small: Any = np.int16 if nb < 2**15 else np.int64
        self._bins: NDArray[Any] = np.where(known, bins, -1).astype(small)
        h2, w2 = -(-ny // 4), -(-nx // 4)
        it: Any = np.int32 if nb * h2 * w2 < 2**31 else np.int64
        rows: NDArray[Any] = (np.arange(ny, dtype=it) >> 2) * w2
        cols: NDArray[Any] = np.arange(nx, dtype=it) >> 2
        key: NDArray[Any] = bins.astype(it) * (h2 * w2) + (rows[:, None] + cols[None, :])
        key = key.ravel() if known.all() else key[known]
        self._counts = np.bincount(key, minlength=nb * h2 * w2).reshape(nb, h2, w2)
        self._level = 2

    def level(self, lv: int) -> F64:
        """Entropy grid of level ``lv`` >= 1 (levels >= 2 must be asked in increasing order)."""
        if lv == 1:
            return self._level1()
        while self._level < lv:
            c = self._counts
            _, h, w = c.shape
            if h % 2 or w % 2:
                c = np.pad(c, ((0, 0), (0, h % 2), (0, w % 2)))
            self._counts = c[:, 0::2, 0::2] + c[:, 1::2, 0::2] + c[:, 0::2, 1::2] + c[:, 1::2, 1::2]
            self._level += 1
        c = self._counts
        n = c.sum(axis=0)
        top = 1 << (2 * lv)  # a level-lv quad holds at most 4**lv cells
        if top <= 4096:
            s = _CLOGC[:top + 1][c].sum(axis=0)
        else:
            cf = c.astype(np.float64)
            s = (cf * np.log2(np.maximum(cf, 1.0))).sum(axis=0)
        return np.maximum(np.log2(np.maximum(n, 1)) - s / np.maximum(n, 1), 0.0)

    def _level1(self) -> F64:
        b = self._bins
        h, w = b.shape
        if h % 2 or w % 2:
            b = np.pad(b, ((0, h % 2), (0, w % 2)), constant_values=-1)
        quads: list[NDArray[Any]] = [b[0::2, 0::2], b[1::2, 0::2], b[0::2, 1::2], b[1::2, 1::2]]
        lut = np.log2(np.array([1.0, 1.0, 2.0, 3.0, 4.0]))
        s = np.zeros(quads[0].shape)
        n = np.zeros(quads[0].shape)
        for qi in quads:
            same = (qi == quads[0]).view(np.int8) + (qi == quads[1]).view(np.int8) \
                + (qi == quads[2]).view(np.int8) + (qi == quads[3]).view(np.int8)
            s += np.where(qi >= 0, lut[same], 0.0)  # an unknown cell (-1) only equals unknowns
            n += qi >= 0
        return np.maximum(np.log2(np.maximum(n, 1)) - s / np.maximum(n, 1), 0.0)


def build_quadtree(
    z: F32 | F64,
    *,
    wheel_diameter_m: float,
    cell_m: float,
    error_bound_m: float,
    quant_step_m: float = 0.0,
    z_offset_m: float = 0.0,
    lowpass_sigma_cells: float = 1.0,
    decimation_height_m: float | None = None,
    split_rule: str = "entropy",
    cell_lo_m: F64 | None = None,
    cell_hi_m: F64 | None = None,
) -> Quadtree:
    """Reduce ``z`` to a quadtree of interest regions (docs/algorithm.md §6, steps 1-4).

    ``split_rule``: ``"entropy"`` is the paper's rule plus the two safety reasons (module
    docstring); ``"bound"`` splits only for unknown/known mixing and the error bound.
    A leaf is accepted only if some value ``z_offset_m + k * quant_step_m`` (any value when
    ``quant_step_m`` is 0) lies within ``error_bound_m`` of every known original cell in it,
    or, when ``cell_lo_m`` and ``cell_hi_m`` are given, inside every known cell's own interval
    ``[cell_lo_m, cell_hi_m]`` (the hazard-preserving intervals of ``fsw.core.codec.hazard``).
    """
    if z.ndim != 2 or z.size == 0:
        raise ValueError(f"expected a non-empty 2-D map, got shape {z.shape}")
    if wheel_diameter_m <= 0 or cell_m <= 0 or error_bound_m <= 0 or quant_step_m < 0:
        raise ValueError("wheel diameter, cell size and error bound must be positive")
    if split_rule not in ("entropy", "bound"):
        raise ValueError(f"unknown split rule {split_rule!r}")
    z64 = np.asarray(z, np.float64)
    known0 = np.isfinite(z64)
    shape = (int(z.shape[0]), int(z.shape[1]))
    L = tree_depth(shape)
    d = decimate(
        lowpass(z64, lowpass_sigma_cells),
        max(1, int(round(wheel_diameter_m / cell_m))),
        0.5 * wheel_diameter_m if decimation_height_m is None else decimation_height_m,
    )
    bins = np.zeros(shape, np.int64)
    if known0.any():
        bins[known0] = np.floor((d[known0] - np.nanmin(d)) / wheel_diameter_m).astype(np.int64)

    # Bottom-up statistics per level: the intersection of the cells' feasible intervals (as
    # min of hi and of -lo), known and unknown cell counts, sum of the decimated map over known cells.
    if cell_lo_m is None or cell_hi_m is None:
        cell_lo_m, cell_hi_m = z64 - error_bound_m, z64 + error_bound_m
    ext = [np.stack([np.where(known0, cell_hi_m, np.inf), np.where(known0, -cell_lo_m, np.inf)])]
    cnt = [np.stack([known0, ~known0]).astype(np.int32)]
    dsum = [np.where(known0, d, 0.0)]
    for _ in range(L):
        ext.append(_pool(ext[-1], np.minimum, np.inf))
        cnt.append(_pool(cnt[-1], np.add, 0))
        dsum.append(_pool(dsum[-1], np.add, 0.0))
    nkn = [c[0] for c in cnt]
    lo = [-e[1] for e in ext]
    hi = [e[0] for e in ext]

    def feasible(lv: int) -> B:
        if quant_step_m <= 0:
            return lo[lv] <= hi[lv]
        with np.errstate(invalid="ignore"):
            c_lo = np.ceil((lo[lv] - z_offset_m) / quant_step_m)
            c_hi = np.floor((hi[lv] - z_offset_m) / quant_step_m)
        return c_lo <= c_hi

    want: list[B] = [np.zeros(shape, bool)]
    pyramid = EntropyPyramid(bins, known0) if split_rule == "entropy" else None
    ent_child = np.zeros(shape)
    for lv in range(1, L + 1):
        rule = (nkn[lv] > 0) & ((cnt[lv][1] > 0) | ~feasible(lv))
        if pyramid is not None:
            ent = pyramid.level(lv)
            rule |= _pool(ent_child, np.maximum, 0.0) > ent + 1e-9
            ent_child = ent
        want.append(rule)

    exists: list[B] = [np.zeros(0, bool)] * (L + 1)
    split: list[B] = [np.zeros(0, bool)] * (L + 1)
    exists[L] = np.ones((1, 1), bool)
    for lv in range(L, -1, -1):
        split[lv] = exists[lv] & want[lv] if lv > 0 else np.zeros_like(exists[0])
        if lv > 0:
            h, w = nkn[lv - 1].shape
            exists[lv - 1] = np.repeat(np.repeat(split[lv], 2, axis=0), 2, axis=1)[:h, :w]

    lvls, iys, ixs, known_l, mean_l, lo_l, hi_l = [], [], [], [], [], [], []
    for lv in range(L, -1, -1):
        iy, ix = np.nonzero(exists[lv] & ~split[lv])
        n = nkn[lv][iy, ix]
        lvls.append(np.full(iy.size, lv, np.int8))
        iys.append(iy)
        ixs.append(ix)
        known_l.append(n > 0)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean_l.append(np.where(n > 0, dsum[lv][iy, ix] / np.maximum(n, 1), np.nan))
        lo_l.append(lo[lv][iy, ix])
        hi_l.append(hi[lv][iy, ix])
    return Quadtree(
        shape=shape,
        n_levels=L,
        exists=tuple(exists),
        split=tuple(split),
        leaf_level=np.concatenate(lvls),
        leaf_iy=np.concatenate(iys).astype(np.int64),
        leaf_ix=np.concatenate(ixs).astype(np.int64),
        leaf_known=np.concatenate(known_l),
        leaf_mean_m=np.concatenate(mean_l),
        leaf_lo_m=np.concatenate(lo_l),
        leaf_hi_m=np.concatenate(hi_l),
    )
