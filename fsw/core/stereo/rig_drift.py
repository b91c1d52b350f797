"""Online rig-drift correction: a vertical misalignment and an exposure difference of the right
image, measured on every pair and taken out before SGBM (docs/algorithm.md §4).

A rig that drifts after calibration (a knock, heat) leaves a rectified pair whose rows no
longer correspond: SGBM searches along the row only, so a vertical offset of a pixel costs
much of its density. Cameras with their own auto-exposure give the right image another gain
and offset, which the census-like SGBM cost tolerates less than the correlation gate does.

**Vertical misalignment.** ORB features (OpenCV) are matched between the two images (Hamming
distance, cross-checked); matches whose horizontal offset lies within the disparity search
range and whose vertical offset is small are kept. A robust line ``dv = a + b (u - cx)`` of the
vertical offset against the column (a shift and a small roll of the right image) is fitted to
them (median, then least squares on the inliers). The shift ``a`` and the roll's offset at
the image side, ``|b| w / 2``, that exceed ``drift_deadband_px`` are taken out by resampling
the right image (one affine warp); below it the pair is passed on untouched, so an aligned
rig's results do not change. A largest offset ``|a| + |b| w / 2`` above ``drift_bound_px`` is
flagged (``exceeds``) for the task to raise an event: the calibration should be redone.

**Exposure and noise.** The right image's grey levels are mapped linearly so its mean and
standard deviation equal the left's when they differ by more than ``exposure_tolerance``
(relative gain) or ``exposure_offset_dn`` (mean); else it is left untouched. When the right
image is then noisier than the left by more than ``noise_ratio_max`` (pixel noise estimated
from the image Laplacian, Immerkaer's method) it is smoothed by a Gaussian of
``denoise_sigma_px``: a camera with a higher gain no longer loses its weakly textured windows
to the correlation gate.
"""

from __future__ import annotations

import math
from collections.abc import Generator
from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from fsw.core.steps import run_to_end

U8 = NDArray[np.uint8]

#: fewest inlier matches a vertical-offset estimate rests on; fewer: no estimate, no correction
MIN_MATCHES = 20
#: vertical offsets searched (|dv| beyond this is taken for a wrong match)
MAX_DV_PX = 8.0
#: inlier band around the median vertical offset
INLIER_PX = 1.5


@dataclass(frozen=True)
class RigAlignment:
    """What was measured on one pair and what was applied to its right image."""

    dv_px: float  # vertical offset of the right image at the image centre (NaN: not measured)
    roll_px_per_px: float  # its change per column (a roll of the right image)
    matches: int  # inlier feature matches the estimate rests on
    gain: float  # right-image grey-level gain applied (1: none)
    offset_dn: float  # right-image grey-level offset applied (0: none)
    noise_ratio: float  # right-image pixel noise over the left's (after the gain)
    denoised: bool  # the right image was smoothed
    corrected: bool  # the geometric correction was applied
    exceeds: bool  # the offset is beyond the bound: an event, the calibration should be redone

    @classmethod
    def none(cls) -> RigAlignment:
        return cls(math.nan, 0.0, 0, 1.0, 0.0, math.nan, False, False, False)


def estimate_vertical_offset(left: U8, right: U8, min_disparity_px: int, num_disparities_px: int,
                             features: int = 1000) -> tuple[float, float, int]:
    """``(a, b, n)``: the right image's vertical offset ``a + b (u - cx)`` from ``n`` inlier matches
    (``a`` NaN when fewer than :data:`MIN_MATCHES`)."""
    return run_to_end(vertical_offset_steps(left, right, min_disparity_px, num_disparities_px, features))


def vertical_offset_steps(left: U8, right: U8, min_disparity_px: int, num_disparities_px: int,
                          features: int = 1000) -> Generator[None, None, tuple[float, float, int]]:
    """:func:`estimate_vertical_offset` as a slack-job generator: a slice per image's features,
    one for the matching and the fit."""
    orb = cv2.ORB.create(nfeatures=features)
    kl, dl = orb.detectAndCompute(left, None)
    yield None
    kr, dr = orb.detectAndCompute(right, None)
    yield None
    if dl is None or dr is None or len(kl) < MIN_MATCHES or len(kr) < MIN_MATCHES:
        return math.nan, 0.0, 0
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(dl, dr)
    if len(matches) < MIN_MATCHES:
        return math.nan, 0.0, 0
    pl = np.array([kl[m.queryIdx].pt for m in matches], np.float64)
    pr = np.array([kr[m.trainIdx].pt for m in matches], np.float64)
    du, dv = pl[:, 0] - pr[:, 0], pr[:, 1] - pl[:, 1]
    keep = ((du >= min_disparity_px - 1) & (du <= min_disparity_px + num_disparities_px + 1)
            & (np.abs(dv) <= MAX_DV_PX))
    if int(keep.sum()) < MIN_MATCHES:
        return math.nan, 0.0, 0
    u, dv = pl[keep, 0] - left.shape[1] / 2.0, dv[keep]
    inl = np.abs(dv - np.median(dv)) <= INLIER_PX
    if int(inl.sum()) < MIN_MATCHES:
        return math.nan, 0.0, 0
    a_mat = np.column_stack([np.ones(int(inl.sum())), u[inl]])
    (a, b), *_ = np.linalg.lstsq(a_mat, dv[inl], rcond=None)
    return float(a), float(b), int(inl.sum())


def exposure_match(left: U8, right: U8, tolerance: float, offset_dn: float) -> tuple[U8, float, float]:
    """The right image with the left's mean and standard deviation, and the gain and offset applied;
    untouched (gain 1, offset 0) when they already agree within ``tolerance`` and ``offset_dn``."""
    ml, sl = cv2.meanStdDev(left)
    mr, sr = cv2.meanStdDev(right)
    m_l, s_l, m_r, s_r = float(ml[0, 0]), float(sl[0, 0]), float(mr[0, 0]), float(sr[0, 0])
    if s_r <= 1e-6 or s_l <= 1e-6:
        return right, 1.0, 0.0
    gain = s_l / s_r
    off = m_l - gain * m_r
    if abs(gain - 1.0) <= tolerance and abs(m_l - m_r) <= offset_dn:
        return right, 1.0, 0.0
    out = cv2.convertScaleAbs(right, alpha=gain, beta=off)  # saturating to 0..255
    return np.ascontiguousarray(out), gain, off


def noise_sigma(image: U8) -> float:
    """Pixel noise sigma of an image (Immerkaer 1996: the mean absolute response of a Laplacian
    difference that cancels smooth content)."""
    k = np.array([[1.0, -2.0, 1.0], [-2.0, 4.0, -2.0], [1.0, -2.0, 1.0]], np.float32)
    resp = cv2.filter2D(image.astype(np.float32), -1, k)[1:-1, 1:-1]
    if resp.size == 0:
        return 0.0
    return float(math.sqrt(math.pi / 2.0) / 6.0 * np.mean(np.abs(resp)))


def shift_right(right: U8, a: float, b: float) -> U8:
    """The right image resampled so that its rows meet the left's: ``out(u, v) = right(u, v + a + b (u - cx))``."""
    h, w = right.shape
    m = np.array([[1.0, 0.0, 0.0], [b, 1.0, a - b * w / 2.0]], np.float64)
    out = cv2.warpAffine(right, m, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                         borderMode=cv2.BORDER_REPLICATE)
    return np.ascontiguousarray(out)


def correct(left: U8, right: U8, *, min_disparity_px: int, num_disparities_px: int, features: int,
            deadband_px: float, bound_px: float, exposure_tolerance: float, exposure_offset_dn: float,
            noise_ratio_max: float, denoise_sigma_px: float) -> tuple[U8, RigAlignment]:
    """The right image with its exposure (and noise) matched to the left and its vertical offset
    taken out, and what was measured and done (:class:`RigAlignment`)."""
    return run_to_end(correct_steps(
        left, right, min_disparity_px=min_disparity_px, num_disparities_px=num_disparities_px, features=features,
        deadband_px=deadband_px, bound_px=bound_px, exposure_tolerance=exposure_tolerance,
        exposure_offset_dn=exposure_offset_dn, noise_ratio_max=noise_ratio_max, denoise_sigma_px=denoise_sigma_px))


def correct_steps(left: U8, right: U8, *, min_disparity_px: int, num_disparities_px: int, features: int,
                  deadband_px: float, bound_px: float, exposure_tolerance: float, exposure_offset_dn: float,
                  noise_ratio_max: float, denoise_sigma_px: float) -> Generator[None, None, tuple[U8, RigAlignment]]:
    """:func:`correct` as a slack-job generator (a slice each: exposure and noise, each image's
    features, the matching with the fit and the resampling; a pair without features: three)."""
    matched, gain, off = exposure_match(left, right, exposure_tolerance, exposure_offset_dn)
    nl = noise_sigma(left)
    ratio = noise_sigma(matched) / nl if nl > 0.0 else math.nan
    denoise = denoise_sigma_px > 0.0 and math.isfinite(ratio) and ratio > noise_ratio_max
    if denoise:
        matched = np.ascontiguousarray(cv2.GaussianBlur(matched, (0, 0), denoise_sigma_px))
    yield None
    a, b, n = yield from vertical_offset_steps(left, matched, min_disparity_px, num_disparities_px, features)
    if not math.isfinite(a):
        return matched, RigAlignment(math.nan, 0.0, n, gain, off, ratio, denoise, False, False)
    half_w = left.shape[1] / 2.0
    a_fix = a if abs(a) > deadband_px else 0.0  # shift and roll each past the deadband, or left alone
    b_fix = b if abs(b) * half_w > deadband_px else 0.0
    fix = a_fix != 0.0 or b_fix != 0.0
    out = shift_right(matched, a_fix, b_fix) if fix else matched
    yield None
    return out, RigAlignment(a, b, n, gain, off, ratio, denoise, fix, abs(a) + abs(b) * half_w > bound_px)


class DriftKeys(Protocol):
    """The ``[stereo]`` keys the correction reads (``StereoConfig``)."""

    @property
    def drift_correction(self) -> bool: ...
    @property
    def min_disparity_px(self) -> int: ...
    @property
    def num_disparities_px(self) -> int: ...
    @property
    def drift_features(self) -> int: ...
    @property
    def drift_deadband_px(self) -> float: ...
    @property
    def drift_bound_px(self) -> float: ...
    @property
    def exposure_tolerance(self) -> float: ...
    @property
    def exposure_offset_dn(self) -> float: ...
    @property
    def noise_ratio_max(self) -> float: ...
    @property
    def denoise_sigma_px(self) -> float: ...


def correct_for(left: U8, right: U8, cfg: DriftKeys) -> Generator[None, None, tuple[U8, RigAlignment]]:
    """:func:`correct_steps` with the ``[stereo]`` keys of ``cfg`` (a ``StereoConfig``); the pair as it is when
    ``drift_correction`` is off."""
    if not cfg.drift_correction:
        return right, RigAlignment.none()
    return (yield from correct_steps(
        left, right, min_disparity_px=cfg.min_disparity_px, num_disparities_px=cfg.num_disparities_px,
        features=cfg.drift_features, deadband_px=cfg.drift_deadband_px, bound_px=cfg.drift_bound_px,
        exposure_tolerance=cfg.exposure_tolerance, exposure_offset_dn=cfg.exposure_offset_dn,
        noise_ratio_max=cfg.noise_ratio_max, denoise_sigma_px=cfg.denoise_sigma_px))
