"""The Anchorbots as landmarks (fsw.core.localization.landmarks; docs/algorithm.md §5.2): the plates'
corners in the team's frame, a resected view carried to another view of one standing, the views
fused, and the fix of a rover whose own pose is off by degrees."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fsw.core.geometry import CameraPose, MapGrid, camera_pose_from_rover
from fsw.core.localization.fiducials import CliffbotLocalizer
from fsw.core.localization.landmarks import (
    Landmark,
    anchor_marker_corners,
    camera_from_landmarks,
    fuse,
    transport,
)
from fsw.core.localization.localization import LocalizationConfig, PoseEstimate, so3_exp, so3_log
from fsw.core.team.climber_ground import ClimberConfig
from fsw.core.team.tether import TetherConfig
from fsw.settings import load_settings
from fsw.tasks.camera import camera_pose_covariance
from fsw.tasks.messages import NavPose
from hil_sim.render import StereoRenderer
from hil_sim.team.cliffbot_rig import CliffbotRig
from hil_sim.world import load_scenario

CHI2_95_6DOF = 12.5916


def test_each_plate_is_a_square_facing_away_from_the_anchors_left_and_tilted_up() -> None:
    cfg = LocalizationConfig()
    a, b = (1.0, 0.6, 0.3), (4.0, 0.6, 0.3)  # A->B along +x: left is +y, the plates face -y
    plates = anchor_marker_corners(a, b, cfg)
    assert sorted(plates) == [11, 12]
    for mid, exit_pt in zip((11, 12), (a, b), strict=True):
        c = plates[mid]
        sides = np.linalg.norm(c - np.roll(c, -1, axis=0), axis=1)
        np.testing.assert_allclose(sides, cfg.anchor_marker_size_m, atol=1e-12)
        np.testing.assert_allclose(c.mean(axis=0), np.asarray(exit_pt) + (0.0, 0.3, -0.1), atol=1e-12)
        n = np.cross(c[3] - c[0], c[1] - c[0])  # out of the face (ArUco order TL, TR, BR, BL)
        n /= np.linalg.norm(n)
        np.testing.assert_allclose(n, (0.0, -math.sqrt(0.5), math.sqrt(0.5)), atol=1e-12)
    assert anchor_marker_corners(a, a, cfg) == {}  # no baseline: no frame, no plates


def _pose(yaw: float, t: tuple[float, float, float], tilt: float = -0.3) -> CameraPose:
    # a camera looking along +x turned by yaw and tilted down: any proper rotation will do
    base = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # camera z forward = world x
    return CameraPose(so3_exp(np.array([0.0, 0.0, yaw])) @ so3_exp(np.array([0.0, -tilt, 0.0])) @ base,
                      np.asarray(t, float))


def test_a_resected_view_carries_the_rovers_error_to_another_view_of_its_standing() -> None:
    # The rover's estimate is off by one rigid motion G of the world (3 deg, 5 cm); both views share it.
    dR, shift, pivot = so3_exp(np.array([0.0, 0.0, math.radians(3.0)])), np.array([0.05, -0.03, 0.01]), np.zeros(3)

    def G(p: CameraPose) -> CameraPose:
        return CameraPose(dR @ p.R, dR @ (p.t - pivot) + pivot + shift)

    pred_plate = _pose(1.2, (2.0, -0.4, 1.3))
    pred_fix = _pose(-1.4, (2.05, -0.45, 1.28), tilt=-0.6)
    cov = np.diag([1e-6] * 3 + [1e-4] * 3)
    got = transport(PoseEstimate(G(pred_plate), cov), pred_plate, pred_fix, np.zeros((6, 6)))
    true_fix = G(pred_fix)
    np.testing.assert_allclose(got.pose.R, true_fix.R, atol=1e-12)
    np.testing.assert_allclose(got.pose.t, true_fix.t, atol=1e-12)
    # the lever: a rotation of the measured view moves the other view's centre by dtheta x v
    v = true_fix.t - G(pred_plate).t
    assert got.cov[3:, 3:].trace() == pytest.approx(1e-4 * 3 + 1e-6 * (2 * float(v @ v)), rel=1e-9)
    with_joints = transport(PoseEstimate(G(pred_plate), cov), pred_plate, pred_fix, np.eye(6) * 1e-5)
    np.testing.assert_allclose(with_joints.cov - got.cov, np.eye(6) * 1e-5, atol=1e-15)


def test_fusing_two_views_weights_them_by_their_information() -> None:
    p = _pose(0.3, (1.0, 2.0, 1.0))
    q = CameraPose(so3_exp(np.array([0.0, 0.0, 0.01])) @ p.R, p.t + np.array([0.02, 0.0, 0.0]))
    a = PoseEstimate(p, np.eye(6) * 1e-4)
    b = PoseEstimate(q, np.eye(6) * 3e-4)
    f = fuse([a, b])
    d = np.concatenate([so3_log(f.pose.R @ p.R.T), f.pose.t - p.t])
    np.testing.assert_allclose(d, [0.0, 0.0, 0.0025, 0.005, 0.0, 0.0], atol=1e-9)  # a quarter of the way to b
    np.testing.assert_allclose(f.cov, np.eye(6) * 0.75e-4, atol=1e-15)
    assert fuse([a]) is a
    assert camera_from_landmarks([], p, np.zeros((6, 6))) is None
    with pytest.raises(ValueError):
        fuse([])


def _aim(cfg, rover, target):  # type: ignore[no-untyped-def]
    base = camera_pose_from_rover(rover, (0.0, 0.0, 0.3), cfg.mast).t
    d = np.asarray(target, float) - base
    pan = math.atan2(d[1], d[0]) - rover[2]
    pan = math.atan2(math.sin(pan), math.cos(pan))
    return cfg.mast.clamp(pan, math.atan2(d[2], math.hypot(d[0], d[1])), 0.3)


@pytest.mark.slow  # three stereo renders
def test_a_fix_through_the_plates_is_as_good_as_one_from_an_exact_camera() -> None:
    """The rover's estimate is 3 deg and 6 cm off (a long mission's drift, docs/results/team-mission.md):
    the fix from its estimate is off by range x 3 deg; through the plates it is within 2 cm and
    1 deg and its NEES within the chi-square bound."""
    cfg = load_settings()
    world = load_scenario("cliff-team", 0)
    grid = MapGrid.from_config(world.map_grid)
    rig = CliffbotRig(world, grid, TetherConfig(), ClimberConfig())
    seen = rig.world_now()  # the Cliff-bot at its start and the Anchorbots' plates
    plates = anchor_marker_corners(rig.anchors[0], rig.anchors[1], cfg.localization)
    loc = CliffbotLocalizer(cfg.localization, cfg.cliffbot, cfg.camera.K, cfg.camera.baseline_m)
    rend = StereoRenderer(seen, cfg.camera, world.noise_sigma, seed=5)
    truth = (0.6, -0.45, 0.2)
    est = (truth[0] + 0.05, truth[1] - 0.03, truth[2] + math.radians(3.0))
    js = math.radians(cfg.capture.joint_sigma_deg)
    nav_cov = np.diag([0.01**2, 0.01**2, math.radians(0.5) ** 2])

    def view(target):  # type: ignore[no-untyped-def]
        joints = _aim(cfg, est, target)
        left, right = rend.render(camera_pose_from_rover(truth, joints, cfg.mast))
        pred, pred_cov = camera_pose_covariance(NavPose(0.0, *est, nav_cov, joints), cfg.mast, (js, js, 0.002))
        q = camera_pose_covariance(NavPose(0.0, *est, np.zeros((3, 3)), joints), cfg.mast, (js, js, 0.002))[1]
        return left, right, pred, pred_cov, q

    landmarks = []
    for c in plates.values():
        left, right, pred, _, q = view(c.mean(axis=0))
        m = loc.resect(plates, left, right)
        if m is not None:
            landmarks.append(Landmark(m, pred, q))
    assert landmarks
    cb = seen.cliffbot
    left, right, pred, pred_cov, q = view(cb.t + np.array([0.0, 0.0, 0.25]))
    camera = camera_from_landmarks(landmarks, pred, q)
    assert camera is not None
    fix = loc.locate(left, camera, right)
    raw = loc.locate(left, PoseEstimate(pred, pred_cov), right)
    assert fix is not None and raw is not None
    rng = float(np.linalg.norm(cb.t - pred.t))
    e = np.concatenate([so3_log(fix.R @ cb.R.T), fix.t - cb.t])
    assert 100 * np.linalg.norm(fix.t - cb.t) <= 2.0 and math.degrees(abs(fix.yaw - cb.yaw)) <= 1.0, (rng, e)
    assert float(e @ np.linalg.solve(fix.cov, e)) <= CHI2_95_6DOF
    # from the rover's estimate alone the fix carries its heading error over the range
    assert math.degrees(abs(raw.yaw - cb.yaw)) > 2.5
    assert np.linalg.norm(raw.t - cb.t) > 0.05  # (range 2 m: 3 deg is 10 cm, less the place error)
