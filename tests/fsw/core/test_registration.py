"""Registration of a view against the map (issue 13, item 2; ALGORITHM.md §5.1): a known
injected pose error is recovered; unconstrained directions stay at their prior; a view that
cannot be registered says why and is merged with an inflated covariance; bounded steps."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fsw.core.geometry import CameraPose, MapGrid
from fsw.core.registration import (
    Registration,
    RegistrationConfig,
    apply_correction,
    inflate,
    reference_cells,
    register_points,
    register_steps,
)

GRID = MapGrid(0.0, 0.0, 0.03, 120, 120)
CFG = RegistrationConfig()
PRIOR = np.diag([math.radians(0.5) ** 2] * 3 + [0.05**2] * 3)


def rough(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Sloped, undulating ground: constrains all six pose directions."""
    return 0.06 * np.sin(2 * np.pi * x / 0.9) + 0.05 * np.cos(2 * np.pi * y / 0.7) + 0.08 * x - 0.03 * y


def level(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.zeros(np.broadcast(x, y).shape)


def make_map(surface, sigma_m: float = 0.004):  # type: ignore[no-untyped-def]
    X, Y = GRID.centers()
    z = surface(X, Y)
    var = np.full(GRID.shape, sigma_m**2)
    n = np.ones(GRID.shape, np.int32)
    return z, var, n


def view_points(surface, true_pose: CameraPose, wrong_pose: CameraPose, box, noise_m: float = 0.004,  # type: ignore[no-untyped-def]
                n: int = 20000, seed: int = 0):
    """Points of the surface in ``box`` as a camera at ``true_pose`` sees them, put into the
    world with ``wrong_pose`` (the view's erroneous pose), with stereo noise."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(box[0], box[1], n)
    y = rng.uniform(box[2], box[3], n)
    p = np.column_stack([x, y, surface(x, y)])
    pc = true_pose.world_to_camera(p) + rng.normal(0.0, noise_m, (n, 3))
    cov = np.broadcast_to(np.eye(3) * noise_m**2, (n, 3, 3)).copy()
    return wrong_pose.camera_to_world(pc), cov


def looking_down_x() -> CameraPose:
    fwd = np.array([math.cos(-0.6), 0.0, math.sin(-0.6)])
    right = np.array([0.0, -1.0, 0.0])
    return CameraPose(np.column_stack([right, np.cross(fwd, right), fwd]), np.array([0.2, 1.8, 1.5]))


def with_error(pose: CameraPose, d: np.ndarray) -> CameraPose:
    """The pose a view would carry if its true pose is ``apply_correction(it, d)``."""
    from fsw.core.localization import so3_exp

    return CameraPose(so3_exp(-d[:3]) @ pose.R, pose.t - d[3:])


def test_recovers_a_known_injected_pose_error_on_rough_ground() -> None:
    """Roll 0.4, pitch -0.3, yaw 0.25 deg, x 2 cm, y -1.5 cm, z 3 cm injected: recovered to
    0.05 deg and 5 mm on ground whose slopes constrain all six directions."""
    d_err = np.r_[np.radians([0.4, -0.3, 0.25]), 0.02, -0.015, 0.03]
    true = looking_down_x()
    wrong = with_error(true, d_err)
    z, var, n = make_map(rough)
    pts, cov = view_points(rough, true, wrong, (1.0, 3.2, 0.6, 3.0))
    reg = register_points(pts, cov, wrong, PRIOR, GRID, z, var, reference_cells(z, var, n, CFG), CFG)
    assert reg.status == "registered", reg.reason
    np.testing.assert_allclose(np.degrees(reg.correction[:3]), np.degrees(d_err[:3]), atol=0.05)
    np.testing.assert_allclose(reg.correction[3:], d_err[3:], atol=0.005)
    fixed = apply_correction(wrong, reg.correction)
    assert np.linalg.norm(fixed.t - true.t) < 0.006
    assert set(reg.summary()["constrained"]) >= {"R", "P", "z"}
    sd = np.sqrt(np.diag(reg.cov))
    assert np.all(sd[:3] < math.radians(0.5)) and np.all(sd[3:] < 0.05)  # better than the prior
    assert reg.residual_sigma < 2.0


def test_level_ground_fixes_height_and_tilt_only() -> None:
    """On level ground x, y and yaw are not observable: they stay at the prior (no
    correction, not flagged constrained); height, roll and pitch are recovered."""
    d_err = np.r_[np.radians([-0.3, 0.35, 0.2]), 0.03, 0.02, -0.025]
    true = looking_down_x()
    wrong = with_error(true, d_err)
    z, var, n = make_map(level)
    pts, cov = view_points(level, true, wrong, (1.0, 3.2, 0.6, 3.0))
    reg = register_points(pts, cov, wrong, PRIOR, GRID, z, var, reference_cells(z, var, n, CFG), CFG)
    assert reg.status == "registered", reg.reason
    fixed = apply_correction(wrong, reg.correction)
    # the surface normal (and so roll and pitch) and the height are right again
    np.testing.assert_allclose(fixed.R[2], true.R[2], atol=math.radians(0.05))
    assert abs(reg.correction[2]) < math.radians(0.02) and np.hypot(*reg.correction[3:5]) < 0.002
    c = reg.summary()["constrained"]
    assert "x" not in c and "y" not in c and "Y" not in c


def test_too_little_overlap_and_empty_map_are_reported() -> None:
    true = looking_down_x()
    z, var, n = make_map(rough)
    n[:, :] = 0  # nothing mapped: the view is the map's reference
    pts, cov = view_points(rough, true, true, (1.0, 3.2, 0.6, 3.0), n=2000)
    ref = reference_cells(z, var, n, CFG)
    assert register_points(pts, cov, true, PRIOR, GRID, z, var, ref, CFG).status == "reference"
    n[:, :] = 1
    n[:, 40:] = 0  # mapped only where the view barely reaches
    var[:, :40] = 0.05**2  # ... and too poorly to be a reference
    var[:5, :5] = 0.001**2
    reg = register_points(pts, cov, true, PRIOR, GRID, z, var, reference_cells(z, var, n, CFG), CFG)
    assert reg.status == "unregistered" and "overlap" in reg.reason
    assert np.all(reg.correction == 0)
    big = inflate(PRIOR, CFG)
    assert np.all(np.diag(big) > np.diag(PRIOR))
    assert math.sqrt(big[0, 0] - PRIOR[0, 0]) == pytest.approx(math.radians(CFG.inflate_rot_deg))


def test_ill_conditioned_overlap_is_refused() -> None:
    """Overlap on a strip along the viewing direction: roll about that strip and height are
    one combination; the normal matrix is singular there and the view is not registered."""
    true = looking_down_x()
    z, var, n = make_map(level)
    pts, cov = view_points(level, true, true, (1.0, 3.2, 1.79, 1.81), n=5000)
    reg = register_points(pts, cov, true, PRIOR, GRID, z, var, reference_cells(z, var, n, CFG), CFG)
    assert reg.status == "unregistered" and "ill-conditioned" in reg.reason


def test_registration_runs_in_bounded_steps_and_rejects_garbage() -> None:
    """One Gauss-Newton iteration per step (slack-job slices); NaN points are ignored."""
    d_err = np.r_[np.radians([0.2, -0.2, 0.0]), 0.0, 0.0, 0.02]
    true = looking_down_x()
    wrong = with_error(true, d_err)
    z, var, n = make_map(rough)
    pts, cov = view_points(rough, true, wrong, (1.0, 3.2, 0.6, 3.0))
    pts[::7] = np.nan
    gen = register_steps(pts, cov, wrong, PRIOR, GRID, z, var, reference_cells(z, var, n, CFG), CFG)
    steps = 0
    try:
        while True:
            next(gen)
            steps += 1
    except StopIteration as stop:
        reg: Registration = stop.value
    assert 2 <= steps <= CFG.iterations + 1 and reg.status == "registered"
    assert abs(reg.correction[5] - 0.02) < 0.004
