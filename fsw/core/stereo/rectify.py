"""Stereo rectification on board: raw camera pairs to the ideal pinhole pair SGBM needs (docs/algorithm.md §4).

SGBM (``fsw.core.stereo.stereo``) searches along image rows: it needs a *rectified* pair, two
pinhole cameras with parallel optical axes, equal intrinsics and the baseline along ``x``.
A real head has lens distortion and a slightly rotated right camera. From the calibration
(``fsw.core.stereo.stereo_calibration``) ``cv2.stereoRectify`` gives for each camera a rotation
``R1``/``R2`` to the common rectified orientation and the new projection ``P1``/``P2``;
``cv2.initUndistortRectifyMap`` turns that into a per-pixel lookup, built **once** at
start-up in OpenCV's fixed-point form (``CV_16SC2`` plus interpolation table), so each pair
costs two ``cv2.remap`` calls. :meth:`Rectifier.rectify_steps` remaps in horizontal bands
(one slack-job slice each), the same bands as the matcher.

The rectified projections may be OpenCV's own (``alpha = 0``: the largest view with no
empty pixel) or, as the flight software does, the nominal pinhole camera of the flight
configuration (``K_target``: its focal length from ``hfov_deg``, its centre): then the
rectified pair *is* the camera every other part of the flight software models (view
planning, P_V, the range gate), only the baseline is the calibrated one, ``B = |T|``, and
a few border pixels with no source stay black (no texture: no points).

Triangulation uses the rectified camera: focal length ``f = P1[0, 0]``, principal point
``(P1[0, 2], P1[1, 2])`` and baseline ``B = -P2[0, 3] / P2[0, 0]`` (:class:`RectifiedCamera`;
``Q`` is the same as a matrix).
The points come out in the rectified left frame; ``x_left = R1^T x_rect`` returns them to
the physical left camera, whose pose the mast kinematics give.
"""

from __future__ import annotations

from collections.abc import Generator
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from fsw.core.stereo.stereo_calibration import StereoCalibration

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]


@dataclass(frozen=True)
class RectifiedCamera:
    """The rectified pinhole pair that triangulation uses (§1.2, §4)."""

    focal_px: float
    cx_px: float
    cy_px: float
    baseline_m: float
    R_rect: F64  # rotation from the physical left camera frame to the rectified one (R1)
    offset_sigma_px: float = 0.0  # the calibration's disparity offset sigma (common to every point)


class Rectifier:
    """Rectification maps of one calibrated pair, built once; banded remapping per pair."""

    def __init__(self, cal: StereoCalibration, K_target: F64 | None = None) -> None:
        self.cal = cal
        size = (cal.width_px, cal.height_px)
        R1, R2, P1, P2, Q = cal.rectification()
        if K_target is not None:
            B = cal.baseline_m
            P1 = np.hstack([K_target, np.zeros((3, 1))])
            P2 = np.hstack([K_target, K_target @ np.array([[-B], [0.0], [0.0]])])
            f, cx, cy = K_target[0, 0], K_target[0, 2], K_target[1, 2]
            Q = np.array([[1, 0, 0, -cx], [0, 1, 0, -cy], [0, 0, 0, f], [0, 0, 1 / B, 0]], np.float64)
        self.Q = Q
        self.maps = [
            cv2.initUndistortRectifyMap(K, D, Rr, P, size, cv2.CV_16SC2)
            for K, D, Rr, P in ((cal.K1, cal.D1, R1, P1), (cal.K2, cal.D2, R2, P2))
        ]
        f = float(P1[0, 0])
        self.camera = RectifiedCamera(
            focal_px=f, cx_px=float(P1[0, 2]), cy_px=float(P1[1, 2]),
            baseline_m=float(-P2[0, 3] / P2[0, 0]), R_rect=np.asarray(R1, np.float64),
            offset_sigma_px=float(cal.disparity_offset_sigma_px))
        if not (f > 0 and self.camera.baseline_m > 0):
            raise ValueError("the calibration gives no usable rectified pair (is the right camera on the left?)")

    def rectify(self, left: U8, right: U8) -> tuple[U8, U8]:
        """Both images rectified in one go."""
        gen = self.rectify_steps(left, right, 0)
        try:
            while True:
                next(gen)
        except StopIteration as stop:
            out: tuple[U8, U8] = stop.value
            return out

    def rectify_steps(self, left: U8, right: U8, band_rows_px: int) -> Generator[None, None, tuple[U8, U8]]:
        """Rectify ``left`` and ``right`` in bands of ``band_rows_px`` output rows (0: whole
        image), yielding after each band of both images; bilinear, constant (black) border."""
        h, w = self.cal.height_px, self.cal.width_px
        for name, img in (("left", left), ("right", right)):
            if not isinstance(img, np.ndarray) or img.dtype != np.uint8 or img.shape != (h, w):
                got = getattr(img, "shape", None), getattr(img, "dtype", type(img).__name__)
                raise ValueError(f"raw {name} image must be uint8 of shape {(h, w)} (the calibration's), got {got}")
        out = (np.empty((h, w), np.uint8), np.empty((h, w), np.uint8))
        rows = band_rows_px or h
        for start in range(0, h, rows):
            end = min(h, start + rows)
            for src, dst, (m1, m2) in zip((left, right), out, self.maps, strict=True):
                dst[start:end] = cv2.remap(src, m1[start:end], m2[start:end], cv2.INTER_LINEAR,
                                           borderMode=cv2.BORDER_CONSTANT)
            yield None
        return out
