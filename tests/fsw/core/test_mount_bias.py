"""The mount-bias estimator (fsw.core.registration.mount_bias): its model against the pose chain,
recovering known offsets from synthetic corrections, inventing none, refusing bad input, and the
map's levelling."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from fsw.core.geometry import CameraPose, MapGrid, MastConfig, camera_pose_from_rover
from fsw.core.localization.localization import so3_log
from fsw.core.map.elevation_map import ElevationMap
from fsw.core.registration.mount_bias import MountBias, data_only, design, relevel_map

DEG = math.pi / 180.0


def _estimator() -> MountBias:
    return MountBias(0.2, 0.1, 0.03, 13.8, 0.6, 0.02, 7.38)


def _pose(view_yaw: float) -> CameraPose:
    return CameraPose.from_pan_tilt(1.0, 2.0, 1.5, view_yaw, -25 * DEG)


def test_the_model_is_the_pose_chain_to_first_order() -> None:
    """A tilt offset and attitude biases rotate the camera pose by ``H(view yaw, body yaw) x``."""
    mast = MastConfig()
    x = np.array([-0.25, -0.14, 0.05]) * DEG
    for body_yaw, pan in ((0.3, 0.0), (2.0, -1.1), (-2.5, 0.8)):
        joints, att = (pan, -25 * DEG, 0.2), (1.5 * DEG, -2.0 * DEG)
        true = camera_pose_from_rover((0.0, 0.0, body_yaw), (pan, joints[1] + x[0], 0.2), mast, 0.0, att)
        est = camera_pose_from_rover((0.0, 0.0, body_yaw), joints, mast, 0.0, (att[0] + x[1], att[1] + x[2]))
        e = so3_log(est.R @ true.R.T)[:2]
        assert np.allclose(e, design(body_yaw + pan, body_yaw) @ x, atol=0.02 * DEG)


def _views(x: np.ndarray, rng: np.random.Generator, sigma_deg: float) -> tuple[MountBias, np.ndarray]:
    """A panorama at one heading, then views at two more headings, their total tilt corrections
    made from ``x`` (the map's frame is the first view's) with noise ``sigma_deg``."""
    est = _estimator()
    ref_yaw, ref_body = 0.0, 0.0
    est.reference(_pose(ref_yaw), ref_body, np.diag([0.22 * DEG] * 2 + [0.1 * DEG, 0.01, 0.01, 0.01]) ** 2)
    H_ref = design(ref_yaw, ref_body)
    for body in (0.0, 1.6, -2.2):
        for pan in (-1.0, -0.5, 0.5, 1.0):
            yaw = body + pan
            y = (H_ref - design(yaw, body)) @ x + rng.normal(0.0, sigma_deg * DEG, 2)
            assert est.update(_pose(yaw), body, y, np.eye(2) * (sigma_deg * DEG) ** 2) == ""
    return est, H_ref


def test_known_offsets_are_recovered_and_the_map_frame_with_them() -> None:
    x = np.array([-0.256, -0.137, 0.030]) * DEG  # terrain seed 2's draw: 2.6 sigma of the mast's tilt
    est, H_ref = _views(x, np.random.default_rng(1), 0.02)
    sd = np.sqrt(np.diag(est.P))
    assert np.all(np.abs(est.x - x) < 3 * sd + 1e-9)
    assert np.all(sd < 0.5 * np.sqrt(np.diag(est.P0)))  # learned, not the prior
    e, C = est.frame()
    assert np.allclose(e, H_ref @ x, atol=3 * math.sqrt(np.trace(C)))
    assert est.confident()


def test_no_offsets_none_invented() -> None:
    est, _ = _views(np.zeros(3), np.random.default_rng(2), 0.02)
    sd = np.sqrt(np.diag(est.P))
    assert np.all(np.abs(est.x) < 3 * sd)
    assert np.all(np.abs(np.degrees(est.x)) < 0.03)
    emap = ElevationMap(MapGrid(-2.0, -2.0, 0.1, 40, 40))
    emap.z[:], emap.var[:], emap.var_common[:], emap.n[:] = 0.0, 1e-4, 1e-4, 1
    assert est.confident() and est.level(emap) is None  # a level map stays level
    assert np.all(emap.z == 0.0)


def test_one_heading_leaves_the_attitude_biases_at_their_prior() -> None:
    """At one heading the attitude biases act on every view alike: not observable."""
    est = _estimator()
    est.reference(_pose(0.0), 0.0, np.eye(6) * 1e-6)
    for pan in (-1.0, -0.5, 0.5, 1.0):
        assert est.update(_pose(pan), 0.0, (design(0.0, 0.0) - design(pan, 0.0)) @ np.array([0.2 * DEG, 0, 0]),
                          np.eye(2) * (0.02 * DEG) ** 2) == ""
    assert abs(est.x[0] - 0.2 * DEG) < 0.03 * DEG
    assert np.allclose(np.sqrt(np.diag(est.P))[1:], 0.1 * DEG, rtol=0.05)


def test_bad_input_is_refused_and_changes_nothing() -> None:
    est = MountBias(0.2, 0.1, 0.0, 13.8, 0.6, 0.02)  # no floor: a singular covariance stays singular
    assert est.update(_pose(0.5), 0.0, np.zeros(2), np.eye(2)) == "no reference view"
    est.reference(_pose(0.0), 0.0, np.eye(6) * 1e-6)
    x0, P0 = est.x.copy(), est.P.copy()
    assert est.update(_pose(0.5), 0.0, np.array([math.nan, 0.0]), np.eye(2) * 1e-8) != ""
    assert est.update(_pose(0.5), 0.0, np.zeros(2), np.array([[1e-8, math.inf], [0.0, 1e-8]])) != ""
    assert "positive" in est.update(_pose(0.5), 0.0, np.zeros(2), np.zeros((2, 2)))
    assert "positive" in est.update(_pose(0.5), 0.0, np.zeros(2), -np.eye(2) * 1e-8)
    assert est.update(_pose(0.5), math.nan, np.zeros(2), np.eye(2) * 1e-8) == "no body yaw"
    assert "inconsistent" in est.update(_pose(0.5), 0.0, np.array([0.1, 0.0]), np.eye(2) * 1e-8)  # 6 deg
    assert est.refused == 5 and est.used == 0
    assert np.array_equal(est.x, x0) and np.array_equal(est.P, P0)
    assert not est.confident() and est.level(ElevationMap(MapGrid(0, 0, 0.1, 4, 4))) is None


def test_levelling_a_tilted_map_and_the_checkpoint() -> None:
    """A map built in a frame tilted by ``e_ref`` is levelled about the reference camera; the
    estimator's state round-trips through JSON exactly."""
    x = np.array([-0.3, 0.1, -0.05]) * DEG
    est, H_ref = _views(x, np.random.default_rng(3), 0.01)
    grid = MapGrid(-2.0, -2.0, 0.1, 40, 40)
    emap = ElevationMap(grid)
    X, Y = grid.centers()
    c = _pose(0.0).t
    e = H_ref @ x  # the frame's error: heights tilted by it about the reference camera
    emap.z[:] = 0.2 + e[0] * (Y - c[1]) - e[1] * (X - c[0])
    emap.var[:], emap.var_common[:], emap.n[:] = 4e-4, 3e-4, 1
    emap.n[0, 0], emap.z[0, 0], emap.var[0, 0], emap.var_common[0, 0] = 0, np.nan, np.inf, 0.0
    restored = _estimator()
    restored.restore(json.loads(json.dumps(est.state())))
    lev = est.level(emap)
    assert lev is not None
    known = emap.n > 0
    assert np.abs(emap.z[known] - 0.2).max() < 0.002  # 0.3 deg over ~4 m: 2 cm before
    assert np.all(emap.var[known] <= 4e-4) and np.all(emap.var[known] >= 1e-4)
    assert np.isnan(emap.z[0, 0]) and np.isinf(emap.var[0, 0])
    assert est.level(emap) is None  # nothing more to do
    assert np.array_equal(restored.x, _views(x, np.random.default_rng(3), 0.01)[0].x)
    assert restored.level(ElevationMap(grid)) is not None  # the restored one levels the same
    assert np.array_equal(restored.F, est.F)


def test_relevel_map_moves_heights_by_the_rotation() -> None:
    grid = MapGrid(0.0, 0.0, 1.0, 3, 3)
    emap = ElevationMap(grid)
    emap.z[:], emap.var[:], emap.var_common[:], emap.n[:] = 0.0, 1.0, 0.5, 1
    relevel_map(emap, np.array([0.01, 0.0]), np.array([1.5, 1.5, 1.0]), np.zeros((2, 2)))
    assert emap.z[2, 1] == pytest.approx(0.01) and emap.z[0, 1] == pytest.approx(-0.01)  # +y rises under +omega_x
    assert np.all(emap.var == 1.0)


def test_the_registration_prior_is_taken_out() -> None:
    """A weakly constrained registration moves the tilt only part of the way from its prior;
    the data's own measurement is the whole way, with the data's covariance."""
    S = np.diag([0.2, 0.2]) ** 2
    D = np.array([[0.1**2, 0.0], [0.0, 0.5**2]])  # the data: well in x, weakly in y
    C = np.linalg.inv(np.linalg.inv(S) + np.linalg.inv(D))
    z = np.array([0.3, -0.3])
    out = data_only(C @ np.linalg.inv(D) @ z, C, S)
    assert out is not None
    assert np.allclose(out[0], z) and np.allclose(out[1], D)
    assert data_only(np.zeros(2), S, S) is None  # the data fixed nothing
    assert data_only(np.array([math.nan, 0.0]), C, S) is None
    assert data_only(np.zeros(2), np.zeros((2, 2)), S) is None  # singular


def test_the_cells_keep_their_variance_unless_asked() -> None:
    x = np.array([-0.3, 0.1, -0.05]) * DEG
    grid = MapGrid(-2.0, -2.0, 0.1, 40, 40)
    for drop in (False, True):
        est, _ = _views(x, np.random.default_rng(3), 0.01)
        est.drop_variance = drop
        emap = ElevationMap(grid)
        emap.z[:], emap.var[:], emap.var_common[:], emap.n[:] = 0.0, 4e-4, 3e-4, 1
        assert est.level(emap) is not None
        assert np.all(emap.var == 4e-4) != drop
