"""The Cliff-bot's camera head: where its small stereo pair looks from, and how sure that is
(docs/team.md, "Both agents sense"; docs/algorithm.md §8.1).

The head stands ``head_m`` above the body's ground point along the ground's normal, at the
body's front end when it looks ahead and at its rear end when it looks back or sideways, unless
the scan names the end for a pointing (``end_m`` along the heading; the heading points down the
tethers, so on the face the front is the lower end), and points along the body's heading
turned by a pan and tilted by a tilt (a levelled head: world angles). The bench renders the views at the TRUE pose with
:func:`head_camera_pose`; the flight side tags each pair with the pose from its navigation
estimate and the attitude sensor, and with that pose's 6x6 covariance
(:func:`head_pose_covariance`: rotation vector, then translation, as every view's,
docs/algorithm.md §1.2).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import CameraPose, normal_from_attitude, rotation_from_yaw_tilt
from fsw.core.localization.localization import so3_log

F64 = NDArray[np.float64]


def head_camera_pose(body: F64, normal: F64, yaw: float, pan: float, tilt: float, head_m: float,
                     end_m: float) -> CameraPose:
    """The left camera: ``head_m`` along the ground ``normal`` above the body's ground point
    ``body`` and ``end_m`` along the body's heading ``yaw`` in the ground's plane (+: its front
    end), looking along world heading ``yaw + pan`` with elevation ``tilt`` (radians)."""
    n = np.asarray(normal, float)
    fwd = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    fwd = fwd - float(fwd @ n) * n
    fwd = fwd / max(float(np.linalg.norm(fwd)), 1e-9)
    t = np.asarray(body, float) + head_m * n + end_m * fwd
    return CameraPose(rotation_from_yaw_tilt(yaw + pan, tilt), t)


def head_end(pan: float, end_m: float, place: str = "") -> float:
    """The head's place along the body for a view turned ``pan`` from the heading: the end
    ``place`` names (``"front"``: ``+end_m``, ``"rear"``: ``-end_m``), else by the pan: its front
    end when it looks ahead, its rear end when it looks back or sideways (the body out of view;
    the tethers run back from the body, and a side view from the rear sees the ground under
    them). A view from the other end sees what those leave out: the ground beside the body's
    front corners (from the front end, looking sideways), beside its rear half (from the rear end,
    looking ahead and sideways)."""
    if place in ("front", "rear"):
        return end_m if place == "front" else -end_m
    return end_m if abs(math.remainder(pan, 2 * math.pi)) < math.pi / 2 - 1e-9 else -end_m


def head_pose_covariance(xy: F64, z: float, yaw: float, roll: float, pitch: float, pan: float, tilt: float,
                         head_m: float, end_m: float, cov_xyyaw: F64, z_sigma_m: float, tilt_sigma_rad: float
                         ) -> tuple[CameraPose, F64]:
    """The head camera's pose from the navigation estimate (``xy``, ``yaw`` with covariance
    ``cov_xyyaw``), the ground height under the body ``z`` (sigma ``z_sigma_m``) and the
    attitude sensor's roll and pitch (sigma ``tilt_sigma_rad``), and the pose's 6x6 covariance
    (rotation vector, translation) by central differences of the head's kinematics. The head is
    levelled (its pan and tilt are world angles): roll and pitch move its place, and their sigma
    is also its pointing error about the horizontal axes."""
    q0 = np.array([float(xy[0]), float(xy[1]), yaw, z, roll, pitch])

    def pose(q: F64) -> CameraPose:
        n = normal_from_attitude(q[2], q[4], q[5])
        return head_camera_pose(np.array([q[0], q[1], q[3]]), n, q[2], pan, tilt, head_m, end_m)

    p0 = pose(q0)
    J = np.zeros((6, 6))
    for i, h in enumerate((1e-4, 1e-4, 1e-5, 1e-4, 1e-5, 1e-5)):
        cols = []
        for s in (h, -h):
            q = q0.copy()
            q[i] += s
            p = pose(q)
            cols.append(np.concatenate([so3_log(p.R @ p0.R.T), p.t]))
        J[:, i] = (cols[0] - cols[1]) / (2 * h)
    sigma = np.zeros((6, 6))
    sigma[:3, :3] = np.asarray(cov_xyyaw, float).reshape(3, 3)
    sigma[3, 3] = z_sigma_m ** 2
    sigma[4, 4] = sigma[5, 5] = tilt_sigma_rad ** 2
    cov = J @ sigma @ J.T
    cov[0, 0] += tilt_sigma_rad ** 2  # the levelled head's own pointing error about the horizontal axes
    cov[1, 1] += tilt_sigma_rad ** 2
    return p0, cov
