"""Localization (docs/algorithm.md §5, §1.2): PnP with covariance, the recursive pose estimate,
pose covariance propagated into points, and the Cliff-bot body pose composition."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fsw.core.geometry import CameraConfig, CameraPose
from fsw.core.localization import fiducials
from fsw.core.localization.localization import (
    PoseEstimate,
    RecursivePoseFilter,
    pnp_jacobian,
    propagate_point_covariance,
    so3_exp,
    so3_log,
    solve_pnp,
)

K = CameraConfig().K
POSE = CameraPose.from_pan_tilt(0.2, -0.1, 1.3, 0.3, math.radians(-30))


def scene_points(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    pc = np.column_stack([rng.uniform(-1, 1, n), rng.uniform(-0.7, 0.7, n), rng.uniform(2, 4, n)])
    return POSE.camera_to_world(pc)


def project(pose: CameraPose, pts: np.ndarray) -> np.ndarray:
    pc = pose.world_to_camera(pts)
    return np.column_stack([K[0, 0] * pc[:, 0] / pc[:, 2] + K[0, 2],
                            K[1, 1] * pc[:, 1] / pc[:, 2] + K[1, 2]])


def perturb(pose: CameraPose, dx: np.ndarray) -> CameraPose:
    return CameraPose(so3_exp(dx[:3]) @ pose.R, pose.t + dx[3:])


def pose_error(est: CameraPose, ref: CameraPose) -> np.ndarray:
    return np.concatenate([so3_log(est.R @ ref.R.T), est.t - ref.t])


def test_pnp_jacobian_matches_finite_differences() -> None:
    pts = scene_points(6)
    J = pnp_jacobian(POSE, pts, K)
    for k in range(6):
        e = np.zeros(6)
        e[k] = 1e-6
        num = (project(perturb(POSE, e), pts) - project(perturb(POSE, -e), pts)).ravel() / 2e-6
        np.testing.assert_allclose(J[:, k], num, rtol=1e-4, atol=1e-3)


def test_pnp_covariance_is_consistent() -> None:
    """§5: PnP from n >= 4 points; its covariance matches the spread of its errors (NEES)."""
    pts = scene_points(10)
    uv = project(POSE, pts)
    rng = np.random.default_rng(1)
    nees = []
    for _ in range(150):
        est = solve_pnp(pts, uv + rng.normal(0, 0.5, uv.shape), K, 0.5)
        assert est is not None
        e = pose_error(est.pose, POSE)
        nees.append(e @ np.linalg.solve(est.cov, e))
    # mean NEES of a consistent 6-dof estimate is 6 (sigma floor makes it a bit smaller)
    assert 3.5 <= float(np.mean(nees)) <= 7.5


def test_pnp_refuses_degenerate_input() -> None:
    """Bad input: too few, NaN or mismatched points give None, not a crash."""
    pts = scene_points(4)
    uv = project(POSE, pts)
    assert solve_pnp(pts[:3], uv[:3], K, 0.3) is None
    bad = uv.copy()
    bad[0, 0] = np.nan
    assert solve_pnp(pts, bad, K, 0.3) is None
    assert solve_pnp(pts, uv[:3], K, 0.3) is None
    est = solve_pnp(pts, uv, K, 0.3)
    assert est is not None and np.linalg.norm(est.pose.t - POSE.t) < 1e-6


def test_recursive_estimate_shrinks_covariance_and_gates() -> None:
    """§5: with more PnP solutions the recursive mean converges and its covariance shrinks
    like 1/k; a measurement far off its covariance is refused by the chi-square gate."""
    pts = scene_points(8, seed=2)
    uv = project(POSE, pts)
    rng = np.random.default_rng(3)
    first = solve_pnp(pts, uv + rng.normal(0, 0.5, uv.shape), K, 0.5)
    assert first is not None
    filt = RecursivePoseFilter(first)
    for _ in range(15):
        m = solve_pnp(pts, uv + rng.normal(0, 0.5, uv.shape), K, 0.5)
        assert m is not None and filt.update(m)
    ratio = np.trace(filt.estimate.cov) / np.trace(first.cov)
    assert ratio == pytest.approx(1 / 16, rel=0.35)
    err = pose_error(filt.estimate.pose, POSE)
    assert err @ np.linalg.solve(filt.estimate.cov, err) < 22.46
    off = PoseEstimate(perturb(POSE, np.array([0, 0, 0, 0.3, 0, 0])), first.cov)
    assert not filt.update(off) and filt.rejected == 1
    # motion: predict adds process noise
    before = np.trace(filt.estimate.cov)
    filt.predict(CameraPose(np.eye(3), np.array([0, 0, 0.5])), np.eye(6) * 1e-4)
    assert np.trace(filt.estimate.cov) == pytest.approx(before + 6e-4)


def test_point_covariance_propagation_matches_monte_carlo() -> None:
    """§1.2: P = J_pose S_pose J_pose^T + R S_c R^T, checked against sampling the pose."""
    rng = np.random.default_rng(4)
    xyz_c = np.array([[0.3, 0.5, 3.0], [-1.0, 0.2, 2.0]])
    cov_c = np.array([np.diag([1e-6, 1e-6, 4e-5])] * 2)
    A = rng.normal(size=(6, 6)) * 3e-3
    S = A @ A.T
    _, P = propagate_point_covariance(POSE, S, xyz_c, cov_c)
    samples = []
    L = np.linalg.cholesky(S)
    Lc = np.linalg.cholesky(cov_c[0])
    for _ in range(20000):
        p = perturb(POSE, L @ rng.normal(size=6))
        c = xyz_c + (Lc @ rng.normal(size=(3, 2))).T
        samples.append(p.camera_to_world(c))
    s = np.array(samples)
    for i in range(2):
        emp = np.cov(s[:, i, :].T)
        np.testing.assert_allclose(emp, P[i], rtol=0.08, atol=2e-7)


def test_body_pose_composition_covariance_matches_monte_carlo() -> None:
    """§5: T_world_body = T_world_cam inv(T_body_cam), covariance of both propagated."""
    rng = np.random.default_rng(5)
    cam_w = PoseEstimate(POSE, np.diag([1e-5, 1e-5, 2e-5, 1e-4, 1e-4, 4e-5]))
    cam_b = PoseEstimate(CameraPose.from_pan_tilt(-2.5, 0.3, 1.0, 0.1, -0.3),
                         np.diag([3e-5, 1e-5, 1e-5, 2e-4, 5e-5, 1e-4]))
    est = fiducials._compose(cam_w, cam_b, (1,))
    errs = []
    for _ in range(20000):
        a = perturb(cam_w.pose, np.sqrt(np.diag(cam_w.cov)) * rng.normal(size=6))
        b = perturb(cam_b.pose, np.sqrt(np.diag(cam_b.cov)) * rng.normal(size=6))
        R = a.R @ b.R.T
        t = a.t - R @ b.t
        errs.append(np.concatenate([so3_log(R @ est.R.T), t - est.t]))
    emp = np.cov(np.array(errs).T)
    np.testing.assert_allclose(emp, est.cov, rtol=0.1, atol=3e-6)
