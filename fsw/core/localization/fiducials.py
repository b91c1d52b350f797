"""Relative localization of the Cliff-bot from its ArUco fiducials (docs/algorithm.md §5).

The RECON-bot is the origin (its start pose defines the world frame). Its camera sees the
Cliff-bot's markers; their corners, whose positions on the Cliff-bot body are known
(``CliffbotLayout``, from config), give the body's pose by PnP: the corners of every
visible marker in one least-squares problem, in the left image and, when given, the right
one too (the known baseline fixes the scale much better than one 40-pixel marker can).
The body pose in the world is then ``T_world_body = T_world_cam * T_cam_body``, with the
covariance of both factors propagated (module ``fsw.core.localization.localization`` conventions).

Detection uses ``cv2.aruco.ArucoDetector``. Corner refinement matters: on the bench images
the ``subpix`` and ``contour`` refinements put corners 0.3-0.8 px inside the marker, which
reads as a target 1-2 cm too far at 3 m; ``apriltag`` (edge-line fit) is unbiased to
0.05 px and is the default (docs/perception.md, "Localization").

A far marker is small: an 18 cm one is 12-15 px on a side at 8-10 m, 2-2.5 px per cell of its
grid, and the detector's thresholding and quad fit lose most of them. When fewer than two known
markers are found (none of them ``SMALL_PX`` or more on a side), the image is searched again
enlarged ``fiducial_upsample`` times (bicubic) by a detector tuned for small quads (finer
adaptive-threshold windows, a looser polygon fit, 8 px per cell when reading the bits); its
corners are scaled back. The pass with more known
markers is used, and the right image is searched the same way.

One marker is a planar target with two mirror poses; far and small, both fit its corners and
the marker alone cannot tell them apart. The mirror pose tilts the body by tens of degrees
(the reflection of the marker's normal about the line of sight: a side marker seen 15 deg from
above comes out tilted about 30 deg). A fix request that carries the Cliff-bot's roll and pitch
(its attitude sensor) therefore settles it: a candidate whose tilt disagrees with that gravity
beyond the chi-square gate is no fix of the body (docs/algorithm.md §5.3, :func:`tilt_agrees`).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import CameraPose, normal_from_attitude
from fsw.core.localization.localization import (
    LocalizationConfig,
    PoseEstimate,
    pnp_candidates,
    pnp_jacobian,
    skew,
    so3_exp,
    so3_log,
)
from fsw.framework.params import param

F64 = NDArray[np.float64]
_S45 = float(np.sqrt(0.5))
SMALL_PX = 30.0  # a marker this large on a side is found without the enlarged pass
# a mirror pose whose corners' chi-square (in the corners' noise, corner_sigma_px) is within this
# of the chosen pose's is as likely (likelihood ratio exp(-1/2) or more): no fix
MIRROR_CHI2 = 1.0
_REFINE = {"none": cv2.aruco.CORNER_REFINE_NONE, "subpix": cv2.aruco.CORNER_REFINE_SUBPIX,
           "contour": cv2.aruco.CORNER_REFINE_CONTOUR, "apriltag": cv2.aruco.CORNER_REFINE_APRILTAG}


@dataclass(frozen=True)
class CliffbotLayout:
    """Where the markers sit on the Cliff-bot body (config ``[cliffbot]``).

    Body frame: origin at the footprint centre on the ground, x forward, y left, z up. Each
    marker row is ``(id, cx, cy, cz, rx, ry, rz, dx, dy, dz)``: its centre and the unit
    vectors pointing right and down across its face as seen by a reader. The default is
    the as-built layout of the bench Cliff-bot (front, left, right, 45-degree top plate).
    """

    marker_size_m: float = param(0.18, lo=0.01, hi=2.0, units="m", doc="black square side")
    markers: tuple[tuple[float, ...], ...] = param(
        (
            (1.0, 0.304, 0.0, 0.175, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0),
            (2.0, 0.0, 0.229, 0.175, -1.0, 0.0, 0.0, 0.0, 0.0, -1.0),
            (3.0, 0.0, -0.229, 0.175, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0),
            (4.0, -0.05, 0.0, 0.35 + 0.004 + 0.12 * _S45, 0.0, 1.0, 0.0, _S45, 0.0, -_S45),
        ),
        doc="(id, centre xyz, right xyz, down xyz) per marker, body frame, metres",
    )

    def __post_init__(self) -> None:
        for row in self.markers:
            if len(row) != 10:
                raise ValueError("each marker row needs 10 numbers (id, centre, right, down)")
            r, d = np.array(row[4:7]), np.array(row[7:10])
            if abs(np.linalg.norm(r) - 1) > 1e-3 or abs(np.linalg.norm(d) - 1) > 1e-3 or abs(
                    r @ d) > 1e-3:
                raise ValueError(f"marker {int(row[0])}: right and down must be orthonormal")

    def corners_body(self) -> dict[int, F64]:
        """``{id: (4, 3)}`` corners in ArUco order (top-left, top-right, bottom-right, bottom-left)."""
        h = self.marker_size_m / 2.0
        out = {}
        for row in self.markers:
            c, r, d = np.array(row[1:4]), np.array(row[4:7]), np.array(row[7:10])
            out[int(row[0])] = np.array([c - r * h - d * h, c + r * h - d * h,
                                         c + r * h + d * h, c - r * h + d * h])
        return out


@dataclass(frozen=True)
class BodyEstimate:
    """A body-to-world pose (``R`` body to world, ``t`` body origin) with 6x6 covariance over
    ``(dtheta_world, dt_world)``, and what it was computed from."""

    R: F64
    t: F64
    cov: F64
    marker_ids: tuple[int, ...]
    rms_px: float
    ambiguity: float = float("inf")  # the mirror pose's RMS residual over the chosen one's (inf: none)

    @property
    def yaw(self) -> float:
        return float(np.arctan2(self.R[1, 0], self.R[0, 0]))


class CliffbotLocalizer:
    """Detects the Cliff-bot's markers and solves its pose relative to the RECON-bot (§5)."""

    def __init__(self, cfg: LocalizationConfig, layout: CliffbotLayout, K: F64,
                 baseline_m: float) -> None:
        self.cfg = cfg
        self.K = np.asarray(K, dtype=np.float64)
        self.baseline_m = baseline_m
        self.corners = layout.corners_body()
        try:
            dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, cfg.aruco_dictionary))
        except AttributeError:
            raise ValueError(f"unknown ArUco dictionary {cfg.aruco_dictionary!r}") from None
        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = _REFINE[cfg.corner_refinement]
        self.detector = cv2.aruco.ArucoDetector(dictionary, params)
        small = cv2.aruco.DetectorParameters()  # the enlarged pass (module docstring)
        small.cornerRefinementMethod = _REFINE[cfg.corner_refinement]
        small.polygonalApproxAccuracyRate = 0.06
        small.perspectiveRemovePixelPerCell = 8
        small.adaptiveThreshWinSizeMin, small.adaptiveThreshWinSizeMax, small.adaptiveThreshWinSizeStep = 3, 15, 2
        small.adaptiveThreshConstant = 5
        small.minCornerDistanceRate = small.minMarkerDistanceRate = 0.02
        self.small_detector = cv2.aruco.ArucoDetector(dictionary, small)

    def detect(self, image: NDArray[np.uint8], scale: int = 1) -> dict[int, F64]:
        """``{id: (4, 2) pixel corners}`` of the dictionary's markers in one image (the first of an
        id); ``scale`` > 1: searched enlarged that many times (the small-marker pass), corners in
        the image's own pixels."""
        if scale > 1:
            big = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_CUBIC)
            corners, ids, _ = self.small_detector.detectMarkers(big)
        else:
            corners, ids, _ = self.detector.detectMarkers(image)
        out: dict[int, F64] = {}
        if ids is None:
            return out
        for c, i in zip(corners, ids.reshape(-1), strict=True):
            if int(i) not in out:
                # pixel centres: x_big = scale * (x + 0.5) - 0.5
                out[int(i)] = (np.asarray(c, dtype=np.float64).reshape(4, 2) + 0.5) / scale - 0.5
        return out

    def detect_known(self, known: dict[int, F64], left: NDArray[np.uint8]) -> tuple[dict[int, F64], int]:
        """The markers of ``known`` in ``left`` and the scale they were found at: the image as it is,
        or enlarged ``fiducial_upsample`` times when that finds more of them and fewer than two
        were found as it is, none of them ``SMALL_PX`` or more on a side (module docstring)."""
        seen = {i: c for i, c in self.detect(left).items() if i in known}
        up = int(self.cfg.fiducial_upsample)
        if len(seen) >= 2 or up <= 1 or any(_side_px(c) >= SMALL_PX for c in seen.values()):
            return seen, 1  # (one marker found large: the others, as near, were not missed for size)
        big = {i: c for i, c in self.detect(left, up).items() if i in known}
        return (big, up) if len(big) > len(seen) else (seen, 1)

    def locate(self, left: NDArray[np.uint8], camera: PoseEstimate,
               right: NDArray[np.uint8] | None = None,
               attitude: tuple[float, float] | None = None) -> BodyEstimate | None:
        """The Cliff-bot body pose in the world, or None when too few corners are seen.
        ``attitude``: its roll and pitch (rad, its attitude sensor's convention), when known:
        a pose whose tilt disagrees with them is not the body's (:func:`tilt_agrees`)."""
        agrees = None
        if attitude is not None:
            sigma = math.radians(self.cfg.fiducial_tilt_sigma_deg)
            gate = -2.0 * math.log(1.0 - self.cfg.fiducial_gravity_gate)  # chi-square, 2 dof
            agrees = functools.partial(tilt_agrees, camera, attitude, sigma, gate)
        got = self.camera_in(self.corners, left, right, agrees)
        if got is None:
            return None
        est, ids, ambiguity = got
        return dataclasses.replace(_compose(camera, est, ids), ambiguity=ambiguity)

    def resect(self, known: dict[int, F64], left: NDArray[np.uint8],
               right: NDArray[np.uint8] | None = None) -> PoseEstimate | None:
        """The camera's pose in the frame of ``known`` (``{id: (4, 3) corners}``, markers whose
        corners that frame knows: the Anchorbots' plates, §5.2), or None when none is seen well."""
        got = self.camera_in(known, left, right)
        return None if got is None else got[0]

    def camera_in(self, known: dict[int, F64], left: NDArray[np.uint8], right: NDArray[np.uint8] | None = None,
                  agrees: Callable[[PoseEstimate], bool] | None = None
                  ) -> tuple[PoseEstimate, tuple[int, ...], float] | None:
        """The left camera's pose in the frame the corners ``known`` are given in, the marker ids it
        rests on and its ambiguity (below), or None when too few corners are seen. ``agrees``: a
        test each candidate pose must pass (the gravity of the request, :meth:`locate`); of two
        mirror poses one that fails it is no rival, and none passing is no fix."""
        seen_l, scale = self.detect_known(known, left)
        if not seen_l:
            return None
        ids = sorted(seen_l)
        if len(ids) == 1 and _side_px(seen_l[ids[0]]) < self.cfg.fiducial_min_marker_px:
            return None  # one marker this small: its pose is not to be trusted (fiducial_min_marker_px)
        obj = np.concatenate([known[i] for i in ids])
        img = np.concatenate([seen_l[i] for i in ids])
        # Camera pose in the markers' frame (PnP: the body is the "world" of the problem). One
        # marker alone is planar and has a mirror solution; the right image usually settles it,
        # and when both still fit (a far, small marker) there is no fix (fiducial_ambiguity_ratio).
        cands = pnp_candidates(obj, img, self.K, self.cfg.corner_sigma_px)
        cands = [c for c in cands if c.rms_px <= self.cfg.max_reproj_px]
        if not cands:
            return None
        seen_r = self.detect(right, scale) if right is not None else {}
        both = [i for i in ids if i in seen_r]
        if both:
            obj_r = np.concatenate([known[i] for i in both])
            img_r = np.concatenate([seen_r[i] for i in both])
            cands = [self._refine_stereo(c, obj, img, obj_r, img_r) for c in cands]
        cands = sorted(cands, key=lambda c: c.rms_px)
        if agrees is not None:
            cands = [c for c in cands if agrees(c)]
            if not cands:
                return None  # no pose of the markers stands as gravity says the body does
        est = cands[0]
        if not np.isfinite(est.rms_px) or est.rms_px > self.cfg.max_reproj_px:
            return None
        ambiguity = _ambiguity(cands)
        if ambiguity < self.cfg.fiducial_ambiguity_ratio:
            return None  # one marker, both mirror poses fit: no fix rather than maybe the wrong one
        if math.isfinite(ambiguity) and _chi2_gap(cands, self.cfg.corner_sigma_px) < MIRROR_CHI2:
            # both residuals far under the corners' noise: their ratio says nothing (a 20 px marker
            # at 5.5 m, 0.05 against 0.10 px, passed the ratio with its mirror 57 deg off)
            return None
        # (J^T J)^-1 treats every corner's error as independent, so the covariance shrinks as
        # 1/corners; the errors the corners share (the camera model, the markers' placement
        # on the body) do not, and they dominate a fix of many corners: the covariance stops
        # shrinking at fiducial_shared_residuals residuals (docs/team.md, "Relative localization").
        k = max(1.0, 2.0 * est.n_points / self.cfg.fiducial_shared_residuals)
        return PoseEstimate(est.pose, est.cov * k, est.rms_px, est.n_points), tuple(ids), ambiguity

    def _refine_stereo(self, est: PoseEstimate, obj_l: F64, img_l: F64, obj_r: F64,
                       img_r: F64, iters: int = 10) -> PoseEstimate:
        """Gauss-Newton over the left and right corners together (known baseline)."""
        pose = est.pose

        def residual_and_jacobian(p: CameraPose) -> tuple[F64, F64]:
            right = p.right(self.baseline_m)
            # right centre = C + B R e_x: a rotation dtheta moves it by -[B R e_x]x dtheta
            T = np.eye(6)
            T[3:, :3] = -skew(self.baseline_m * p.R[:, 0])
            J = np.vstack([pnp_jacobian(p, obj_l, self.K), pnp_jacobian(right, obj_r, self.K) @ T])
            res = np.concatenate([(_project(p, obj_l, self.K) - img_l).ravel(),
                                  (_project(right, obj_r, self.K) - img_r).ravel()])
            return res, J

        res, J = residual_and_jacobian(pose)
        for _ in range(iters):
            step = np.linalg.lstsq(J, -res, rcond=None)[0]
            pose = CameraPose(so3_exp(step[:3]) @ pose.R, pose.t + step[3:])
            res, J = residual_and_jacobian(pose)
            if np.linalg.norm(step) < 1e-10:
                break
        rms = float(np.sqrt(np.mean(res**2)))
        cov = max(self.cfg.corner_sigma_px, rms) ** 2 * np.linalg.inv(J.T @ J)
        return PoseEstimate(pose, 0.5 * (cov + cov.T), rms, est.n_points + obj_r.shape[0])


def _side_px(corners: F64) -> float:
    """The mean side of a marker's four image corners (px)."""
    c = np.asarray(corners, float).reshape(4, 2)
    return float(np.mean(np.linalg.norm(c - np.roll(c, -1, axis=0), axis=1)))


def tilt_agrees(camera: PoseEstimate, attitude: tuple[float, float], sigma_rad: float, gate: float,
                cam_in_body: PoseEstimate) -> bool:
    """Whether the body pose of ``cam_in_body`` (the camera in the body's frame, seen from
    ``camera`` in the world) stands tilted as the attitude sensor's ``attitude`` (roll, pitch,
    rad) says: the two horizontal components of the rotation between the pose's up axis and the
    sensor's (:func:`~fsw.core.geometry.normal_from_attitude` at the pose's heading), in the
    covariance of the pose (the camera's and the PnP's, carried to the body) plus the sensor's
    ``sigma_rad`` on each, within the chi-square ``gate`` (2 dof)."""
    body = _compose(camera, cam_in_body, ())
    up = body.R[:, 2]
    measured = normal_from_attitude(body.yaw, attitude[0], attitude[1])  # the sensor's up in the world
    err = np.cross(up, measured)  # the small rotation from the pose's up to the sensor's (world frame)
    b1 = np.cross(up, [0.0, 0.0, 1.0] if abs(up[2]) < 0.9 else [1.0, 0.0, 0.0])
    b1 /= float(np.linalg.norm(b1))
    basis = np.column_stack([b1, np.cross(up, b1)])  # the two rotations that tilt the up axis
    S = basis.T @ body.cov[:3, :3] @ basis + sigma_rad ** 2 * np.eye(2)
    e = basis.T @ err
    if not (np.isfinite(S).all() and np.isfinite(e).all()):
        return False
    return float(e @ np.linalg.solve(S, e)) <= gate


def _ambiguity(cands: list[PoseEstimate], same_deg: float = 1.0, same_m: float = 0.01) -> float:
    """The second candidate's RMS residual over the best one's (``cands`` sorted by it), inf when
    there is one, or when both are the same pose (the stereo refinement took both to one
    minimum: within ``same_deg`` and ``same_m``)."""
    if len(cands) < 2:
        return math.inf
    a, b = cands[0], cands[1]
    dr = math.degrees(float(np.linalg.norm(so3_log(a.pose.R.T @ b.pose.R))))
    if dr <= same_deg and float(np.linalg.norm(a.pose.t - b.pose.t)) <= same_m:
        return math.inf
    return b.rms_px / max(a.rms_px, 1e-9)


def _chi2_gap(cands: list[PoseEstimate], sigma_px: float) -> float:
    """How much worse the second candidate fits than the best (``cands`` sorted by RMS), as the
    difference of their chi-squares over the corners' noise ``sigma_px`` (two residuals per point)."""
    a, b = cands[0], cands[1]
    return 2.0 * (b.n_points * b.rms_px ** 2 - a.n_points * a.rms_px ** 2) / max(sigma_px, 1e-9) ** 2


def _project(pose: CameraPose, pts: F64, K: F64) -> F64:
    pc = pose.world_to_camera(pts)
    uv = pc[:, :2] / pc[:, 2:3]
    return np.column_stack([K[0, 0] * uv[:, 0] + K[0, 2], K[1, 1] * uv[:, 1] + K[1, 2]])


def _compose(camera: PoseEstimate, cam_in_body: PoseEstimate, ids: tuple[int, ...]
             ) -> BodyEstimate:
    """``T_world_body = T_world_cam * inv(T_body_cam)`` with first-order covariance."""
    R_wc, C_w = camera.pose.R, camera.pose.t
    R_bc, C_b = cam_in_body.pose.R, cam_in_body.pose.t
    R_wb = R_wc @ R_bc.T
    t_wb = C_w - R_wb @ C_b
    A = skew(R_wb @ C_b)
    Jb = np.zeros((6, 6))  # w.r.t. the camera-in-body perturbation
    Jb[:3, :3] = -R_wb
    Jb[3:, :3] = -A @ R_wb
    Jb[3:, 3:] = -R_wb
    Jc = np.eye(6)  # w.r.t. the camera-in-world perturbation
    Jc[3:, :3] = A
    cov = Jb @ cam_in_body.cov @ Jb.T + Jc @ camera.cov @ Jc.T
    return BodyEstimate(R_wb, t_wb, 0.5 * (cov + cov.T), ids, cam_in_body.rms_px)
