"""One-factor lockstep replays (hil_sim.lab.view_replay): the same views merged again with one
factor changed; the camera path through the TRUE calibration maps the views as the ideal
pinhole pair does (the check that would have told the lab's map regression was not the
calibration), and a pose error the flight did not know shows in the figures."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fsw.core.geometry import CameraPose, camera_pose_from_rover
from fsw.core.localization.localization import so3_exp
from fsw.settings import load_settings
from hil_sim.camera_model import TrueCameras
from hil_sim.lab.view_replay import Factor, RecordedView, replay
from hil_sim.render import StereoRenderer
from hil_sim.rig import load_hardware
from hil_sim.world import load_scenario

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def views() -> list[RecordedView]:
    """One station of the lab seen through the real (distorted, misaligned) cameras, three
    pans; the flight's estimate of the last one is 0.5 deg off in yaw and 4 cm in x."""
    cfg = load_settings()
    world = load_scenario("lab", 0)
    cams = TrueCameras.from_config(cfg.camera, load_hardware().camera)
    rend = StereoRenderer(world, cfg.camera, float(world.noise_sigma), 0, cameras=cams)
    cov = np.diag([math.radians(0.2) ** 2] * 3 + [0.01**2] * 3)
    out = []
    for i, pan in enumerate((-60.0, -90.0, -120.0)):
        true = camera_pose_from_rover(world.rover_start, (math.radians(pan), math.radians(-30.0), 0.5), cfg.mast,
                                      world.plateau_z)
        pose = true if i < 2 else CameraPose(so3_exp(np.r_[0, 0, math.radians(0.5)]) @ true.R,
                                             true.t + np.r_[0.04, 0.0, 0.0])
        out.append(RecordedView(i, *rend.render(true), pose, cov, true))
    return out


def test_true_calibration_path_maps_like_the_ideal_cameras(views: list[RecordedView], tmp_path) -> None:  # type: ignore[no-untyped-def]
    from fsw.drivers.calibration_file import save_calibration

    cfg = load_settings()
    cal = tmp_path / "true.yaml"
    save_calibration(cal, TrueCameras.from_config(cfg.camera, load_hardware().camera).truth())
    est = replay(views, "lab", 0, Factor(true_pose=True))
    true = replay(views, "lab", 0, Factor(true_pose=True, calibration_file=str(cal)))
    ideal = replay(views, "lab", 0, Factor(true_pose=True, calibration_file="", cameras="ideal"))
    for q in (est, true):
        assert abs(q["cells"] / ideal["cells"] - 1) < 0.05
        assert q["rms_m"] < 1.5 * ideal["rms_m"] + 0.005, (q, ideal)
        assert q["within_2sigma"] > 0.9
    assert ideal["within_2sigma"] > 0.9


def test_an_unknown_pose_error_shows(views: list[RecordedView]) -> None:
    flight = replay(views, "lab", 0, Factor(registration=False))
    true = replay(views, "lab", 0, Factor(true_pose=True, registration=False))
    assert flight["rms_m"] > true["rms_m"]


def test_registration_errors_from_true_poses_are_consistent(views: list[RecordedView]) -> None:
    """The views merged from their true poses: each registered one gives a finite NEES, and
    the covariance of the shipped configuration holds its error (mean roll/pitch NEES well
    inside what an overconfident covariance gives; chi-square 2 dof has mean 2)."""
    from hil_sim.lab.view_replay import registration_errors

    rows, q = registration_errors(views, "lab", 0)
    assert 1 <= len(rows) <= len(views) - 1  # the first view begins the map
    assert all(np.isfinite([r["nees_rp"], r["nees6"]]).all() and r["nees_rp"] >= 0 for r in rows)
    assert np.mean([r["nees_rp"] for r in rows]) < 6.0
    assert all(r["tilt_err_deg"] < 3 * r["tilt_sd_deg"] + 0.05 for r in rows)
    assert q["cells"] > 0
