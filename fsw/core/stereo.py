"""Dense stereo: a rectified pair to 3-D points with a covariance each (ALGORITHM.md §4, §1.2).

The left camera is the reference (``fsw.core.geometry``). OpenCV's semi-global block
matcher (SGBM) gives a disparity ``d`` per left pixel ``(u, v)``; a point in the camera
frame is

    Z = f B / d,   X = (u - cx) Z / f,   Y = (v - cy) Z / f.

On a calibrated head the pair is first rectified (``fsw.core.rectify``) and ``f``, ``cx``,
``cy``, ``B`` are the rectified camera's (``RectifiedCamera``); the points are then rotated
from the rectified left frame back to the physical left camera, ``x = R1^T x_rect``, and
their covariances with them.

Its covariance is first-order propagation of independent pixel noise on ``u``, ``v`` (the
pixel localisation, ``sigma_pixel_px``) and on ``d`` (the matcher's sub-pixel error,
``sigma_disparity_px``): ``Sigma_c = J diag(su^2, sv^2, sd^2) J^T``. Its depth part is the
range-squared law of §1.2, ``sigma_Z = Z^2 sigma_d / (f B)``.

A pixel gives no point unless the match is trustworthy. The filters, in order:
  * texture: the mean absolute horizontal gradient over the block window must reach
    ``texture_threshold`` (as StereoBM's textureThreshold; SGBM has none), so a
    textureless patch gives nothing, never a guess from image noise;
  * uniqueness: the best matching cost beats the second best by ``uniqueness_ratio_pct``;
  * left-right consistency: the right-to-left disparity agrees within
    ``disp12_max_diff_px`` (OpenCV's disp12MaxDiff check);
  * speckle filter: small connected blobs of disparity are dropped;
  * range gate: the depth lies within the camera's ``min_range_m .. max_range_m``.
"""

from __future__ import annotations

from collections.abc import Generator
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import CameraConfig
from fsw.core.rectify import RectifiedCamera
from fsw.core.steps import run_to_end
from fsw.framework.params import param

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]

_MODES = {
    "sgbm": cv2.StereoSGBM_MODE_SGBM,
    "sgbm_3way": cv2.StereoSGBM_MODE_SGBM_3WAY,
    "hh": cv2.StereoSGBM_MODE_HH,
    "hh4": cv2.StereoSGBM_MODE_HH4,
}


@dataclass(frozen=True)
class StereoConfig:
    """SGBM parameters, validity filters and the stereo noise model (config ``[stereo]``)."""

    mode: str = param("sgbm_3way", choices=tuple(_MODES), doc="OpenCV SGBM variant")
    min_disparity_px: int = param(0, lo=-256, hi=256, units="px")
    num_disparities_px: int = param(
        128, lo=16, hi=512, units="px", doc="disparity search range, a multiple of 16"
    )
    block_size_px: int = param(5, lo=1, hi=21, units="px", doc="odd matching window side")
    p1: int = param(8, lo=0, hi=1000, doc="smoothness penalty P1, per window pixel")
    p2: int = param(32, lo=0, hi=4000, doc="smoothness penalty P2 (> P1), per window pixel")
    pre_filter_cap: int = param(31, lo=1, hi=63)
    uniqueness_ratio_pct: int = param(
        10, lo=0, hi=100, units="%", doc="best cost must beat the second best by this margin"
    )
    disp12_max_diff_px: int = param(
        1, lo=-1, hi=64, units="px", doc="left-right consistency tolerance (-1 disables)"
    )
    speckle_window_px: int = param(
        100, lo=0, hi=10000, units="px", doc="blobs smaller than this are removed (0 disables)"
    )
    speckle_range_px: int = param(2, lo=0, hi=64, units="px", doc="disparity step inside a blob")
    band_rows_px: int = param(
        120, lo=0, hi=4096, units="px",
        doc="SGBM runs on horizontal bands of this many rows, one slack-job slice each (0: whole image)",
    )
    band_margin_px: int = param(
        48, lo=0, hi=512, units="px", doc="rows of context matched above each band and cropped off",
    )
    texture_threshold: float = param(
        4.0, lo=0.0, hi=255.0, units="grey/px",
        doc="minimum mean |d I/dx| over the block window; below it the pixel gives no point",
    )
    texture_window_px: int = param(5, lo=3, hi=31, units="px", doc="odd texture window side")
    border_px: int = param(4, lo=0, hi=64, units="px", doc="image border that gives no points")
    refine_iterations: int = param(
        1, lo=0, hi=5, doc="Lucas-Kanade sub-pixel refinement steps after SGBM (0: none)"
    )
    refine_window_px: int = param(5, lo=3, hi=21, units="px", doc="odd refinement window side")
    refine_max_step_px: float = param(
        0.5, lo=0.05, hi=2.0, units="px", doc="a larger refinement step drops the pixel"
    )
    sigma_disparity_px: float = param(
        0.15, lo=0.01, hi=5.0, units="px", doc="1-sigma sub-pixel disparity noise (calibrated)"
    )
    sigma_pixel_px: float = param(
        0.3, lo=0.0, hi=5.0, units="px", doc="1-sigma pixel localisation noise on u and v"
    )

    def __post_init__(self) -> None:
        if self.num_disparities_px % 16:
            raise ValueError("num_disparities_px must be a multiple of 16")
        if self.block_size_px % 2 == 0 or self.texture_window_px % 2 == 0 or (
                self.refine_window_px % 2 == 0):
            raise ValueError("block_size_px, texture_window_px and refine_window_px must be odd")
        if self.p2 <= self.p1:
            raise ValueError("p2 must exceed p1")


@dataclass(frozen=True)
class StereoPoints:
    """3-D points of one pair in the left camera frame (OpenCV axes), one row per pixel used."""

    xyz_c: F64  # (N, 3) metres
    cov_c: F64  # (N, 3, 3) square metres
    uv: F64  # (N, 2) left-image pixel (u = column, v = row)
    disparity_px: F64  # (N,)
    valid: NDArray[np.bool_]  # (H, W) which pixels produced a point

    def __len__(self) -> int:
        return int(self.xyz_c.shape[0])


class StereoMatcher:
    """SGBM disparity with validity filters and triangulation with covariance (§4, §1.2)."""

    def __init__(self, cfg: StereoConfig, camera: CameraConfig, rectified: RectifiedCamera | None = None) -> None:
        self.cfg = cfg
        self.camera = camera
        self.rectified = rectified  # None: the pair is the nominal pinhole pair of ``camera``
        win = cfg.block_size_px * cfg.block_size_px
        # The speckle filter is connected-component labelling over the whole image: it runs
        # once on the stitched bands (as SGBM itself runs it after its median filter), so
        # the matcher proper has it off.
        self._sgbm = cv2.StereoSGBM.create(
            minDisparity=cfg.min_disparity_px,
            numDisparities=cfg.num_disparities_px,
            blockSize=cfg.block_size_px,
            P1=cfg.p1 * win,
            P2=cfg.p2 * win,
            disp12MaxDiff=cfg.disp12_max_diff_px,
            preFilterCap=cfg.pre_filter_cap,
            uniquenessRatio=cfg.uniqueness_ratio_pct,
            speckleWindowSize=0,
            speckleRange=cfg.speckle_range_px,
            mode=_MODES[cfg.mode],
        )

    def disparity(self, left: U8, right: U8) -> F64:
        """Disparity in pixels for each left pixel; NaN where no trustworthy match."""
        return run_to_end(self.disparity_steps(left, right))

    def bands(self, height: int) -> list[tuple[int, int, int, int]]:
        """The SGBM bands of an image ``height`` rows high: ``(start, end, src_start, src_end)``.

        Rows ``start:end`` of the disparity come from matching rows ``src_start:src_end``:
        ``band_margin_px`` rows of context above (the top-down cost paths start there, not
        at the band) and ``block_size_px // 2 + 2`` below (the matching window and SGBM's
        3x3 median filter); the context rows are cropped off.
        """
        rows = self.cfg.band_rows_px or height
        below = self.cfg.block_size_px // 2 + 2
        out = []
        for start in range(0, height, rows):
            end = min(height, start + rows)
            src0 = 0 if start == 0 else max(0, start - self.cfg.band_margin_px)
            out.append((start, end, src0, min(height, end + below)))
        return out

    def disparity_steps(self, left: U8, right: U8) -> Generator[None, None, F64]:
        """:meth:`disparity` as a slack-job generator: it yields after each SGBM band (a
        bounded share of the pair) and returns the same disparity as :meth:`disparity`."""
        self._check_pair(left, right)
        raw = np.empty(left.shape, np.int16)
        for start, end, src0, src1 in self.bands(left.shape[0]):
            part = self._sgbm.compute(left[src0:src1], right[src0:src1])
            raw[start:end] = part[start - src0:end - src0]
            yield None
        if self.cfg.speckle_window_px > 0:
            cv2.filterSpeckles(
                raw,
                (self.cfg.min_disparity_px - 1) * cv2.StereoMatcher_DISP_SCALE,
                self.cfg.speckle_window_px,
                self.cfg.speckle_range_px * cv2.StereoMatcher_DISP_SCALE,
            )
        disp = raw.astype(np.float64) / cv2.StereoMatcher_DISP_SCALE
        bad = raw <= (self.cfg.min_disparity_px - 1) * cv2.StereoMatcher_DISP_SCALE
        bad |= disp <= 0.0
        bad |= ~self.textured(left)
        b = self.cfg.border_px
        if b:
            bad[:b, :] = bad[-b:, :] = True
            bad[:, :b] = bad[:, -b:] = True
        # SGBM cannot match the left columns that have no partner in the right image.
        bad[:, : self.cfg.min_disparity_px + self.cfg.num_disparities_px] = True
        disp[bad] = np.nan
        if self.cfg.refine_iterations:
            disp = self.refine(left, right, disp)
        return disp

    def refine(self, left: U8, right: U8, disp: F64) -> F64:
        """Sub-pixel refinement: Lucas-Kanade steps on the SSD over the refinement window.

        SGBM interpolates its sub-pixel disparity from three integer costs, which pulls it
        toward integers ("pixel locking", up to 0.15 px here, the same for every pixel of a
        cell and so not averaged out). A step ``dd = -sum(Ix e) / sum(Ix^2)`` on the right
        image resampled at the current disparity removes most of that bias; a step is kept
        only where it lowers the window's SSD (docs/perception.md, "Stereo").
        """
        h, w = left.shape
        lf, rf = left.astype(np.float32), right.astype(np.float32)
        uu, vv = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
        ok = np.isfinite(disp)
        d = np.where(ok, disp, 0.0).astype(np.float32)
        win = (self.cfg.refine_window_px, self.cfg.refine_window_px)
        rw = cv2.remap(rf, uu - d, vv, cv2.INTER_LINEAR)
        e = lf - rw
        ssd = cv2.boxFilter(e * e, -1, win, normalize=False)
        for _ in range(self.cfg.refine_iterations):
            ix = np.asarray(cv2.Sobel(rw, cv2.CV_32F, 1, 0, ksize=3), np.float32) / 8.0
            num = cv2.boxFilter(np.asarray(ix * e, np.float32), -1, win, normalize=False)
            den = cv2.boxFilter(np.asarray(ix * ix, np.float32), -1, win, normalize=False)
            step = -num / np.maximum(den, 1e-6)
            # SGBM's own sub-pixel error is under 0.2 px where it matched well; a larger
            # step means the window disagrees with the match: the pixel is ambiguous
            ok &= np.abs(step) <= self.cfg.refine_max_step_px
            cand = d + np.clip(step, -0.5, 0.5)
            rw2 = cv2.remap(rf, uu - cand, vv, cv2.INTER_LINEAR)
            e2 = lf - rw2
            ssd2 = cv2.boxFilter(e2 * e2, -1, win, normalize=False)
            better = ssd2 < ssd
            d = np.where(better, cand, d)
            rw, e, ssd = np.where(better, rw2, rw), np.where(better, e2, e), np.minimum(ssd, ssd2)
        return np.where(ok, d.astype(np.float64), np.nan)

    def textured(self, image: U8) -> NDArray[np.bool_]:
        """Pixels whose window has enough horizontal gradient to be matched."""
        gx = cv2.Sobel(image, cv2.CV_32F, 1, 0, ksize=3) / 4.0  # grey levels per pixel
        w = self.cfg.texture_window_px
        mean_abs = cv2.boxFilter(np.abs(gx), -1, (w, w), borderType=cv2.BORDER_REFLECT)
        return np.asarray(mean_abs >= self.cfg.texture_threshold)

    def points(self, left: U8, right: U8, stride_px: int = 1) -> StereoPoints:
        """Match the pair and triangulate every valid pixel (every ``stride_px``-th one)."""
        disp = self.disparity(left, right)
        return self.triangulate(disp, stride_px)

    def triangulate(self, disp: F64, stride_px: int = 1) -> StereoPoints:
        """3-D points and covariances from a disparity image (NaN = no match)."""
        return run_to_end(self.triangulate_steps(disp, stride_px))

    def triangulate_steps(self, disp: F64, stride_px: int = 1) -> Generator[None, None, StereoPoints]:
        """:meth:`triangulate`, yielding after each band of ``band_rows_px`` rows; the points
        come in the same (row-major) order with the same values."""
        cam, rect = self.camera, self.rectified
        if rect is None:
            f, B, cx, cy = cam.focal_px, cam.baseline_m, cam.K[0, 2], cam.K[1, 2]
        else:
            f, B, cx, cy = rect.focal_px, rect.baseline_m, rect.cx_px, rect.cy_px
        with np.errstate(invalid="ignore", divide="ignore"):
            depth = f * B / disp
        valid = np.isfinite(depth) & (depth >= cam.min_range_m) & (depth <= cam.max_range_m)
        if stride_px > 1:
            keep = np.zeros_like(valid)
            keep[::stride_px, ::stride_px] = True
            valid &= keep
        parts: list[tuple[F64, F64, F64, F64]] = []
        for start, end, _, _ in self.bands(disp.shape[0]):
            v, u = np.nonzero(valid[start:end])
            v = v + start
            d = disp[v, u]
            u = u.astype(np.float64)
            v = v.astype(np.float64)
            z = f * B / d
            xyz = np.column_stack([(u - cx) * z / f, (v - cy) * z / f, z])
            cov = stereo_covariance(u - cx, v - cy, d, f, B, self.cfg.sigma_pixel_px,
                                    self.cfg.sigma_disparity_px)
            if rect is not None:  # rectified left frame -> physical left camera: x = R1^T x_rect
                R1 = rect.R_rect
                xyz = xyz @ R1
                cov = R1.T @ cov @ R1
            parts.append((xyz, cov, np.column_stack([u, v]), d))
            yield None
        if len(parts) == 1:
            xyz, cov, uv, d = parts[0]
        else:
            xyz, cov, uv, d = (np.concatenate([p[i] for p in parts]) for i in range(4))
        return StereoPoints(xyz, cov, uv, d, valid)

    def _check_pair(self, left: U8, right: U8) -> None:
        shape = (self.camera.height_px, self.camera.width_px)
        for name, img in (("left", left), ("right", right)):
            if not isinstance(img, np.ndarray) or img.dtype != np.uint8 or img.shape != shape:
                got = getattr(img, "shape", None), getattr(img, "dtype", type(img).__name__)
                raise ValueError(f"{name} image must be uint8 of shape {shape}, got {got}")


def stereo_covariance(
    du: F64, dv: F64, d: F64, f: float, B: float, sigma_px: float, sigma_d: float
) -> F64:
    """Camera-frame covariance ``J diag(su^2, sv^2, sd^2) J^T`` per point (§1.2).

    ``du = u - cx`` and ``dv = v - cy`` are pixel offsets from the principal point, ``d`` the
    disparity. With X = B du / d, Y = B dv / d, Z = f B / d the Jacobian rows are
    dX = (B/d, 0, -X/d), dY = (0, B/d, -Y/d), dZ = (0, 0, -Z/d).
    """
    a = B / d
    x, y, z = a * du / d, a * dv / d, f * B / d**2  # -dX/dd, -dY/dd, -dZ/dd
    sp2, sd2 = sigma_px**2, sigma_d**2
    cov = np.empty((d.shape[0], 3, 3))
    cov[:, 0, 0] = a * a * sp2 + x * x * sd2
    cov[:, 1, 1] = a * a * sp2 + y * y * sd2
    cov[:, 2, 2] = z * z * sd2
    cov[:, 0, 1] = cov[:, 1, 0] = x * y * sd2
    cov[:, 0, 2] = cov[:, 2, 0] = x * z * sd2
    cov[:, 1, 2] = cov[:, 2, 1] = y * z * sd2
    return cov


def depth_sigma_m(range_m: F64 | float, camera: CameraConfig, sigma_d: float) -> F64:
    """The range-squared law ``sigma_Z = Z^2 sigma_d / (f B)`` of ALGORITHM.md §1.2."""
    z = np.asarray(range_m, dtype=np.float64)
    return z**2 * sigma_d / (camera.focal_px * camera.baseline_m)
