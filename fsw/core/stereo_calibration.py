"""A stereo calibration: intrinsics, distortion and extrinsics of the pair (ALGORITHM.md §4).

A calibration is what ``safer-fsw calibrate`` estimates from views of a target and what the
flight software rectifies with (``fsw.core.rectify``): for each camera the matrix ``K`` and
the Brown–Conrady distortion ``D = (k1, k2, p1, p2, k3)`` of OpenCV's model, and the pose of
the right camera in the left camera's frame, ``x_right = R x_left + T`` (metres). The left
camera is the reference (``fsw.core.geometry``), so ``T`` is close to ``(-baseline, 0, 0)``.
The file that holds it is read and written by ``fsw.drivers.calibration_file``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]

@dataclass(frozen=True)
class StereoCalibration:
    """Both cameras' intrinsics and distortion, and the right camera in the left frame."""

    width_px: int
    height_px: int
    K1: F64
    D1: F64
    K2: F64
    D2: F64
    R: F64
    T: F64
    rms_px: float = float("nan")
    views: int = 0

    @property
    def baseline_m(self) -> float:
        return float(np.linalg.norm(self.T))

    def rectification(self) -> tuple[F64, F64, F64, F64, F64]:
        """``(R1, R2, P1, P2, Q)`` of ``cv2.stereoRectify`` (zero disparity at infinity,
        ``alpha = 0``: every rectified pixel has a source pixel in both images)."""
        size = (self.width_px, self.height_px)
        out = cv2.stereoRectify(self.K1, self.D1, self.K2, self.D2, size, self.R, self.T,
                                flags=cv2.CALIB_ZERO_DISPARITY, alpha=0.0)
        R1, R2, P1, P2, Q = (np.asarray(m, dtype=np.float64) for m in out[:5])
        return R1, R2, P1, P2, Q
