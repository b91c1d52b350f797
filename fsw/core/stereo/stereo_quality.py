"""Per-pixel quality of a stereo match: the gates and the disparity sigma (docs/algorithm.md §1.2, §4).

SGBM gives a disparity per pixel but no measure of how well it is determined. Three quantities,
all computed from the pair and the disparity with a few box filters (no per-pixel loops), give
one; each is invariant to the image's gain and offset, so the same thresholds hold on a real
camera and on the renderer (docs/perception.md, "Per-pixel disparity sigma"):

* **normalised cross-correlation** of the left window with the right window at the matched
  disparity. In a textureless window (sensor noise only) SGBM's choice is arbitrary and the
  NCC is that of two independent noise patches (below 0.45 for 99.9 % of 9x9 windows on the
  renderer); a real match correlates (median 0.96-0.98 on Middlebury and the renderer). It
  replaces an absolute texture threshold, which on a real image with little noise rejects
  good matches on smooth surfaces (half of them on Middlebury Motorcycle);
* **least-squares disparity sigma** of a zero-mean (gain-robust) Lucas-Kanade step on the
  window: ``sigma_ls^2 = s^2 / sum(Ix^2)`` with ``s^2`` the window's residual variance after
  the step. It is the Cramer-Rao form of the matching-cost curvature: a flat cost (weak
  gradient) or a poor fit (large residual) gives a large sigma;
* **local disparity spread**: the RMS deviation of the disparities in a small window from
  their 3x3 means (a plane, however steep its disparity gradient, gives none). Beyond the
  noise (``sigma_ls``) it marks a depth discontinuity or an occlusion border, where SGBM's
  errors concentrate (foreground fattening).

* **disparity gradient** ``|grad d|`` (pixels per pixel): the least-squares plane of the valid
  disparities over a small window. At grazing incidence a pixel's footprint on the surface
  stretches (``Z / (f cos theta)`` long) and the depth changes across the matching window by
  ``W Z tan(theta) / f``: the window's one disparity mixes the depths of a footprint ``W`` pixels
  long, and where the ground is not a plane over that footprint the mix departs from the
  centre's depth. For a plane ``|grad d| = B tan(theta) / Z`` (the disparity's span over the
  window is ``W |grad d|``), so no normal is needed; the departure is taken as uniform over the
  span (docs/algorithm.md §1.2).

The sigma of §1.2 per pixel is ``sigma_d^2 = floor^2 + (g sigma_ls)^2 + c^2 max(0, spread^2 -
(g sigma_ls)^2) + (k W |grad d|)^2``; ``floor``, ``g`` and ``c`` were fitted on Middlebury and
rendered pairs together (``safer-hil bench stereo-real``); ``k`` is 0 (off) by default (a
uniform mix gives ``1 / sqrt(12)``; at 0.2 the rendered pairs hold 99.5 % within 2 sigma).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]


def _grid(shape: tuple[int, ...]) -> tuple[F32, F32]:
    h, w = shape[0], shape[1]
    uu, vv = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    return uu, vv


def warp_right(right: F32, disp: F32) -> F32:
    """The right image resampled at each left pixel's match ``(u - d, v)`` (bilinear)."""
    uu, vv = _grid(right.shape)
    return np.asarray(cv2.remap(right, uu - disp, vv, cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_REPLICATE), np.float32)


def ncc(left: F32, right: F32, disp: F32, window_px: int) -> F32:
    """Normalised cross-correlation of the ``window_px`` windows at the disparity ``disp``
    (0 where either window is flat)."""
    rw = warp_right(right, disp)
    win = (window_px, window_px)
    ml, mr = cv2.boxFilter(left, -1, win), cv2.boxFilter(rw, -1, win)
    vl = cv2.boxFilter(left * left, -1, win) - ml * ml
    vr = cv2.boxFilter(rw * rw, -1, win) - mr * mr
    cov = cv2.boxFilter(left * rw, -1, win) - ml * mr
    den = np.sqrt(np.maximum(vl, 0.0) * np.maximum(vr, 0.0))
    return np.where(den > 1e-3, cov / np.maximum(den, 1e-3), 0.0).astype(np.float32)


def refine(left: F32, right: F32, disp: F32, window_px: int, iterations: int) -> tuple[F32, F32]:
    """Zero-mean Lucas-Kanade sub-pixel refinement and the least-squares sigma per pixel.

    SGBM interpolates its sub-pixel disparity from three integer costs, which pulls it toward
    integers ("pixel locking", up to 0.15 px). A step ``dd = -sum(Ix e) / sum(Ix^2)`` on the
    window's zero-mean residual ``e`` (left minus the resampled right, each less its window
    mean, so a gain or offset between the cameras does not bias it) removes most of that; a
    step (clipped to +-0.5 px) is kept only where it lowers the window's residual. Returns
    the refined disparity and ``sigma_ls = sqrt(s^2 / sum(Ix^2))``, ``s^2`` the residual
    variance (``n - 2`` degrees of freedom: the offset and the step).
    """
    win = (window_px, window_px)
    n = window_px * window_px

    def residual(d: F32) -> tuple[F32, F32, F32]:
        rw = warp_right(right, d)
        e = np.asarray(left - rw, np.float32)
        e = np.asarray(e - cv2.boxFilter(e, -1, win), np.float32)
        return rw, e, np.asarray(cv2.boxFilter(e * e, -1, win, normalize=False), np.float32)

    d = disp
    rw, e, ssd = residual(d)
    for _ in range(iterations):
        ix = np.asarray(cv2.Sobel(rw, cv2.CV_32F, 1, 0, ksize=3), np.float32) / 8.0
        ix = ix - cv2.boxFilter(ix, -1, win)
        num = cv2.boxFilter(ix * e, -1, win, normalize=False)
        den = cv2.boxFilter(ix * ix, -1, win, normalize=False)
        cand = d + np.clip(-num / np.maximum(den, 1e-6), -0.5, 0.5).astype(np.float32)
        rw2, e2, ssd2 = residual(cand)
        better = ssd2 < ssd
        d = np.where(better, cand, d)
        rw, e, ssd = np.where(better, rw2, rw), np.where(better, e2, e), np.minimum(ssd, ssd2)
    ix = np.asarray(cv2.Sobel(rw, cv2.CV_32F, 1, 0, ksize=3), np.float32) / 8.0
    ix = ix - cv2.boxFilter(ix, -1, win)
    den = cv2.boxFilter(ix * ix, -1, win, normalize=False)
    sigma_ls = np.sqrt(np.maximum(ssd, 0.0) / (n - 2) / np.maximum(den, 1e-6))
    return d.astype(np.float32), sigma_ls.astype(np.float32)


def local_spread(disp: F64, window_px: int) -> F32:
    """Local roughness of the disparity: the RMS over a ``window_px`` window of each valid
    pixel's difference from the mean of its valid 3x3 neighbourhood. A plane (any disparity
    gradient, as on ground seen obliquely) gives 0; noise gives about its own std; a depth
    jump or an occlusion border gives a large value on both sides of it."""
    ok = np.isfinite(disp)
    okf = ok.astype(np.float32)
    z = np.where(ok, disp, 0.0).astype(np.float32)
    cnt3 = cv2.boxFilter(okf, -1, (3, 3), normalize=False)
    mean3 = cv2.boxFilter(z, -1, (3, 3), normalize=False) / np.maximum(cnt3, 1.0)
    r2 = np.where(ok, (z - mean3) ** 2, 0.0).astype(np.float32)
    win = (window_px, window_px)
    cnt = cv2.boxFilter(okf, -1, win, normalize=False)
    # OpenCV's box filter keeps running sums: a window of exact zeros (a plane) just past large
    # squares (an occlusion border, a mismatched patch) sums to a residue like -2e-10, not 0
    ms = cv2.boxFilter(r2, -1, win, normalize=False) / np.maximum(cnt, 1.0)
    return np.sqrt(np.maximum(ms, 0.0)).astype(np.float32)


def disparity_gradient(disp: F64, window_px: int) -> F64:
    """``|grad d|`` per pixel (pixels per pixel): the slopes of the least-squares plane through the
    valid disparities of the ``window_px`` window (box filters of the masked sums; 0 where the
    window holds too few valid pixels to fit one). Noise averages down over the window (a
    pixel's own central difference is as noisy as the disparity)."""
    ok = np.isfinite(disp)
    m = ok.astype(np.float64)
    d = np.where(ok, disp, 0.0)
    h, w = disp.shape
    uu, vv = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    win = (window_px, window_px)

    def box(a: F64) -> F64:
        return np.asarray(cv2.boxFilter(a, cv2.CV_64F, win, normalize=False, borderType=cv2.BORDER_CONSTANT))

    n = box(m)
    su, sv, sd = box(m * uu), box(m * vv), box(m * d)
    with np.errstate(invalid="ignore", divide="ignore"):
        mu, mv, md = su / n, sv / n, sd / n
        cuu = box(m * uu * uu) - n * mu * mu
        cvv = box(m * vv * vv) - n * mv * mv
        cuv = box(m * uu * vv) - n * mu * mv
        cud = box(m * uu * d) - n * mu * md
        cvd = box(m * vv * d) - n * mv * md
        det = cuu * cvv - cuv * cuv
        gu = (cvv * cud - cuv * cvd) / det
        gv = (cuu * cvd - cuv * cud) / det
        g = np.hypot(gu, gv)
    enough = (n >= 0.5 * window_px * window_px) & (det > 1e-6)
    return np.asarray(np.where(enough & np.isfinite(g), g, 0.0))


def disparity_sigma(sigma_ls: F32, spread: F32, floor_px: float, ls_gain: float,
                    spread_gain: float, span_px: F64 | None = None, graze_gain: float = 0.0) -> F64:
    """``sqrt(floor^2 + (g sigma_ls)^2 + c^2 max(0, spread^2 - (g sigma_ls)^2) + (k span)^2)``
    (§1.2), ``span = W |grad d|`` the disparity's span over the matching window (None: 0)."""
    ls = ls_gain * sigma_ls.astype(np.float64)
    excess = np.maximum(spread.astype(np.float64) ** 2 - ls * ls, 0.0)
    graze = 0.0 if span_px is None else (graze_gain * span_px) ** 2
    return np.asarray(np.sqrt(floor_px**2 + ls * ls + spread_gain**2 * excess + graze))
