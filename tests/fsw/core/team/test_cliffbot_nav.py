"""The Cliff-bot's EKF: tether lengths locate it; a fix that disagrees beyond both covariances is refused."""

from __future__ import annotations

import math

import numpy as np

from fsw.core.geometry import MapGrid
from fsw.core.team.cliffbot_nav import CliffbotNav, NavConfig
from fsw.core.team.tether import TetherConfig, TetherState, anchor_points, tether_state
from tests.fsw.core.team.test_tether import cliff


def _on_the_face() -> tuple[np.ndarray, MapGrid, TetherConfig, np.ndarray, np.ndarray, TetherState]:
    """The test cliff, its anchors, a place on the face and the tethers' state there."""
    z, grid = cliff()
    cfg = TetherConfig()
    anchors = anchor_points(z, grid, np.array([[-1.5, 1.5], [1.5, 1.5]]), cfg)
    truth = np.array([0.3, -0.5])
    st = tether_state(z, grid, anchors, truth, cfg)
    assert st is not None
    return z, grid, cfg, anchors, truth, st


def test_tether_lengths_pull_the_estimate_to_the_truth() -> None:
    z, grid, cfg, anchors, truth, st = _on_the_face()
    nav = CliffbotNav(truth + np.array([0.12, -0.08]), -math.pi / 2, NavConfig(init_sigma_m=0.2))
    for _ in range(10):
        assert nav.lengths(st.lengths_m, z, grid, anchors, cfg, 0.3)
    assert np.linalg.norm(nav.xy - truth) < 0.03
    assert np.sqrt(np.max(np.linalg.eigvalsh(nav.P[:2, :2]))) < 0.05


def test_fix_gate() -> None:
    nav = CliffbotNav(np.array([1.0, -2.0]), -math.pi / 2, NavConfig(init_sigma_m=0.02))
    cov = np.diag([0.01 ** 2, 0.01 ** 2, math.radians(0.5) ** 2])
    ok, nis = nav.fix(np.array([1.01, -2.005]), -math.pi / 2 + 0.005, cov)
    assert ok and nis < 3.0
    before = nav.s.copy()
    ok, nis = nav.fix(np.array([1.6, -2.0]), -math.pi / 2, cov)  # 0.6 m off, both sure of themselves
    assert not ok and nis > 100
    assert np.array_equal(nav.s, before)  # a refused fix does not move the estimate
    nav.reset(np.array([1.6, -2.0]), -math.pi / 2, cov)
    assert np.allclose(nav.xy, [1.6, -2.0])


def test_a_non_finite_length_is_not_used() -> None:
    z, grid = cliff()
    cfg = TetherConfig()
    anchors = anchor_points(z, grid, np.array([[-1.5, 1.5], [1.5, 1.5]]), cfg)
    nav = CliffbotNav(np.array([0.0, -0.5]), -math.pi / 2, NavConfig())
    assert not nav.lengths((math.nan, 3.0), z, grid, anchors, cfg, 0.3)
    assert np.isfinite(nav.s).all()


def test_a_length_model_error_that_holds_while_it_stands_is_not_averaged_away() -> None:
    """The taut-tether model on the map is a few cm off at this place (its error holds while the
    Cliff-bot stands): 600 length readings leave a covariance that still covers the estimate's
    error; a fix at the truth is fused and takes the model's error with it, so the lengths that
    follow keep the estimate near the truth, and its covariance covers what is left."""
    z, grid, cfg, anchors, truth, st = _on_the_face()
    rng = np.random.default_rng(4)
    model_error = np.array([0.035, 0.02])
    nav = CliffbotNav(truth + np.array([0.02, -0.01]), -math.pi / 2, NavConfig(init_sigma_m=0.05))

    def read() -> tuple[float, float]:
        got = np.asarray(st.lengths_m) + model_error + rng.normal(0.0, 0.005, 2)
        return float(got[0]), float(got[1])

    for _ in range(600):
        nav.predict(0.0, 0.0, 0.1)
        assert nav.lengths(read(), z, grid, anchors, cfg, 0.3)
    err = nav.xy - truth
    assert np.linalg.norm(err) > 0.01  # the lengths alone put it off (the model's error)
    nees = float(err @ np.linalg.solve(nav.P[:2, :2], err))
    assert nees < 13.8  # chi2(2 dof, 0.999): its covariance says so
    ok, nis = nav.fix(truth, -math.pi / 2, np.diag([0.01 ** 2, 0.01 ** 2, math.radians(0.5) ** 2]))
    assert ok, nis
    for _ in range(600):
        nav.predict(0.0, 0.0, 0.1)
        assert nav.lengths(read(), z, grid, anchors, cfg, 0.3)
    assert np.linalg.norm(nav.xy - truth) < 0.012
    err = nav.xy - truth
    assert float(err @ np.linalg.solve(nav.P[:2, :2], err)) < 13.8


def test_a_drives_noise_does_not_depend_on_how_often_the_wheels_are_read() -> None:
    """0.5 m driven read in 1, 10 or 100 steps leaves the same covariance, the length model's
    error included (random walks and a Gauss-Markov process in the distance driven)."""
    got = []
    for steps in (1, 10, 100):
        nav = CliffbotNav(np.array([0.0, -0.5]), -math.pi / 2, NavConfig(drift_mps=0.0))
        for _ in range(steps):
            nav.predict(0.5 / steps, 0.0, 0.0, -math.pi / 2)
        got.append(nav.P_full.copy())
        assert np.allclose(nav.xy, [0.0, -1.0], atol=1e-9)
    for p in got[1:]:
        np.testing.assert_allclose(p, got[0], rtol=1e-9, atol=1e-12)
    assert math.isclose(got[0][0, 0], 0.1 ** 2 + 0.5 ** 2 * 0.5, rel_tol=1e-9)  # init 0.1 m; 0.5 m/sqrt(m) over 0.5 m
