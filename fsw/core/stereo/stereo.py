"""Dense stereo: a rectified pair to 3-D points with a covariance each (docs/algorithm.md §4, §1.2).

The left camera is the reference (``fsw.core.geometry``). OpenCV's semi-global block
matcher (SGBM) gives a disparity ``d`` per left pixel ``(u, v)``; a point in the camera
frame is

    Z = f B / d,   X = (u - cx) Z / f,   Y = (v - cy) Z / f.

On a calibrated head the pair is first rectified (``fsw.core.stereo.rectify``) and ``f``, ``cx``,
``cy``, ``B`` are the rectified camera's (``RectifiedCamera``); the points are then rotated
from the rectified left frame back to the physical left camera, ``x = R1^T x_rect``, and
their covariances with them.

Its covariance is first-order propagation of independent pixel noise on ``u``, ``v`` (the
pixel localisation, ``sigma_pixel_px``) and on ``d``: ``Sigma_c = J diag(su^2, sv^2, sd^2)
J^T``, with ``sd`` the **per-pixel** disparity sigma of ``fsw.core.stereo.stereo_quality`` (from the
window's least-squares fit and the local disparity spread). Its depth part is the
range-squared law of §1.2, ``sigma_Z = Z^2 sigma_d / (f B)``.

A pixel gives no point unless the match is trustworthy. The filters, in order:
  * uniqueness: the best matching cost beats the second best by ``uniqueness_ratio_pct``
    (OpenCV's ``disp12MaxDiff`` left-right check is passed on too, but measured to change
    nothing in OpenCV's SGBM modes: docs/perception.md);
  * correlation: the normalised cross-correlation of the windows at the match reaches
    ``min_ncc`` (a textureless window correlates like noise; gain invariant, so the same
    threshold holds on real cameras; an absolute ``texture_threshold`` is off by default);
  * speckle filter: small connected blobs of disparity are dropped (after the gates, so an
    isolated survivor in a textureless patch goes too);
  * local spread: the valid disparities around the pixel spread less than
    ``max_spread_px`` (an occlusion border or a depth jump);
  * range gate: the depth lies within the camera's ``min_range_m .. max_range_m``.
Before matching, a rig that drifted since its calibration is corrected per pair (vertical
offset, exposure and noise of the right image: ``fsw.core.stereo.rig_drift``).
The filters and the noise model were derived on real rectified pairs with ground truth
(Middlebury 2014 Motorcycle, shipped by scikit-image) and on the renderer: ``safer-hil bench
stereo-real`` prints both.
"""

from __future__ import annotations

from collections.abc import Generator
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import CameraConfig
from fsw.core.steps import run_to_end
from fsw.core.stereo import stereo_quality as quality
from fsw.core.stereo.occlusion import lip_pixels
from fsw.core.stereo.rectify import RectifiedCamera
from fsw.core.stereo.rig_drift import RigAlignment
from fsw.core.stereo.rig_drift import correct_for as correct_drift_steps
from fsw.framework.params import param

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]

_MODES = {"sgbm": cv2.StereoSGBM_MODE_SGBM, "sgbm_3way": cv2.StereoSGBM_MODE_SGBM_3WAY,
          "hh": cv2.StereoSGBM_MODE_HH, "hh4": cv2.StereoSGBM_MODE_HH4}


#: points per slice of the triangulation (row-major chunks; ~10 ms here, a bounded slack slice)
TRIANGULATE_STEP_POINTS = 20000

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
        0.0, lo=0.0, hi=255.0, units="grey/px",
        doc="minimum mean |d I/dx| over the texture window (0: off; min_ncc is the texture gate)",
    )
    texture_window_px: int = param(5, lo=3, hi=31, units="px", doc="odd texture window side")
    min_ncc: float = param(
        0.5, lo=-1.0, hi=1.0, doc="least normalised cross-correlation of the windows at the match",
    )
    ncc_window_px: int = param(7, lo=3, hi=31, units="px", doc="odd correlation window side")
    max_spread_px: float = param(
        2.0, lo=0.0, hi=1000.0, units="px",
        doc="largest std of the valid disparities around a pixel (a depth jump beyond: no point)",
    )
    spread_window_px: int = param(5, lo=3, hi=31, units="px", doc="odd local-spread window side")
    border_px: int = param(4, lo=0, hi=64, units="px", doc="image border that gives no points")
    lip_jump_px: float = param(
        1.0, lo=0.0, hi=1000.0, units="px",
        doc="occluding lip: the disparity drops by more than this within lip_rows_px rows above",
    )
    lip_rows_px: int = param(6, lo=1, hi=64, units="px", doc="rows above a pixel searched for a lip's far side")
    refine_iterations: int = param(
        1, lo=0, hi=5, doc="zero-mean Lucas-Kanade sub-pixel refinement steps after SGBM (0: none)"
    )
    refine_window_px: int = param(5, lo=3, hi=21, units="px", doc="odd refinement window side")
    sigma_floor_px: float = param(
        0.11, lo=0.0, hi=5.0, units="px", doc="per-pixel disparity sigma: the floor (fitted)"
    )
    sigma_ls_gain: float = param(
        1.0, lo=0.0, hi=10.0, doc="per-pixel disparity sigma: gain on the least-squares sigma (fitted)"
    )
    sigma_spread_gain: float = param(
        6.0, lo=0.0, hi=20.0, doc="per-pixel disparity sigma: gain on the excess local spread (fitted)"
    )
    sigma_disparity_px: float = param(
        0.15, lo=0.01, hi=5.0, units="px",
        doc="1-sigma disparity noise where no per-pixel sigma is given (triangulate of a bare disparity)",
    )
    sigma_graze_gain: float = param(
        0.0, lo=0.0, hi=5.0,
        doc="per-pixel disparity sigma: gain on the disparity's span over the matching window (grazing incidence)",
    )
    sigma_pixel_px: float = param(
        0.3, lo=0.0, hi=5.0, units="px", doc="1-sigma pixel localisation noise on u and v"
    )
    drift_correction: bool = param(True, doc="take out the right image's vertical offset and exposure, per pair")
    drift_features: int = param(1000, lo=50, hi=5000, doc="ORB features per image for the vertical offset")
    drift_deadband_px: float = param(0.25, lo=0.0, hi=10.0, units="px", doc="offsets up to this are left alone")
    drift_bound_px: float = param(2.0, lo=0.0, hi=50.0, units="px", doc="an offset beyond: event (recalibrate)")
    exposure_tolerance: float = param(0.05, lo=0.0, hi=1.0, doc="relative grey-level gain difference left alone")
    exposure_offset_dn: float = param(4.0, lo=0.0, hi=255.0, units="DN", doc="mean grey-level difference left alone")
    noise_ratio_max: float = param(1.3, lo=1.0, hi=10.0, doc="right/left noise beyond which the right is smoothed")
    denoise_sigma_px: float = param(0.7, lo=0.0, hi=5.0, units="px", doc="Gaussian smoothing it (0: never)")

    def __post_init__(self) -> None:
        if self.num_disparities_px % 16:
            raise ValueError("num_disparities_px must be a multiple of 16")
        windows = (self.block_size_px, self.texture_window_px, self.refine_window_px,
                   self.ncc_window_px, self.spread_window_px)
        if any(w % 2 == 0 for w in windows):
            raise ValueError("block_size_px and every *_window_px must be odd")
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
    # occluding lips (fsw.core.stereo.occlusion): the lip's point and the farther point above it, (M, 3)
    lip_near_c: F64 = field(default_factory=lambda: np.zeros((0, 3)))
    lip_far_c: F64 = field(default_factory=lambda: np.zeros((0, 3)))

    def __len__(self) -> int:
        return int(self.xyz_c.shape[0])


@dataclass(frozen=True)
class DisparityImage:
    """A matched pair: disparity and its 1-sigma per pixel (both NaN where no point)."""

    disparity_px: F64  # (H, W)
    sigma_px: F64  # (H, W)
    alignment: RigAlignment = field(default_factory=RigAlignment.none)  # the rig-drift correction's figures


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

    @property
    def window_rad(self) -> float:
        """The matching window's angle, ``block_size_px / focal_px`` (of the rectified camera when
        there is one): the width of scene one disparity mixes, per metre of range."""
        f = self.camera.focal_px if self.rectified is None else self.rectified.focal_px
        return float(self.cfg.block_size_px / f)

    def disparity(self, left: U8, right: U8) -> F64:
        """Disparity in pixels for each left pixel; NaN where no trustworthy match."""
        return run_to_end(self.match_steps(left, right)).disparity_px

    def match(self, left: U8, right: U8) -> DisparityImage:
        """Disparity and its per-pixel sigma (:meth:`match_steps` run to the end)."""
        return run_to_end(self.match_steps(left, right))

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
        """:meth:`disparity` as a slack-job generator (see :meth:`match_steps`)."""
        dm = yield from self.match_steps(left, right)
        return dm.disparity_px

    def match_steps(self, left: U8, right: U8) -> Generator[None, None, DisparityImage]:
        """:meth:`match` as a slack-job generator. It yields after each band of each pass (a
        bounded share of the pair): the rig-drift correction (four slices), then SGBM, the
        correlation gate and the refinement, each over the ``band_rows_px`` bands; then the
        local gates, then the sigma (a slice each).
        The correlation and the refinement are row-local (the match moves along rows; the
        windows reach a few rows), so each band is computed with a few rows of context and
        the result equals the whole image's exactly."""
        self._check_pair(left, right)
        cfg = self.cfg
        h = left.shape[0]
        right, alignment = yield from correct_drift_steps(left, right, cfg)  # when drift_correction is on
        raw = np.empty(left.shape, np.int16)
        for start, end, src0, src1 in self.bands(h):
            part = self._sgbm.compute(left[src0:src1], right[src0:src1])
            raw[start:end] = part[start - src0:end - src0]
            yield None
        invalid = (cfg.min_disparity_px - 1) * cv2.StereoMatcher_DISP_SCALE
        lf, rf = left.astype(np.float32), right.astype(np.float32)
        bad = raw <= invalid
        d32 = np.where(bad, 0.0, raw.astype(np.float32) / cv2.StereoMatcher_DISP_SCALE)
        bad |= d32 <= 0.0
        d32 = d32.astype(np.float32)
        margin = cfg.ncc_window_px // 2 + 1
        for start, end, _, _ in self.bands(h):
            s0, s1 = max(0, start - margin), min(h, end + margin)
            c = quality.ncc(lf[s0:s1], rf[s0:s1], d32[s0:s1], cfg.ncc_window_px)
            bad[start:end] |= c[start - s0:end - s0] < cfg.min_ncc
            yield None
        if cfg.texture_threshold > 0.0:
            bad |= ~self.textured(left)
        raw[bad] = invalid
        if cfg.speckle_window_px > 0:
            cv2.filterSpeckles(raw, invalid, cfg.speckle_window_px,
                               cfg.speckle_range_px * cv2.StereoMatcher_DISP_SCALE)
        bad = raw <= invalid
        b = cfg.border_px
        if b:
            bad[:b, :] = bad[-b:, :] = True
            bad[:, :b] = bad[:, -b:] = True
        # SGBM cannot match the left columns that have no partner in the right image.
        bad[:, : cfg.min_disparity_px + cfg.num_disparities_px] = True
        d32 = np.where(bad, 0.0, raw.astype(np.float32) / cv2.StereoMatcher_DISP_SCALE)
        d32 = d32.astype(np.float32)
        refined, sigma_ls = np.empty_like(d32), np.empty_like(d32)
        margin = 2 * (cfg.refine_window_px // 2 + 1) * (cfg.refine_iterations + 1)
        for start, end, _, _ in self.bands(h):
            s0, s1 = max(0, start - margin), min(h, end + margin)
            dr, sl = quality.refine(lf[s0:s1], rf[s0:s1], d32[s0:s1], cfg.refine_window_px,
                                    cfg.refine_iterations)
            refined[start:end], sigma_ls[start:end] = dr[start - s0:end - s0], sl[start - s0:end - s0]
            yield None
        disp = np.where(bad, np.nan, refined.astype(np.float64))
        spread = quality.local_spread(disp, cfg.spread_window_px)
        disp[spread > cfg.max_spread_px] = np.nan
        yield None  # the spread gate and the sigma: ~20 ms together here, a slice each
        span = None
        if cfg.sigma_graze_gain > 0.0:  # grazing incidence: the window mixes a stretched footprint's depths
            span = cfg.block_size_px * quality.disparity_gradient(disp, cfg.spread_window_px)
        sigma = quality.disparity_sigma(sigma_ls, spread, cfg.sigma_floor_px, cfg.sigma_ls_gain,
                                        cfg.sigma_spread_gain, span, cfg.sigma_graze_gain)
        sigma[~np.isfinite(disp)] = np.nan
        return DisparityImage(disp, sigma, alignment)

    def textured(self, image: U8) -> NDArray[np.bool_]:
        """Pixels whose window has enough horizontal gradient to be matched."""
        gx = cv2.Sobel(image, cv2.CV_32F, 1, 0, ksize=3) / 4.0  # grey levels per pixel
        w = self.cfg.texture_window_px
        mean_abs = cv2.boxFilter(np.abs(gx), -1, (w, w), borderType=cv2.BORDER_REFLECT)
        return np.asarray(mean_abs >= self.cfg.texture_threshold)

    def points(self, left: U8, right: U8, stride_px: int = 1) -> StereoPoints:
        """Match the pair and triangulate every valid pixel (every ``stride_px``-th one)."""
        dm = self.match(left, right)
        return self.triangulate(dm.disparity_px, stride_px, dm.sigma_px)

    def triangulate(self, disp: F64, stride_px: int = 1, sigma_px: F64 | None = None) -> StereoPoints:
        """3-D points and covariances from a disparity image (NaN = no match) and its
        per-pixel sigma (None: the constant ``sigma_disparity_px``)."""
        return run_to_end(self.triangulate_steps(disp, stride_px, sigma_px))

    def triangulate_steps(self, disp: F64, stride_px: int = 1, sigma_px: F64 | None = None,
                          step_points: int = TRIANGULATE_STEP_POINTS) -> Generator[None, None, StereoPoints]:
        """:meth:`triangulate`, yielding after each ``step_points`` points (a slice bounded by
        points, not rows: a 120-row band of near ground held 60k points, a 36 ms slice); the
        points come in the same (row-major) order with the same values."""
        if sigma_px is not None and sigma_px.shape != disp.shape:
            raise ValueError(f"sigma_px shape {sigma_px.shape} differs from disparity {disp.shape}")
        if step_points < 1:
            raise ValueError(f"step_points must be >= 1, got {step_points}")
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
        v_all, u_all = np.nonzero(valid)  # row-major: the order of the points
        n = v_all.size  # filled chunk by chunk: no list of parts joined at the end
        xyz_all, cov_all = np.empty((n, 3)), np.empty((n, 3, 3))
        uv_all, d_all = np.empty((n, 2)), np.empty(n)
        for i in range(0, n, step_points):
            j = min(n, i + step_points)
            v, u = v_all[i:j], u_all[i:j]
            d = disp[v, u]
            sd = (np.full(d.shape, self.cfg.sigma_disparity_px) if sigma_px is None
                  else np.nan_to_num(sigma_px[v, u], nan=self.cfg.sigma_disparity_px))
            u = u.astype(np.float64)
            v = v.astype(np.float64)
            z = f * B / d
            xyz = np.column_stack([(u - cx) * z / f, (v - cy) * z / f, z])
            cov = stereo_covariance(u - cx, v - cy, d, f, B, self.cfg.sigma_pixel_px, sd)
            if rect is not None:  # rectified left frame -> physical left camera: x = R1^T x_rect
                R1 = rect.R_rect
                xyz = xyz @ R1
                cov = R1.T @ cov @ R1
            xyz_all[i:j], cov_all[i:j], d_all[i:j] = xyz, cov, d
            uv_all[i:j, 0], uv_all[i:j, 1] = u, v
            yield None
        lv, lu, lfar = lip_pixels(disp, self.cfg.lip_jump_px, self.cfg.lip_rows_px)
        lips = []
        for rows in (lv, lfar):  # the lip's near point and the far ground behind it
            dl = disp[rows, lu]
            zl = f * B / dl
            p = np.column_stack([(lu - cx) * zl / f, (rows - cy) * zl / f, zl])
            lips.append(p if rect is None else p @ rect.R_rect)
        return StereoPoints(xyz_all, cov_all, uv_all, d_all, valid, lips[0], lips[1])

    def _check_pair(self, left: U8, right: U8) -> None:
        shape = (self.camera.height_px, self.camera.width_px)
        for name, img in (("left", left), ("right", right)):
            if not isinstance(img, np.ndarray) or img.dtype != np.uint8 or img.shape != shape:
                got = getattr(img, "shape", None), getattr(img, "dtype", type(img).__name__)
                raise ValueError(f"{name} image must be uint8 of shape {shape}, got {got}")


def stereo_covariance(du: F64, dv: F64, d: F64, f: float, B: float, sigma_px: float, sigma_d: float | F64) -> F64:
    """Camera-frame covariance ``J diag(su^2, sv^2, sd^2) J^T`` per point (§1.2); ``sigma_d``
    is one value or one per point.

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
    """The range-squared law ``sigma_Z = Z^2 sigma_d / (f B)`` of docs/algorithm.md §1.2."""
    z = np.asarray(range_m, dtype=np.float64)
    return z**2 * sigma_d / (camera.focal_px * camera.baseline_m)
