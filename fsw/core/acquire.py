"""Acquire and merge one view (docs/algorithm.md §4): stereo points, their world covariance
(§1.2: stereo noise plus the camera pose covariance from §5), fusion into the map (§1.1)
and the misses of the cells that were expected visible but got no point (§3.4).

The executive's perception task calls ``acquire`` with a captured pair and the current
camera pose estimate; the HIL bench and the tests call it with rendered pairs.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from fsw.core.localization.localization import PoseEstimate, point_covariance_parts
from fsw.core.map.elevation_map import ElevationMap, MergeStats
from fsw.core.stereo.occlusion import LipGuard
from fsw.core.stereo.stereo import StereoMatcher

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class ViewPoints:
    """One view's points in the world frame with their 3x3 covariances."""

    xyz_w: F64
    cov_w: F64  # total: stereo plus pose
    cov_pose_w: F64 | None  # the pose part alone (common to the view), None if pose exact
    valid_px: int  # pixels that produced a point (before any stride)
    lip_near_w: F64 = field(default_factory=lambda: np.zeros((0, 3)))  # occluding lips (fsw.core.stereo.occlusion)
    lip_far_w: F64 = field(default_factory=lambda: np.zeros((0, 3)))


@dataclass(frozen=True)
class AcquireResult:
    points: ViewPoints
    merge: MergeStats


def view_points(matcher: StereoMatcher, left: NDArray[np.uint8], right: NDArray[np.uint8],
                camera: PoseEstimate, stride_px: int = 1) -> ViewPoints:
    """Stereo points of one pair, in the world, with stereo and pose covariance (§1.2)."""
    sp = matcher.points(left, right, stride_px)
    exact = not np.any(camera.cov)
    xyz_w, cov_s, cov_p = point_covariance_parts(
        camera.pose, None if exact else camera.cov, sp.xyz_c, sp.cov_c)
    total = cov_s if cov_p is None else cov_s + cov_p
    return ViewPoints(xyz_w, total, cov_p, int(sp.valid.sum()), camera.pose.camera_to_world(sp.lip_near_c),
                      camera.pose.camera_to_world(sp.lip_far_c))


def acquire(matcher: StereoMatcher, emap: ElevationMap, left: NDArray[np.uint8],
            right: NDArray[np.uint8], camera: PoseEstimate,
            p_visible: NDArray[np.floating] | NDArray[np.bool_] | None = None,
            stride_px: int = 1) -> AcquireResult:
    """Match, triangulate, transform and fuse one view; record its misses (§4)."""
    pts = view_points(matcher, left, right, camera, stride_px)
    common, keep = pts.cov_pose_w, np.ones(pts.xyz_w.shape[0], bool)
    if common is not None:  # too near the view's own lips, given its common (pose) error (fsw.core.stereo.occlusion)
        guard = LipGuard(emap.grid, pts.lip_near_w, pts.lip_far_w, emap.cfg.lip_min_drop_m)
        keep = guard.clear(pts.xyz_w, common, emap.cfg.lip_guard_sigma)
        common = common[keep]
    stats = emap.merge(pts.xyz_w[keep], cov=pts.cov_w[keep], p_visible=p_visible, cov_common=common)
    return AcquireResult(pts, stats)
