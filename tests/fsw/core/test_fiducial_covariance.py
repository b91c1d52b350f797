"""The fiducial fix's covariance stops shrinking with its corners (fsw.core.localization.fiducials;
docs/team.md, "Relative localization"): one rendered pair, the Cliff-bot at about 3 m."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from fsw.core.geometry import camera_pose_from_rover
from fsw.core.localization.fiducials import CliffbotLocalizer
from fsw.core.localization.localization import PoseEstimate
from fsw.settings import load_settings
from hil_sim.render import StereoRenderer
from hil_sim.world import load_scenario

pytestmark = pytest.mark.slow  # one stereo render (a few seconds on a loaded machine)


def test_a_many_corner_fix_keeps_the_shared_error_in_its_covariance() -> None:
    cfg = load_settings()
    world = load_scenario("lab")
    cb = world.cliffbot
    base = camera_pose_from_rover(world.rover_start, (0.0, 0.0, 0.3), cfg.mast)
    d = np.array([cb.x, cb.y, cb.z + 0.25]) - base.t
    pan = math.atan2(d[1], d[0]) - world.rover_start[2]
    tilt = math.atan2(d[2], math.hypot(d[0], d[1]))
    pose = camera_pose_from_rover(world.rover_start, cfg.mast.clamp(pan, tilt, 0.3), cfg.mast)
    left, right = StereoRenderer(world, cfg.camera, world.noise_sigma, seed=3).render(pose)
    exact = PoseEstimate(pose, np.zeros((6, 6)))

    def locate(shared: int) -> tuple[np.ndarray, int]:
        lcfg = dataclasses.replace(cfg.localization, fiducial_shared_residuals=shared)
        est = CliffbotLocalizer(lcfg, cfg.cliffbot, cfg.camera.K, cfg.camera.baseline_m).locate(left, exact, right)
        assert est is not None
        return est.cov, len(est.marker_ids)

    independent, n_markers = locate(100000)  # every corner independent: (J^T J)^-1 alone
    shared, _ = locate(24)
    assert n_markers >= 1
    # a stereo fix has 2 x 2 x 4 residuals per marker seen in both images: more than 24 ->
    # the covariance is scaled up by residuals / 24, the same for every entry
    ratio = np.trace(shared) / np.trace(independent)
    assert ratio >= 1.0 - 1e-9
    np.testing.assert_allclose(shared, ratio * independent, rtol=1e-9, atol=1e-15)
    if n_markers >= 2:
        assert ratio > 1.0
