"""A stereo calibration: intrinsics, distortion and extrinsics of the pair (docs/algorithm.md §4).

A calibration is what ``safer-fsw calibrate`` estimates from views of a target and what the
flight software rectifies with (``fsw.core.stereo.rectify``): for each camera the matrix ``K`` and
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
    disparity_offset_sigma_px: float = 0.0  # the calibration's own uncertainty (jackknife), see below

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


def disparity_offset_px(ref: StereoCalibration, other: StereoCalibration, K: F64) -> float:
    """Mean disparity that ``ref``'s rectification (onto the pinhole ``K``) gives to points at
    infinity when the cameras are ``other``: the systematic disparity error of ``ref`` if
    ``other`` were the truth (zero for ``other = ref``). Over a 7x5 grid of image directions."""
    u, v = np.meshgrid(np.linspace(0.1, 0.9, 7) * ref.width_px, np.linspace(0.1, 0.9, 5) * ref.height_px)
    ray = cv2.undistortPoints(np.column_stack([u.ravel(), v.ravel()]).reshape(-1, 1, 2), other.K1, other.D1)
    far = 1e8 * np.column_stack([ray.reshape(-1, 2), np.ones(ray.shape[0])])
    pl = cv2.projectPoints(far, np.zeros(3), np.zeros(3), other.K1, other.D1)[0]
    pr = cv2.projectPoints(far, cv2.Rodrigues(other.R)[0], other.T, other.K2, other.D2)[0]
    R1, R2, _, _, _ = ref.rectification()
    P1 = np.hstack([K, np.zeros((3, 1))])
    ul = cv2.undistortPoints(pl, ref.K1, ref.D1, R=R1, P=P1).reshape(-1, 2)
    ur = cv2.undistortPoints(pr, ref.K2, ref.D2, R=R2, P=P1).reshape(-1, 2)
    return float(np.mean(ul[:, 0] - ur[:, 0]))


def offset_covariance(xyz_w: F64, centre: F64, disparity_px: F64, sigma_px: float) -> F64:
    """World covariance ``(N, 3, 3)`` of points from a disparity offset of ``sigma_px``
    common to the whole image (the calibration's uncertainty, §1.2): an offset ``e`` moves a
    point along its ray by ``-e/d`` of its range, ``J = -(x - c)/d``."""
    v = (np.asarray(xyz_w, np.float64) - centre) / np.asarray(disparity_px, np.float64)[:, None]
    out: F64 = sigma_px**2 * v[:, :, None] * v[:, None, :]
    return out
