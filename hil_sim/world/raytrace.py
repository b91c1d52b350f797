"""Casting camera rays into a heightfield: coarse to fine, vectorised (docs/world.md, "Renderer").

The renderer needs, for every pixel, the first point where its ray meets the terrain. Per
camera:

1. Each ray is clipped to the slab ``z_min <= z <= z_max`` of the terrain and to the grid's
   box: nothing can be hit outside that interval.
2. Coarsest level: one ray per ``16 x 16`` pixel block, sampled densely along its interval;
   the first sample under the terrain brackets the hit.
3. Each finer level (blocks of 4, then single pixels) searches only between the nearest and
   farthest hit of the 3 x 3 coarser rays around it, with as many samples as that interval
   needs (rays are grouped by sample count, one numpy call per group). A ray found under the
   terrain at the start of its bracket, or above it at the end, searches again before or
   beyond the bracket, so occlusion stays exact whatever the coarse level missed, except
   for features thinner than the sample spacing.
4. The bracketing samples are refined by regula falsi (Illinois) to well under a millimetre.

Heights between cell centres are bilinear (``cv2.remap``). Depths ``t`` are along rays whose
camera-frame ``z`` component is 1, i.e. range along the optical axis.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from hil_sim.world.rays import Heightfield, pixel_rays, ray_intervals, sample, subpixel_rays

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
IDX = NDArray[np.intp]

TOP_SAMPLES = 256         # samples per ray of the coarsest level
LEVELS = (16, 4, 2, 1)    # block sizes, coarse to fine
# Interpolate the last level where the depth error dt it costs stays under this times t^2:
# the disparity error is then f * B * dt / t^2, 0.02 px for f * B = 100 px m.
SMOOTH_TOL_PER_M = 2e-4
_LAPLACE = np.array([[0, 1, 0], [1, -4, 1], [0, 1, 0]], np.float32)
REFINE_ITERATIONS = 2
MIN_LOG2_SAMPLES = 2       # at least 2**2 samples per bracket


class _Rays:
    """Rays from one centre in grid coordinates: ``px = px0 + t * dpx`` and so on."""

    def __init__(self, hf: Heightfield, c: F64, d: F32 | None,
                 parts: tuple[F32, F32, F32] | None = None) -> None:
        self.hf = hf
        self.c = c
        self.px0 = np.float32((c[0] - hf.x0) / hf.cell_m - 0.5)
        self.py0 = np.float32((c[1] - hf.y0) / hf.cell_m - 0.5)
        self.z0 = np.float32(c[2])
        if parts is None:
            assert d is not None
            parts = (d[..., 0].reshape(-1), d[..., 1].reshape(-1), d[..., 2].reshape(-1))
            inv = np.float32(1.0 / hf.cell_m)
            parts = (parts[0] * inv, parts[1] * inv, np.ascontiguousarray(parts[2]))
        self.dpx, self.dpy, self.dz = parts

    def subset(self, idx: IDX) -> _Rays:
        return _Rays(self.hf, self.c, None, (self.dpx[idx], self.dpy[idx], self.dz[idx]))

    def above(self, t: F32) -> F32:
        """Height above the terrain at parameters ``t``: ``(m,)`` or ``(n, m)`` (samples
        first, so numpy's inner loops run along the rays)."""
        h = sample(self.hf.z, t * self.dpx + self.px0, t * self.dpy + self.py0)
        f = t * self.dz
        f += self.z0
        f -= h
        return f


def cast_image(hf: Heightfield, c: F64, R: F64, K: F64, width: int, height: int,
               levels: tuple[int, ...] = LEVELS, dist: F64 | None = None) -> tuple[F32, F32]:
    """Depth (range along the optical axis) of each pixel's first terrain hit (NaN if none)
    and the pixel rays ``(height, width, 3)`` (world directions with camera ``z`` = 1);
    ``dist``: the lens distortion of the pixels (``pixel_rays``)."""
    if not levels or levels[-1] != 1 or any(
            a <= b for a, b in zip(levels[:-1], levels[1:], strict=True)):
        raise ValueError(f"levels must decrease to 1 (single pixels), got {levels}")
    c = np.asarray(c, float)
    prev: F32 | None = None
    prev_step = 0
    for step in levels[:-1]:
        wl, hl = -(-width // step), -(-height // step)
        off = (step - 1) / 2.0
        d = pixel_rays(R, K, (step * np.arange(wl) + off).astype(np.float64),
                       (step * np.arange(hl) + off).astype(np.float64), dist)
        lo, hi = ray_intervals(hf, c, d)
        rays = _Rays(hf, c, d)
        if prev is None:
            t = _first_hits(rays, lo.reshape(-1), hi.reshape(-1), fixed=TOP_SAMPLES)
        else:
            rr, cc = np.meshgrid(np.arange(hl), np.arange(wl), indexing="ij")
            near, far, n_miss = _neighbour_hits(prev, prev_step // step, rr, cc)
            a, b = _bracket(near, far, n_miss, lo, hi)
            t = _first_hits(rays, a.reshape(-1), b.reshape(-1), own=(lo.reshape(-1),
                                                                      hi.reshape(-1)))
        prev, prev_step = t.reshape(hl, wl), step
    d = pixel_rays(R, K, np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64), dist)
    if prev is None:
        lo, hi = ray_intervals(hf, c, d)
        t = _first_hits(_Rays(hf, c, d), lo.reshape(-1), hi.reshape(-1),
                        fixed=TOP_SAMPLES)
        return t.reshape(height, width), d
    return _finest(hf, c, d, prev, prev_step), d


def _finest(hf: Heightfield, c: F64, d: F32, tc: F32, factor: int) -> F32:
    """Full-resolution depth from the previous level: where that level's inverse depth is
    locally affine (interpolation error under ``SMOOTH_TOL_PER_M * t^2``) the pixels
    interpolate it; the rest (edges, silhouettes, rough ground, sky) cast their own rays."""
    height, width = d.shape[:2]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = (1.0 / tc).astype(np.float32)
        lap = cv2.filter2D(inv, -1, _LAPLACE, borderType=cv2.BORDER_REPLICATE)
        # Linear interpolation of 1/t at mid-points errs by |lap| / 8 (in 1/t), i.e. by
        # |lap| t^2 / 8 in depth; lap is over the coarse spacing, the pixels half-way.
        rough = ~(np.abs(lap) * (factor * factor / 32.0) <= SMOOTH_TOL_PER_M)  # NaN: rough
    rough_u8 = cv2.dilate(rough.astype(np.uint8), np.ones((3, 3), np.uint8),
                          borderType=cv2.BORDER_REPLICATE)
    hl, wl = tc.shape
    inv_full = cv2.resize(np.nan_to_num(inv, nan=0.0), (wl * factor, hl * factor),
                          interpolation=cv2.INTER_LINEAR)[:height, :width]
    with np.errstate(divide="ignore"):
        t = (1.0 / inv_full).astype(np.float32)
    mask = np.repeat(np.repeat(rough_u8, factor, 0), factor, 1)[:height, :width].astype(bool)
    mask |= ~np.isfinite(t)
    # Pixels outside the outermost coarse centres would be extrapolated: cast them.
    off = (factor - 1) / 2.0
    mask[:, (np.arange(width) < off) | (np.arange(width) > (wl - 1) * factor + off)] = True
    mask[(np.arange(height) < off) | (np.arange(height) > (hl - 1) * factor + off), :] = True
    idx = np.flatnonzero(mask)
    t_flat = t.reshape(-1)
    t_flat[idx] = np.nan
    if idx.size:
        dsel = np.stack([d[..., k].reshape(-1)[idx] for k in range(3)], axis=-1)
        lo, hi = ray_intervals(hf, c, dsel)
        near, far, n_miss = _neighbour_hits(tc, factor, idx // width, idx % width)
        a, b = _bracket(near, far, n_miss, lo, hi)
        t_flat[idx] = _first_hits(_Rays(hf, c, dsel), a, b, own=(lo, hi))
    return t


def _neighbour_hits(tc: F32, factor: int, rows: IDX, cols: IDX) -> tuple[F32, F32, F32]:
    """For finer rays at ``(rows, cols)``: nearest and farthest hit of the 2 x 2 coarser
    rays whose centres enclose each, and how many of those missed."""
    miss = np.isnan(tc)
    kernel = np.ones((2, 2), np.uint8)
    pad = ((0, 1), (0, 1))  # the last coarse row/column encloses the image border alone
    near = cv2.erode(np.pad(np.where(miss, np.inf, tc), pad, mode="edge").astype(np.float32),
                     kernel, anchor=(0, 0), borderType=cv2.BORDER_REPLICATE)
    far = cv2.dilate(np.pad(np.where(miss, -np.inf, tc), pad, mode="edge").astype(np.float32),
                     kernel, anchor=(0, 0), borderType=cv2.BORDER_REPLICATE)
    n_miss = cv2.filter2D(np.pad(miss, pad, mode="edge").astype(np.float32), -1,
                          np.ones((2, 2), np.float32), anchor=(0, 0),
                          borderType=cv2.BORDER_REPLICATE)
    off = (factor - 1) / 2.0
    iv = np.clip(np.floor((rows - off) / factor).astype(np.intp), 0, tc.shape[0] - 1)
    iu = np.clip(np.floor((cols - off) / factor).astype(np.intp), 0, tc.shape[1] - 1)
    return (np.asarray(near[iv, iu], np.float32), np.asarray(far[iv, iu], np.float32),
            np.asarray(n_miss[iv, iu], np.float32))


def _bracket(near: F32, far: F32, n_miss: F32, lo: F32, hi: F32) -> tuple[F32, F32]:
    """Search interval from the neighbours' hits, within the ray's own ``[lo, hi]``."""
    some_miss = n_miss > 0.5
    margin = 0.002 + 0.002 * np.where(some_miss, 0.0, far)
    a = np.where(some_miss, lo, np.maximum(lo, near - margin))
    b = np.where(some_miss, hi, np.minimum(hi, far + margin))
    # Neighbours' hits outside this ray's own interval (it enters the slab later, or leaves
    # the world sooner, e.g. past the last coarse ray at the image border): search it all.
    empty = b <= a
    a, b = np.where(empty, lo, a), np.where(empty, hi, b)
    b = np.where(n_miss > 3.5, -np.inf, b)  # a block of sky stays sky
    return a.astype(np.float32), b.astype(np.float32)


def _first_hits(rays: _Rays, a: F32, b: F32, *, fixed: int = 0,
                own: tuple[F32, F32] | None = None) -> F32:
    """First hit in ``[a, b]`` per ray (NaN if none). With ``own`` (the rays' full intervals)
    a bracket that proves wrong is searched again before or beyond ``[a, b]``."""
    t_out = np.full(a.shape, np.nan, np.float32)
    todo = np.nonzero(b > a)[0]
    a, b = a.copy(), b.copy()
    for _ in range(4):
        if todo.size == 0:
            break
        if fixed:
            groups = [(fixed, todo)]
        else:
            span = b[todo] - a[todo]
            need = span / (0.004 + 0.004 * (a[todo] + 0.5 * span))
            level = np.clip(np.ceil(np.log2(np.maximum(need, 1.0))), MIN_LOG2_SAMPLES, 10
                            ).astype(np.intp)
            present = np.nonzero(np.bincount(level, minlength=11))[0]
            groups = [(2 ** int(k), todo[level == k]) for k in present]
        retry: list[IDX] = []
        for n_s, idx in groups:
            t, status = _march(rays.subset(idx), a[idx], b[idx], n_s)
            t_out[idx] = t
            if own is None:
                continue
            lo, hi = own
            early = idx[(status == 1) & (a[idx] > lo[idx] + 1e-4)]  # under terrain at a
            late = idx[(status == 2) & (b[idx] < hi[idx] - 1e-4)]   # nothing up to b
            b[early], a[early] = a[early], lo[early]
            a[late], b[late] = b[late], hi[late]
            t_out[early] = np.nan
            retry += [early, late]
        todo = np.concatenate(retry) if retry else np.zeros(0, np.intp)
    return t_out


def _march(rays: _Rays, a: F32, b: F32, n: int) -> tuple[F32, NDArray[np.int8]]:
    """Sample ``n`` points per ray in ``[a, b]``; status 0 hit, 1 under at ``a``, 2 none."""
    s = np.linspace(0.0, 1.0, n, dtype=np.float32)[:, None]
    t = a + (b - a) * s                      # (n, m)
    f = rays.above(t)
    below = f <= 0.0
    k = below.argmax(axis=0)
    cols = np.arange(t.shape[1])
    has = below[k, cols]
    status = np.where(has, np.where(k == 0, 1, 0), 2).astype(np.int8)
    t_hit = np.where(status == 1, a, np.nan).astype(np.float32)
    sel = np.nonzero(status == 0)[0]
    if sel.size:
        k1, c1 = k[sel], cols[sel]
        t_hit[sel] = _refine(rays.subset(sel), t[k1 - 1, c1], f[k1 - 1, c1], t[k1, c1],
                             f[k1, c1])
    return t_hit, status


def _refine(rays: _Rays, t1: F32, f1: F32, t2: F32, f2: F32) -> F32:
    """Illinois regula falsi between ``t1`` (above, ``f1 > 0``) and ``t2`` (below)."""
    for _ in range(REFINE_ITERATIONS):
        tn = _secant(t1, f1, t2, f2)
        fn = rays.above(tn)
        up = fn > 0
        # Replace the end on the same side as the new point; halve the other (Illinois).
        t1 = np.where(up, tn, t1)
        t2 = np.where(up, t2, tn)
        f1, f2 = np.where(up, fn, f1 * 0.5), np.where(up, f2 * 0.5, fn)
    return _secant(t1, f1, t2, f2)


def _secant(t1: F32, f1: F32, t2: F32, f2: F32) -> F32:
    denom = f1 - f2
    ok = denom > 1e-12
    return np.where(ok, t1 + f1 * (t2 - t1) / np.where(ok, denom, 1.0), t2).astype(np.float32)


def cast_rays(hf: Heightfield, c: F64, d: F32, samples: int = 1024) -> F32:
    """First terrain hit (``t`` along ``d``; NaN if none) of arbitrary rays ``(n, 3)`` from
    ``c``: a dense fixed-step search, for a few rays (figures, checks), not whole images."""
    d = np.asarray(d, np.float32).reshape(-1, 3)
    c = np.asarray(c, float)
    lo, hi = ray_intervals(hf, c, d)
    hi = np.minimum(hi, lo + 100.0)
    return _first_hits(_Rays(hf, c, d), lo, hi, fixed=samples)


__all__ = ["Heightfield", "cast_image", "cast_rays", "pixel_rays", "ray_intervals", "sample", "subpixel_rays"]
