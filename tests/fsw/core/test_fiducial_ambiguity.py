"""A fix from one far marker is refused when its mirror pose fits as well (fsw.core.localization.fiducials;
docs/team.md, "Relative localization"): projected corners, no rendering."""

from __future__ import annotations

import math

import numpy as np

from fsw.core.geometry import CameraPose
from fsw.core.localization.fiducials import CliffbotLayout, _ambiguity, _project
from fsw.core.localization.localization import pnp_candidates
from fsw.settings import load_settings

CFG = load_settings()


def _candidates(range_m: float, yaw_deg: float, seed: int) -> list:
    """The PnP candidates of one marker (id 1) seen at ``range_m``, turned ``yaw_deg``, corners noisy."""
    corners = CliffbotLayout().corners_body()[1]
    c = corners.mean(axis=0)
    a = math.radians(yaw_deg)
    # the camera looks at the marker's centre from range_m, along the body's x axis turned by a
    eye = c + range_m * np.array([math.cos(a), math.sin(a), 0.15])
    fwd = (c - eye) / np.linalg.norm(c - eye)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    pose = CameraPose(np.column_stack([right, down, fwd]), eye)
    K = np.asarray(CFG.camera.K, float)
    px = _project(pose, corners, K) + np.random.default_rng(seed).normal(0.0, 0.3, (4, 2))
    return sorted(pnp_candidates(corners, px, K, CFG.localization.corner_sigma_px), key=lambda e: e.rms_px)


def test_a_far_frontal_marker_is_ambiguous_and_a_near_oblique_one_is_not() -> None:
    ratio = CFG.localization.fiducial_ambiguity_ratio
    far = [_ambiguity(_candidates(6.0, 5.0, s)) for s in range(8)]
    near = [_ambiguity(_candidates(2.0, 40.0, s)) for s in range(8)]
    assert sum(r < ratio for r in far) >= 6, far  # both mirror poses fit the noisy corners
    assert all(r >= ratio for r in near), near


def test_one_candidate_or_the_same_pose_twice_is_not_ambiguous() -> None:
    c = _candidates(2.0, 40.0, 0)
    assert _ambiguity(c[:1]) == math.inf
    assert _ambiguity([c[0], c[0]]) == math.inf


def test_one_marker_too_small_in_the_image_gives_no_fix() -> None:
    """A far single marker (its side under ``fiducial_min_marker_px``) is no fix; the same marker
    near is one (the detector is stubbed with projected corners)."""
    from fsw.core.localization.fiducials import CliffbotLocalizer, _side_px
    from fsw.core.localization.localization import PoseEstimate

    corners = CliffbotLayout().corners_body()[1]
    K = np.asarray(CFG.camera.K, float)
    loc = CliffbotLocalizer(CFG.localization, CliffbotLayout(), K, CFG.camera.baseline_m)
    got = {}
    for r in (2.0, 11.0):
        c = corners.mean(axis=0)
        eye = c + r * np.array([math.cos(0.6), math.sin(0.6), 0.1])
        fwd = (c - eye) / np.linalg.norm(c - eye)
        right = np.cross(fwd, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        pose = CameraPose(np.column_stack([right, np.cross(fwd, right), fwd]), eye)
        px = _project(pose, corners, K)
        loc.detect = lambda image, px=px: {1: px}  # type: ignore[method-assign]
        got[r] = (_side_px(px), loc.locate(np.zeros((4, 4), np.uint8), PoseEstimate(pose, np.zeros((6, 6)))))
    assert got[2.0][0] >= CFG.localization.fiducial_min_marker_px and got[2.0][1] is not None
    assert got[11.0][0] < CFG.localization.fiducial_min_marker_px and got[11.0][1] is None


def test_one_marker_whose_mirror_fits_within_the_corners_noise_gives_no_fix() -> None:
    """Both mirror poses of a 20 px marker fit to hundredths of a pixel: their RMS ratio passes
    ``fiducial_ambiguity_ratio``, but in the corners' noise (``corner_sigma_px``) the mirror is as
    likely, and the pose chosen may be tens of degrees off: no fix. The same marker near and
    oblique (its mirror many chi-square units worse) is a fix."""
    from fsw.core.localization.fiducials import CliffbotLocalizer, _side_px
    from fsw.core.localization.localization import PoseEstimate

    corners = CliffbotLayout().corners_body()[1]
    K = np.asarray(CFG.camera.K, float)
    loc = CliffbotLocalizer(CFG.localization, CliffbotLayout(), K, CFG.camera.baseline_m)
    c = corners.mean(axis=0)
    got = {}
    for r, yaw in ((5.5, 20.0), (2.0, 40.0)):
        a = math.radians(yaw)
        eye = c + r * np.array([math.cos(a), math.sin(a), 0.15])
        fwd = (c - eye) / np.linalg.norm(c - eye)
        right = np.cross(fwd, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        pose = CameraPose(np.column_stack([right, np.cross(fwd, right), fwd]), eye)
        px = _project(pose, corners, K) + np.random.default_rng(1).normal(0.0, 0.05, (4, 2))
        cands = sorted(pnp_candidates(corners, px, K, CFG.localization.corner_sigma_px), key=lambda e: e.rms_px)
        loc.detect = lambda image, scale=1, px=px: {1: px}  # type: ignore[method-assign]
        got[r] = (_side_px(px), _ambiguity(cands),
                  loc.locate(np.zeros((4, 4), np.uint8), PoseEstimate(pose, np.zeros((6, 6)))))
    side, ratio, fix = got[5.5]
    assert side >= CFG.localization.fiducial_min_marker_px and ratio >= CFG.localization.fiducial_ambiguity_ratio
    assert fix is None
    assert got[2.0][2] is not None



def _far_marker(seed: int, r: float = 4.0, yaw_deg: float = 5.0, rise: float = 0.3
                ) -> tuple[CameraPose, np.ndarray, np.ndarray]:
    """Marker 1 of a level body at the origin seen from ``r`` m, ``yaw_deg`` off its normal and
    ``rise`` x ``r`` above it (a RECON-bot's mast looking down at it): the left camera's pose and
    the corners in the left and right images, with 0.3 px noise."""
    corners = CliffbotLayout().corners_body()[1]
    c = corners.mean(axis=0)
    a = math.radians(yaw_deg)
    eye = c + r * np.array([math.cos(a), math.sin(a), rise])
    fwd = (c - eye) / np.linalg.norm(c - eye)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    pose = CameraPose(np.column_stack([right, np.cross(fwd, right), fwd]), eye)
    K = np.asarray(CFG.camera.K, float)
    noise = np.random.default_rng(seed).normal(0.0, 0.3, (2, 4, 2))
    return (pose, _project(pose, corners, K) + noise[0],
            _project(pose.right(CFG.camera.baseline_m), corners, K) + noise[1])


def test_the_requests_gravity_settles_the_mirror_pose_of_one_far_marker() -> None:
    """One far marker's two mirror poses fit its corners alike (left and right images): without
    the Cliff-bot's attitude no fix; with its roll and pitch the pose that stands as gravity says
    is the fix (within its sigma of the truth), and an attitude that neither pose agrees with
    gives none, never the mirror (docs/algorithm.md §5.3)."""
    from fsw.core.localization.fiducials import CliffbotLocalizer
    from fsw.core.localization.localization import PoseEstimate, so3_log

    K = np.asarray(CFG.camera.K, float)
    loc = CliffbotLocalizer(CFG.localization, CliffbotLayout(), K, CFG.camera.baseline_m)
    left, right = np.zeros((4, 4), np.uint8), np.ones((4, 4), np.uint8)
    blind = 0
    for seed in range(12):
        pose, px_l, px_r = _far_marker(seed)
        loc.detect = lambda image, scale=1, a=px_l, b=px_r: {1: a if image is left else b}  # type: ignore[method-assign]
        cam = PoseEstimate(pose, np.zeros((6, 6)))
        blind += loc.locate(left, cam, right) is None
        fix = loc.locate(left, cam, right, attitude=(0.0, 0.0))  # the body stands level: so says its sensor
        assert fix is not None, seed
        # the body's pose (within its sigma of about 5 deg), not its mirror (30-36 deg off)
        assert math.degrees(float(np.linalg.norm(so3_log(fix.R)))) < 12.0, seed
        assert loc.locate(left, cam, right, attitude=(math.radians(20.0), 0.0)) is None, seed  # neither stands so
    assert blind >= 6, blind  # most of these are refused without the attitude
