"""The Cliff-bot's own views at its start, masked as its sensing task masks them (issue 27): no
robot or tether point reaches its map (judged on the renderer's labels) and the ground under
both tethers, from each Anchorbot's contact-known foot to its own body, is known."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from fsw.core.geometry import MapGrid
from fsw.core.map.body_mask import MaskConfig, TeamGeometry
from fsw.core.pipeline import RegisteredPose, SensingPipeline
from fsw.core.registration.registration import Registration
from fsw.core.steps import run_to_end
from fsw.core.team.cliffbot_head import head_end, head_pose_covariance
from fsw.core.team.tether import ground_profile
from fsw.settings import load_settings
from fsw.tasks.cliffbot import sensing as S
from hil_sim.render import StereoRenderer
from hil_sim.team.cliffbot_rig import CliffbotRig
from hil_sim.team.face_scene import team_points
from hil_sim.team.team_sensing import CliffbotHeadCamera, team_quads
from hil_sim.world import load_scenario

CLIFFBOT_TOML = Path(__file__).resolve().parents[2] / "config" / "cliffbot.toml"


def _grounded(team: TeamGeometry, on: bool) -> TeamGeometry:
    return team if on else dataclasses.replace(
        team, boxes=tuple(dataclasses.replace(b, ground=None) for b in team.boxes))


@pytest.mark.slow
def test_the_cliffbots_start_views_know_the_ground_under_its_tethers() -> None:
    cfg = load_settings(CLIFFBOT_TOML, check_calibration=False)
    w = load_scenario("cliff-team", 0)
    assert w.config is not None
    grid = MapGrid.from_config(w.config.map)
    cfg = dataclasses.replace(cfg, map=w.config.map)
    rig = CliffbotRig(w, grid, cfg.tether, cfg.climber)
    sc = cfg.cliffbot_sensing
    cam = CliffbotHeadCamera(rig, sc, 0)
    P = np.diag([0.03**2, 0.03**2, math.radians(1.0) ** 2])  # its estimate after a fix
    s = np.array([rig.xy[0] + 0.03, rig.xy[1] - 0.02, rig.yaw + math.radians(0.5)])
    body_z = float(w.ground_at(*rig.xy))
    pipes = {}
    for on in (True, False):
        pipes[on] = SensingPipeline(S.CliffbotPipelineSettings.of(cfg), None)
        pipes[on].team_with_camera = True
        pipes[on].team_mask_cfg = MaskConfig(margin_m=S.MARGIN_M, behind=1.0, behind_tether=S.BEHIND_TETHER)
    team = S.cliffbot_team(cfg, s, P, 0.0, 0.0, body_z, rig.anchors, rig.z, grid)
    fused_team = {True: 0, False: 0}
    judged = 0
    for k, pan_deg in enumerate(sc.pan_deg):
        pan = math.radians(pan_deg)
        true_pose = cam.true_pose(k + 1)
        rend = StereoRenderer(rig.world_now(), cam.camera, w.noise_sigma, seed=k)
        left, right, quad, terrain = rend.render_labelled(true_pose, team_quads(cam.team_now(), true_pose.t))
        pose, cov = head_pose_covariance(s[:2], body_z, float(s[2]), 0.0, 0.0, pan, math.radians(sc.tilt_of(k)),
                                         sc.head_m, head_end(pan, sc.head_end_m, sc.place_of(k)), P, sc.height_sigma_m,
                                         math.radians(sc.tilt_sigma_deg))
        placed = RegisteredPose(Registration("off", "test"), pose, cov, None)
        pipe0 = pipes[True]
        dm = run_to_end(pipe0.matcher.match_steps(left, right))
        pts = run_to_end(pipe0.matcher.triangulate_steps(dm.disparity_px, sigma_px=dm.sigma_px))
        on_team = team_points(pts, quad, terrain)
        judged += int(on_team.sum())
        sub = dataclasses.replace(pts, xyz_c=pts.xyz_c[on_team], cov_c=pts.cov_c[on_team], uv=pts.uv[on_team],
                                  disparity_px=pts.disparity_px[on_team])
        for on, pipe in pipes.items():
            pipe.team = _grounded(team, on)
            fused_team[on] += sum(len(x) for x, _, _ in run_to_end(pipe.world_parts_steps(placed, sub)))
            run_to_end(pipe.fuse_steps(placed, run_to_end(pipe.world_parts_steps(placed, pts))))
    assert judged > 300  # the robots and tethers are in the views
    assert fused_team == {True: 0, False: 0}

    def unknown_under_tethers(on: bool) -> list[float]:
        m = pipes[on].map
        z = np.where(m.mapped, m.z, np.nan)
        X, Y = grid.centers()
        for a in rig.anchors[:, :2]:  # known by contact: each Anchorbot's foot, its own body
            z[(np.abs(X - a[0]) <= S.ANCHOR_FOOT_M) & (np.abs(Y - a[1]) <= S.ANCHOR_FOOT_M)] = 0.0
        z[np.hypot(X - rig.xy[0], Y - rig.xy[1]) <= cfg.climber.footprint_m + 0.15] = 0.0
        out: list[float] = []
        for a in rig.anchors:
            d, h, _ = ground_profile(z, grid, a[:2], rig.xy, cfg.tether.sample_m)
            out += d[~np.isfinite(h)].round(2).tolist()
        return out

    assert unknown_under_tethers(True) == []
    assert unknown_under_tethers(False)  # the robots' grown masks take ground the tethers run over
