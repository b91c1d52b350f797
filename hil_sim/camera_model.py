"""The true stereo head of the bench: lenses, misalignment and exposure (``[camera]`` of hil_hardware.toml).

The flight software knows the camera only through its configuration (a nominal pinhole
pair, ``fsw.core.geometry.CameraConfig``) and, on the real path, its calibration file. The
bench's cameras differ from that nominal pair the way a real head does:

* each camera has its own matrix ``K`` (focal length ``focal_scale`` times the nominal one,
  principal point offset by a few pixels) and Brown–Conrady distortion
  ``(k1, k2, p1, p2, k3)`` (OpenCV's model: radial ``1 + k1 r^2 + k2 r^4 + k3 r^6`` and
  tangential ``p1, p2`` terms on normalised coordinates);
* the right camera sits ``baseline_m + baseline_error_m`` along the left camera's ``x`` and
  is rotated by a few tenths of a degree (``right_r*_deg``, about the left camera's axes);
* the right camera's exposure differs by ``right_exposure_ratio``; both have Gaussian noise;
* each pixel integrates the light over its area (``pixel_samples`` squared rays averaged), as
  a sensor does; one ray per pixel (a point sample) aliases fine texture, which the ideal
  pair, sampled exactly on the rectified grid, hides but a rectified pair cannot
  (docs/perception.md, "Camera model").

:class:`TrueCameras` is what the renderer draws with (``hil_sim.render``) and what the
calibration bench compares an estimate with (its :meth:`TrueCameras.truth` is a
:class:`fsw.core.stereo.stereo_calibration.StereoCalibration`). ``model = "ideal"`` gives the
nominal pinhole pair the flight configuration assumes (no calibration needed).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import CameraConfig, CameraPose
from fsw.core.stereo.stereo_calibration import StereoCalibration
from fsw.framework.params import param

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class CameraModelConfig:
    """The bench's true cameras (config ``[camera]`` of hil_hardware.toml)."""

    model: str = param("real", choices=("real", "ideal"),
                       doc="real: lenses, misalignment, exposure below; ideal: the nominal pinhole pair")
    pixel_samples: int = param(2, lo=1, hi=4, doc="rays per pixel side, averaged (pixel-area integration; "
                               "both models); 1: a point sample at the pixel centre")
    noise_sigma: float = param(-1.0, lo=-1.0, hi=50.0, doc="sensor noise, grey levels; negative: the scenario's")
    exposure: float = param(1.3, lo=0.1, hi=5.0, doc="grey levels per unit albedo / 255 (left camera)")
    right_exposure_ratio: float = param(1.0, lo=0.5, hi=2.0, doc="right camera exposure / left")
    focal_scale: float = param(1.0, lo=0.8, hi=1.25, doc="true focal length / the nominal one (left)")
    right_focal_scale: float = param(1.0, lo=0.8, hi=1.25, doc="true focal length / the nominal one (right)")
    cx_offset_px: float = param(0.0, lo=-50.0, hi=50.0, units="px", doc="left principal point offset")
    cy_offset_px: float = param(0.0, lo=-50.0, hi=50.0, units="px")
    right_cx_offset_px: float = param(0.0, lo=-50.0, hi=50.0, units="px")
    right_cy_offset_px: float = param(0.0, lo=-50.0, hi=50.0, units="px")
    k1: float = param(0.0, lo=-1.0, hi=1.0, doc="radial distortion r^2 (both lenses)")
    k2: float = param(0.0, lo=-1.0, hi=1.0, doc="radial distortion r^4")
    p1: float = param(0.0, lo=-0.05, hi=0.05, doc="tangential distortion")
    p2: float = param(0.0, lo=-0.05, hi=0.05, doc="tangential distortion")
    k3: float = param(0.0, lo=-1.0, hi=1.0, doc="radial distortion r^6")
    right_rx_deg: float = param(0.0, lo=-5.0, hi=5.0, units="deg", doc="right camera rotation about left x")
    right_ry_deg: float = param(0.0, lo=-5.0, hi=5.0, units="deg", doc="... about left y")
    right_rz_deg: float = param(0.0, lo=-5.0, hi=5.0, units="deg", doc="... about left z")
    baseline_error_m: float = param(0.0, lo=-0.05, hi=0.05, units="m", doc="true baseline - nominal")


@dataclass(frozen=True, eq=False)
class TrueCameras:
    """Both true cameras: intrinsics, distortion, the right camera's pose and exposures."""

    width_px: int
    height_px: int
    K: tuple[F64, F64]
    dist: tuple[F64 | None, F64 | None]  # None: no distortion (pinhole)
    right_rotation: F64  # right camera axes in the left camera frame (columns)
    baseline_m: float
    exposure: tuple[float, float]
    pixel_samples: int = 1  # rays per pixel side, averaged (the sensor integrates over the pixel)

    @staticmethod
    def from_config(camera: CameraConfig, cfg: CameraModelConfig) -> TrueCameras:
        K0 = camera.K
        if cfg.model == "ideal":
            return TrueCameras(camera.width_px, camera.height_px, (K0, K0), (None, None), np.eye(3),
                               camera.baseline_m, (cfg.exposure, cfg.exposure), cfg.pixel_samples)
        Ks = []
        for scale, dx, dy in ((cfg.focal_scale, cfg.cx_offset_px, cfg.cy_offset_px),
                              (cfg.right_focal_scale, cfg.right_cx_offset_px, cfg.right_cy_offset_px)):
            K = K0.copy()
            K[0, 0] *= scale
            K[1, 1] *= scale
            K[0, 2] += dx
            K[1, 2] += dy
            Ks.append(K)
        D = np.array([cfg.k1, cfg.k2, cfg.p1, cfg.p2, cfg.k3], np.float64)
        rvec = np.radians([cfg.right_rx_deg, cfg.right_ry_deg, cfg.right_rz_deg]).reshape(3, 1)
        rot = cv2.Rodrigues(rvec)[0]
        dist = None if not D.any() else D
        return TrueCameras(camera.width_px, camera.height_px, (Ks[0], Ks[1]), (dist, dist), rot,
                           camera.baseline_m + cfg.baseline_error_m,
                           (cfg.exposure, cfg.exposure * cfg.right_exposure_ratio), cfg.pixel_samples)

    def sampled(self) -> TrueCameras:
        """The same cameras at ``pixel_samples`` times the resolution, one ray per pixel: the
        sub-pixel grid the renderer casts (sub-pixel ``(i, j)`` of pixel ``(u, v)`` has its
        centre at ``u + (i + 0.5) / s - 0.5``)."""
        s = self.pixel_samples
        Ks = []
        for K in self.K:
            Kh = K.copy()
            Kh[:2, :2] *= s
            Kh[:2, 2] = s * K[:2, 2] + (s - 1) / 2.0
            Ks.append(Kh)
        return TrueCameras(self.width_px * s, self.height_px * s, (Ks[0], Ks[1]), self.dist, self.right_rotation,
                           self.baseline_m, self.exposure, 1)

    @property
    def ideal(self) -> bool:
        return all(d is None for d in self.dist) and np.array_equal(self.right_rotation, np.eye(3))

    def right_pose(self, left: CameraPose) -> CameraPose:
        """The right camera's pose for the left camera's pose ``left``."""
        return CameraPose(left.R @ self.right_rotation, left.t + self.baseline_m * left.R[:, 0])

    def truth(self) -> StereoCalibration:
        """The calibration a perfect estimate would find (OpenCV's ``x_r = R x_l + T``)."""
        R = self.right_rotation.T
        T = -R @ np.array([[self.baseline_m], [0.0], [0.0]])
        zero = np.zeros((1, 5))
        d1, d2 = (zero if d is None else d.reshape(1, 5) for d in self.dist)
        return StereoCalibration(self.width_px, self.height_px, self.K[0], d1, self.K[1], d2, R, T)

    def project(self, which: int, pts_c: F64) -> F64:
        """Pixel coordinates ``(N, 2)`` of camera-frame points (``z > 0``) in camera ``which``."""
        d = self.dist[which]
        img, _ = cv2.projectPoints(np.asarray(pts_c, np.float64).reshape(-1, 1, 3), np.zeros(3), np.zeros(3),
                                   self.K[which], np.zeros(5) if d is None else d)
        return np.asarray(img.reshape(-1, 2), np.float64)

