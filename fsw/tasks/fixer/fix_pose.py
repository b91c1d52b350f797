"""The camera pose of a fix and its covariance (docs/algorithm.md §5.2; docs/team.md, "Relative localization").

A fix's camera pose rests on the views of the Anchorbots' plates from the same standing when
there are any (:func:`fix_camera`), else on the rover's estimate with its covariance against
the team's frame (:func:`frame_extra`); the mast's joints add their own error to every view
(:func:`joints_covariance`). Pure functions of the rover's pose and the configuration: the
fixer task (:mod:`fsw.tasks.fixer.task`) and the bench's judging of the fixes use the same.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import CameraPose
from fsw.core.localization.landmarks import Landmark, camera_from_landmarks
from fsw.core.localization.localization import PoseEstimate
from fsw.settings import FswConfig
from fsw.tasks.camera import camera_pose_covariance
from fsw.tasks.messages import NavPose


def joints_covariance(pose: NavPose, cfg: FswConfig) -> NDArray[np.float64]:
    """The camera pose covariance of the mast's joints alone at a view from ``pose`` (the rover's
    own pose error is one for all views of a standing: the plates measure it)."""
    cap = cfg.capture
    js = math.radians(cap.joint_sigma_deg)
    still = dataclasses.replace(pose, cov=np.zeros((3, 3)), att_cov=None)
    return camera_pose_covariance(still, cfg.mast, (js, js, cap.lift_sigma_m))[1]


def frame_extra(pose: NavPose, cfg: FswConfig) -> NDArray[np.float64]:
    """What the camera pose covariance of a view from ``pose`` lacks against the team's frame: the
    errors of the map the rover registered on (``NavPose.frame_cov`` minus ``cov``, the
    corrections before the last, ``fsw.core.localization.odometry``) carried through the mast's
    chain at its joints (docs/algorithm.md §5.2, "A fix without a plate"). Zero without it."""
    if pose.frame_cov is None:
        return np.zeros((6, 6))
    d = np.asarray(pose.frame_cov, float) - np.asarray(pose.cov, float)[:3, :3]
    if not np.isfinite(d).all():
        return np.zeros((6, 6))
    still = dataclasses.replace(pose, cov=0.5 * (d + d.T), att_cov=None)
    return camera_pose_covariance(still, cfg.mast, (0.0, 0.0, 0.0))[1]


def fix_camera(landmarks: list[Landmark], pose: CameraPose, pose_cov: NDArray[np.float64],
               joints_cov: NDArray[np.float64], extra: NDArray[np.float64] | None = None) -> PoseEstimate:
    """The camera pose of a fix's view: from the views of the plates of the same standing when
    there are any (each carried to this view, fused), else the rover's estimate ``pose`` with
    its covariance ``pose_cov`` plus ``extra`` (what it lacks against the team's frame,
    :func:`frame_extra`)."""
    est = camera_from_landmarks(landmarks, pose, joints_cov)
    if est is not None:
        return est
    cov = np.asarray(pose_cov, float) + (0.0 if extra is None else np.asarray(extra, float))
    return PoseEstimate(pose, cov)
