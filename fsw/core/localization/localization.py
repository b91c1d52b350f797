"""Localization: camera pose by PnP with covariance, its recursive estimate, and the Cliff-bot
from its ArUco fiducials relative to the RECON-bot (docs/algorithm.md §5), plus the propagation
of the pose covariance into every measured point (§1.2, the paper's EKF step).

Pose convention (used by every function here): a camera pose is ``CameraPose(R, t)`` with
``R`` camera-to-world and ``t`` the camera centre. Its uncertainty is a 6x6 covariance over
the perturbation ``(dtheta, dt)``: ``R = exp([dtheta]x) R_hat`` (a small rotation about the
*world* axes, radians) and ``t = t_hat + dt`` (metres, world frame).

A world point measured in the camera frame, ``p = R c + t``, then has the covariance

    P = J_pose Sigma_pose J_pose^T + R Sigma_c R^T,   J_pose = [ -[R c]x | I ]

which is ``propagate_point_covariance``. The vertical component ``P[2, 2]`` is the ``vm`` of
the fusion (§1.1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import CameraPose
from fsw.framework.params import param

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class LocalizationConfig:
    """Fiducial detection, PnP noise and the pose filter (config ``[localization]``)."""

    aruco_dictionary: str = param("DICT_4X4_50", doc="cv2.aruco predefined dictionary name")
    corner_refinement: str = param(
        "apriltag", choices=("none", "subpix", "contour", "apriltag"),
        doc="ArUco corner refinement (apriltag: unbiased edge-line fit)",
    )
    corner_sigma_px: float = param(
        0.8, lo=0.01, hi=10.0, units="px", doc="1-sigma image noise of a detected corner"
    )
    max_reproj_px: float = param(
        3.0, lo=0.1, hi=100.0, units="px", doc="reject a PnP solution whose RMS residual exceeds"
    )
    fiducial_shared_residuals: int = param(
        24, lo=2, hi=100000,
        doc="a fiducial fix's covariance shrinks with its corners only up to this many residuals "
            "(beyond, the errors all corners share dominate: camera model, marker placement)",
    )
    fiducial_ambiguity_ratio: float = param(
        2.0, lo=1.0, hi=100.0,
        doc="a fix from one marker (planar: two mirror poses) is refused unless the other pose's RMS residual "
            "exceeds the chosen one's by this factor",
    )
    fiducial_min_marker_px: float = param(
        15.0, lo=0.0, hi=1000.0, units="px",
        doc="a fix from one marker is refused when its mean side in the image is shorter than this",
    )
    fiducial_tilt_sigma_deg: float = param(
        1.0, lo=0.01, hi=30.0, units="deg",
        doc="sigma of the Cliff-bot's roll and pitch as a fix request carries them (its attitude sensor): "
            "the gravity a fix's attitude must agree with (docs/algorithm.md §5.3)",
    )
    fiducial_gravity_gate: float = param(
        0.999, lo=0.5, hi=0.999999,
        doc="chi-square probability (2 dof) within which a fix's tilt must agree with the request's attitude",
    )
    fiducial_upsample: int = param(
        2, lo=1, hi=4,
        doc="when fewer than two known markers are found, the image is searched again enlarged this many times "
            "(small, far markers; 1: off)",
    )
    gate_chi2: float = param(
        22.46, lo=1.0, hi=1e6, doc="chi-square gate (6 dof) of a pose update; 22.46 = 0.1 %"
    )
    anchor_marker_ids: tuple[float, ...] = param(
        (11.0, 12.0), doc="ArUco ids of the marker plates of Anchorbot A and B, the fixer's landmarks "
                          "(docs/algorithm.md §5.2); () for none"
    )
    anchor_marker_size_m: float = param(0.18, lo=0.01, hi=2.0, units="m", doc="their black square's side")
    anchor_marker_offset_m: tuple[float, ...] = param(
        (0.0, 0.3, -0.1), units="m",
        doc="each plate's centre from its tether exit: along A->B, to the left of A->B, up",
    )
    anchor_marker_tilt_deg: float = param(
        45.0, lo=0.0, hi=90.0, units="deg",
        doc="the plates face to the right of A->B (the face's side), tilted up from vertical by this",
    )


def skew(v: F64) -> F64:
    """``[v]x`` for one vector (3,) or a stack (N, 3) -> (N, 3, 3)."""
    v = np.asarray(v, dtype=np.float64)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def so3_exp(w: NDArray[np.float32] | NDArray[np.float64] | cv2.typing.MatLike) -> F64:
    R, _ = cv2.Rodrigues(np.asarray(w, dtype=np.float64).reshape(3, 1))
    return np.asarray(R, dtype=np.float64)


def so3_log(R: F64) -> F64:
    """Rotation vector of ``R``, exact for small angles too (``cv2.Rodrigues`` returns zero
    below about 1e-5 rad, which zeroed every numerical Jacobian taken with such steps).

    Through the unit quaternion (Shepperd's choice of the largest of trace and diagonal, so
    it is well conditioned at any angle; rounding-level non-orthogonality is absorbed by the
    normalisation), then ``angle / sin(angle / 2)`` times its vector part, by its series
    below 1e-3 rad: the method of ``scipy.spatial.transform.Rotation``, without importing
    scipy.spatial into the flight process (11 MB resident; issue 15)."""
    m = np.asarray(R, dtype=np.float64).reshape(3, 3)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    k = int(np.argmax([m[0, 0], m[1, 1], m[2, 2], tr]))
    q = np.empty(4)
    if k == 3:
        q[:] = (m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1], 1.0 + tr)
    else:
        j, n = (k + 1) % 3, (k + 2) % 3
        q[k] = 1.0 - tr + 2.0 * m[k, k]
        q[j] = m[j, k] + m[k, j]
        q[n] = m[n, k] + m[k, n]
        q[3] = m[n, j] - m[j, n]
    q /= np.linalg.norm(q)
    if q[3] < 0.0:
        q = -q
    angle = 2.0 * math.atan2(float(np.linalg.norm(q[:3])), float(q[3]))
    small = angle <= 1e-3  # series of angle / sin(angle / 2)
    scale = 2.0 + angle**2 / 12.0 + 7.0 * angle**4 / 2880.0 if small else angle / math.sin(angle / 2.0)
    return np.asarray(scale * q[:3], dtype=np.float64)


@dataclass(frozen=True)
class PoseEstimate:
    """A camera pose with its 6x6 covariance over ``(dtheta_world, dt_world)``."""

    pose: CameraPose
    cov: F64
    rms_px: float = 0.0
    n_points: int = 0

    @property
    def sigma_t_m(self) -> float:
        """RMS position standard deviation (sqrt of the mean translation variance)."""
        return float(np.sqrt(np.trace(self.cov[3:, 3:]) / 3.0))


def pnp_jacobian(pose: CameraPose, pts_w: F64, K: F64) -> F64:
    """d(u, v) / d(dtheta, dt): (2N, 6) for the world points ``pts_w`` seen from ``pose``.

    ``p_c = R^T (p_w - t)``; perturbing gives ``dp_c = R^T [p_w - t]x dtheta - R^T dt``.
    """
    d = pts_w - pose.t
    pc = d @ pose.R
    fx, fy = K[0, 0], K[1, 1]
    x, y, z = pc[:, 0], pc[:, 1], pc[:, 2]
    n = pts_w.shape[0]
    dproj = np.zeros((n, 2, 3))
    dproj[:, 0, 0] = fx / z
    dproj[:, 0, 2] = -fx * x / z**2
    dproj[:, 1, 1] = fy / z
    dproj[:, 1, 2] = -fy * y / z**2
    Rt = pose.R.T
    dpc = np.concatenate([Rt @ skew(d), np.broadcast_to(-Rt, (n, 3, 3))], axis=2)  # (n, 3, 6)
    return np.einsum("nij,njk->nik", dproj, dpc).reshape(2 * n, 6)


def solve_pnp(pts_w: F64, pts_px: F64, K: F64, corner_sigma_px: float) -> PoseEstimate | None:
    """Camera pose from ``n >= 4`` known world points and their image points (§5).

    Least squares (OpenCV PnP, then Levenberg-Marquardt refinement); the covariance is the
    Gauss-Newton one, ``sigma^2 (J^T J)^-1`` with ``sigma`` the larger of the configured
    corner noise and the residual RMS. Returns None when the points cannot give a pose.
    """
    cands = pnp_candidates(pts_w, pts_px, K, corner_sigma_px)
    return min(cands, key=lambda e: e.rms_px) if cands else None


def pnp_candidates(pts_w: F64, pts_px: F64, K: F64, corner_sigma_px: float
                   ) -> list[PoseEstimate]:
    """Every PnP solution worth considering: two for a planar target (IPPE; the mirror
    ambiguity of one small marker), one otherwise (SQPnP). Each is LM-refined."""
    pts_w = np.asarray(pts_w, dtype=np.float64).reshape(-1, 3)
    pts_px = np.asarray(pts_px, dtype=np.float64).reshape(-1, 2)
    n = pts_w.shape[0]
    if n < 4 or pts_px.shape[0] != n or not (np.isfinite(pts_w).all()
                                             and np.isfinite(pts_px).all()):
        return []
    sv = np.linalg.svd(pts_w - pts_w.mean(axis=0), compute_uv=False)
    planar = sv[2] <= 1e-6 * max(sv[0], 1e-12)
    flag = cv2.SOLVEPNP_IPPE if planar else cv2.SOLVEPNP_SQPNP
    out = []
    try:
        count, rvecs, tvecs, _ = cv2.solvePnPGeneric(pts_w, pts_px, K, None, flags=flag)
        for rvec, tvec in zip(rvecs[:count], tvecs[:count], strict=True):
            rvec, tvec = cv2.solvePnPRefineLM(pts_w, pts_px, K, None, rvec, tvec)
            est = _pnp_estimate(pts_w, pts_px, K, corner_sigma_px, rvec, tvec)
            if est is not None:
                out.append(est)
    except cv2.error:
        return []
    return out


def _pnp_estimate(pts_w: F64, pts_px: F64, K: F64, corner_sigma_px: float,
                  rvec: cv2.typing.MatLike, tvec: cv2.typing.MatLike) -> PoseEstimate | None:
    R_wc = so3_exp(rvec)
    t = np.asarray(tvec, dtype=np.float64).reshape(3)
    pose = CameraPose(R_wc.T, -R_wc.T @ t)
    if (pose.world_to_camera(pts_w)[:, 2] <= 0).any():
        return None
    proj, _ = cv2.projectPoints(pts_w, rvec, tvec, K, None)
    res = proj.reshape(-1, 2) - pts_px
    rms = float(np.sqrt(np.mean(res**2)))
    J = pnp_jacobian(pose, pts_w, K)
    JtJ = J.T @ J
    if not np.isfinite(JtJ).all() or np.linalg.cond(JtJ) > 1e12:
        return None
    sigma = max(corner_sigma_px, rms)
    cov = sigma**2 * np.linalg.inv(JtJ)
    return PoseEstimate(pose, 0.5 * (cov + cov.T), rms, pts_w.shape[0])


@dataclass
class RecursivePoseFilter:
    """Recursive estimate of the camera pose mean and covariance (§5).

    Each PnP solution is a measurement of the whole pose (measurement matrix I) fused by a
    Kalman update in the tangent space; motion between views (odometry, mast) is a
    ``predict`` with its process noise. An update whose innovation fails the chi-square
    gate is refused and counted.
    """

    estimate: PoseEstimate
    gate_chi2: float = 22.46
    rejected: int = 0
    updates: int = 0
    history: list[float] = field(default_factory=list)

    def predict(self, delta: CameraPose, process_cov: F64) -> PoseEstimate:
        """Apply a relative motion (camera frame of the current pose) and add process noise."""
        R0, t0 = self.estimate.pose.R, self.estimate.pose.t
        pose = CameraPose(R0 @ delta.R, t0 + R0 @ delta.t)
        self.estimate = PoseEstimate(pose, self.estimate.cov + process_cov)
        return self.estimate

    def update(self, meas: PoseEstimate) -> bool:
        """Fuse one pose measurement; False (and counted) if it fails the gate."""
        x = self.estimate
        innov = np.concatenate(
            [so3_log(meas.pose.R @ x.pose.R.T), meas.pose.t - x.pose.t]
        )
        S = x.cov + meas.cov
        m2 = float(innov @ np.linalg.solve(S, innov))
        if not np.isfinite(m2) or m2 > self.gate_chi2:
            self.rejected += 1
            return False
        Kg = x.cov @ np.linalg.inv(S)
        dx = Kg @ innov
        pose = CameraPose(so3_exp(dx[:3]) @ x.pose.R, x.pose.t + dx[3:])
        cov = (np.eye(6) - Kg) @ x.cov
        self.estimate = PoseEstimate(pose, 0.5 * (cov + cov.T), meas.rms_px, meas.n_points)
        self.updates += 1
        self.history.append(self.estimate.sigma_t_m)
        return True


def propagate_point_covariance(pose: CameraPose, pose_cov: F64 | None, xyz_c: F64,
                               cov_c: F64) -> tuple[F64, F64]:
    """World points and their covariances, ``P = J_pose S_pose J_pose^T + R S_c R^T`` (§1.2)."""
    pts_w, P, P_pose = point_covariance_parts(pose, pose_cov, xyz_c, cov_c)
    return pts_w, P if P_pose is None else P + P_pose


def point_covariance_parts(pose: CameraPose, pose_cov: F64 | None, xyz_c: F64, cov_c: F64
                           ) -> tuple[F64, F64, F64 | None]:
    """World points, their stereo covariance ``R S_c R^T`` and their pose covariance
    ``J_pose S_pose J_pose^T`` (None without a pose covariance), kept apart because the
    pose part is common to every point of the view (§1.2)."""
    R = pose.R
    rc = xyz_c @ R.T
    pts_w = rc + pose.t
    P = np.matmul(np.matmul(R, cov_c), R.T)
    if pose_cov is None:
        return pts_w, P, None
    S = np.asarray(pose_cov, dtype=np.float64)
    A = skew(rc)  # J_pose = [-A | I]
    ASrt = np.matmul(A, S[:3, 3:])
    Pp = np.matmul(np.matmul(A, S[:3, :3]), A.transpose(0, 2, 1))
    Pp -= ASrt + ASrt.transpose(0, 2, 1)
    Pp += S[3:, 3:]
    return pts_w, P, Pp
