"""The Anchorbots as landmarks: the RECON-bot's camera pose in the team's frame from their marker
plates (docs/algorithm.md §5.2).

A fix of the Cliff-bot is ``T_team_body = T_team_cam * T_cam_body``: its error is the camera's
error carried over the range (a yaw error ``e`` moves it by ``range * e``) plus the PnP's. The
camera's pose from the RECON-bot's dead reckoning and registration drifts by degrees over a
mission; the two Anchorbots do not move, and the team's frame is where their tether exits are
surveyed (``[cliffbot_site]``: the same points the Cliff-bot's tether model uses). Each carries
a marker plate at a fixed place from its exit (:func:`anchor_marker_corners`), so a view of a
plate resects the camera in the team's frame (PnP on known corners,
:meth:`~fsw.core.localization.fiducials.CliffbotLocalizer.resect`).

The RECON-bot stands still while it answers fixes; its views of the plates and of the Cliff-bot
differ by the mast's joints only. :func:`transport` carries a resected camera pose from the view
it was measured in to another view of the same standing (the body's error is one rigid motion
of the world, the joints' errors are added), :func:`fuse` combines the views of both plates.
Covariances are 6x6 over ``(dtheta_world, dt_world)`` (``fsw.core.localization.localization``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import CameraPose
from fsw.core.localization.localization import LocalizationConfig, PoseEstimate, skew, so3_exp, so3_log

F64 = NDArray[np.float64]


def plate_frames(a_xyz: Sequence[float], b_xyz: Sequence[float], cfg: LocalizationConfig
                 ) -> list[tuple[int, F64, F64, F64]]:
    """Each Anchorbot plate's ``(id, centre, right, down)`` (unit vectors across its face as a
    reader sees it). The anchors' frame: ``x`` level along A->B, ``z`` up, ``y = z x x`` (left of
    A->B); a plate's centre is its exit plus ``anchor_marker_offset_m`` in that frame, and it faces
    ``-y`` tilted up by ``anchor_marker_tilt_deg``."""
    a, b = np.asarray(a_xyz, float), np.asarray(b_xyz, float)
    x = b - a
    x[2] = 0.0
    n = float(np.linalg.norm(x))
    if n < 1e-6 or len(cfg.anchor_marker_offset_m) != 3:
        return []
    x /= n
    z = np.array([0.0, 0.0, 1.0])
    y = np.cross(z, x)
    t = math.radians(cfg.anchor_marker_tilt_deg)
    down = -math.sin(t) * y - math.cos(t) * z  # down the plate's face; its normal is down x right
    off = np.asarray(cfg.anchor_marker_offset_m, float)
    out = []
    for mid, exit_pt in zip(cfg.anchor_marker_ids, (a, b), strict=False):
        centre = exit_pt + off[0] * x + off[1] * y + off[2] * z
        out.append((int(mid), centre, x.copy(), down))
    return out


def anchor_marker_corners(a_xyz: Sequence[float], b_xyz: Sequence[float], cfg: LocalizationConfig
                          ) -> dict[int, F64]:
    """``{id: (4, 3) corners}`` of the Anchorbots' marker plates in the frame of ``a_xyz`` and
    ``b_xyz`` (their tether exits), in ArUco order (top-left, top-right, bottom-right, bottom-left)."""
    h = cfg.anchor_marker_size_m / 2.0
    return {mid: np.array([c - r * h - d * h, c + r * h - d * h, c + r * h + d * h, c - r * h + d * h])
            for mid, c, r, d in plate_frames(a_xyz, b_xyz, cfg)}


def transport(measured: PoseEstimate, at: CameraPose, to: CameraPose, joints_cov: F64) -> PoseEstimate:
    """The camera pose of view ``to`` (as dead-reckoned) given view ``at`` (dead-reckoned) was
    measured as ``measured``: the body's error is the rigid motion ``G`` of the world that takes
    ``at`` to ``measured`` (a rotation ``dR`` about ``at``'s centre, then a shift), so the other
    view is ``G(to)``. Its covariance: ``measured``'s carried by the lever between the two centres,
    plus ``joints_cov`` (the mast's joint errors of both views)."""
    dR = measured.pose.R @ at.R.T
    v = dR @ (to.t - at.t)
    pose = CameraPose(dR @ to.R, measured.pose.t + v)
    J = np.eye(6)
    J[3:, :3] = -skew(v)  # a rotation dtheta of the measured camera moves the other centre by dtheta x v
    cov = J @ measured.cov @ J.T + np.asarray(joints_cov, float)
    return PoseEstimate(pose, 0.5 * (cov + cov.T), measured.rms_px, measured.n_points)


def fuse(estimates: Sequence[PoseEstimate]) -> PoseEstimate:
    """The information-weighted mean of independent estimates of one camera pose (in the
    tangent space at the first one)."""
    if not estimates:
        raise ValueError("fuse needs at least one estimate")
    if len(estimates) == 1:
        return estimates[0]
    ref = estimates[0].pose
    info = np.zeros((6, 6))
    vec = np.zeros(6)
    for e in estimates:
        w = np.linalg.inv(e.cov)
        d = np.concatenate([so3_log(e.pose.R @ ref.R.T), e.pose.t - ref.t])
        info += w
        vec += w @ d
    cov = np.linalg.inv(info)
    delta = cov @ vec
    pose = CameraPose(so3_exp(delta[:3]) @ ref.R, ref.t + delta[3:])
    return PoseEstimate(pose, 0.5 * (cov + cov.T), max(e.rms_px for e in estimates),
                        sum(e.n_points for e in estimates))


@dataclass(frozen=True)
class Landmark:
    """A view of the plates: the camera resected on them (team frame), the camera pose the rover's
    estimate gave for that view, and the covariance of the mast's joints at it."""

    measured: PoseEstimate
    predicted: CameraPose
    joints_cov: F64
    ids: tuple[int, ...] = ()  # the plates it rests on


def camera_from_landmarks(landmarks: Sequence[Landmark], predicted: CameraPose, joints_cov: F64
                          ) -> PoseEstimate | None:
    """The camera pose of a view the rover's estimate puts at ``predicted`` (joints covariance
    ``joints_cov``) from the views of the plates of the same standing: each carried to it
    (:func:`transport`), fused; None without any."""
    if not landmarks:
        return None
    return fuse([transport(lm.measured, lm.predicted, predicted, lm.joints_cov + joints_cov) for lm in landmarks])
