"""The occluding-lip guard end to end (fsw.core.stereo.occlusion in the sensing pipeline): rendered views of
a generated terrain's cliff edge, merged with a pose that is off by a drive's dead-reckoning
error (and says so in its covariance), put the plateau's height on the occluded face past the
lip; with the guard they do not (docs/perception.md, "Occluding lips")."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy import ndimage

from fsw.core.geometry import CameraPose, MapGrid
from fsw.core.localization.localization import so3_exp
from fsw.core.pipeline import SensingPipeline
from fsw.settings import load_settings
from fsw.tasks.messages import CameraFrame
from hil_sim.lab.perception_eval import edge_pass_poses
from hil_sim.render import StereoRenderer
from hil_sim.world import load_scenario

SCENARIO = "terrain?slope_deg=-1"


def _map_band(lip_guard_sigma: float, seed: int) -> tuple[int, int, float]:
    """Cells mapped more than 10 cm above the truth within 0.3 m past the true edge, cells
    mapped, fraction within 2 sigma: two views along the edge with a -2.5 deg yaw and 6 cm error."""
    cfg = load_settings("config/fsw.toml")
    world = load_scenario(SCENARIO, seed)
    camera = dataclasses.replace(cfg.camera, calibration_file="")  # the ideal renderer's pairs
    grid = MapGrid.from_config(cfg.map)
    # the displaced poses merged as they come (registration off: the guard alone)
    pipeline = SensingPipeline(dataclasses.replace(
        cfg, camera=camera, fusion=dataclasses.replace(cfg.fusion, lip_guard_sigma=lip_guard_sigma),
        registration=dataclasses.replace(cfg.registration, enabled=False)), None)
    render = StereoRenderer(world, camera, float(world.noise_sigma), seed)
    cov = np.diag(np.array([0.3, 0.3, 3.0, 0.0, 0.0, 0.0]) * math.pi / 180) ** 2
    cov[3:, 3:] = np.diag([0.05, 0.05, 0.02]) ** 2
    for i, true in enumerate(edge_pass_poses(world, cfg.mast, stops_x_m=(1.5, 3.0), pans_deg=(-50.0,))):
        left, right = render.render(true)
        est = CameraPose(so3_exp(np.array([0.0, 0.0, math.radians(-2.5)])) @ true.R, true.t + [0.0, -0.06, 0.0])
        pipeline.merge_view(CameraFrame(i, 0.0, left, right, est, cov))
    emap = pipeline.map
    truth = world.truth_on_grid(grid)
    X, Y = grid.centers()
    past = ndimage.distance_transform_edt(~world.on_plateau(X.ravel(), Y.ravel()).reshape(grid.shape)) * grid.cell
    mapped = emap.mapped & np.isfinite(truth)
    err = np.where(mapped, emap.z - truth, np.nan)
    band = int(np.count_nonzero((err > 0.1) & (past > 0) & (past <= 0.3)))
    within = float(np.mean(np.abs(err[mapped]) <= 2 * np.sqrt(emap.var[mapped])))
    return band, int(mapped.sum()), within


@pytest.mark.parametrize("seed", [6, 19])
def test_guard_removes_the_band_past_the_lip_of_a_displaced_view(seed: int) -> None:
    # measured (docs/perception.md): seed 3 177 -> 0, seed 6 80 -> 17, seed 11 462 -> 0, seed 19 483 -> 0
    band0, cells0, _ = _map_band(0.0, seed)
    band, cells, within = _map_band(2.0, seed)
    print(f"without guard: {band0} band cells of {cells0}; with: {band} of {cells}, {100 * within:.1f} % in 2 sigma")
    assert band0 >= 50  # the defect: the plateau's height on the occluded face
    assert band <= band0 // 4
    assert within >= 0.9
    assert cells >= 0.6 * cells0  # the rest of the view is still mapped
