"""The RECON-bot's team mask from the surveyed site (docs/algorithm.md §8.1, ``[cliffbot_site]
mask_team``): the Cliff-bot at its start, the Anchorbots and the tethers are kept out of the
RECON-bot's map, the ground round the robots and under the tethers is not."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from fsw.core.map.body_mask import team_mask
from fsw.sections import CliffbotSiteConfig
from fsw.settings import load_settings
from fsw.tasks.perception import SITE_BELOW_M, site_team


def _cfg(yaw_deg: float, mask: bool = True):
    cfg = load_settings()
    site = CliffbotSiteConfig(anchor_a_xyz=(-1.0, 1.0, cfg.tether.anchor_exit_m),
                              anchor_b_xyz=(3.0, 1.0, cfg.tether.anchor_exit_m),
                              start_xy=(1.0, 2.0), start_yaw_deg=yaw_deg, mask_team=mask)
    return dataclasses.replace(cfg, cliffbot_site=site)


def test_no_mask_unless_the_site_asks() -> None:
    assert site_team(load_settings()) is None
    assert site_team(_cfg(0.0, mask=False)) is None


def test_the_cliffbot_at_its_start_and_its_tethers_are_masked() -> None:
    team = site_team(_cfg(90.0))
    assert team is not None and len(team.boxes) == 3 and len(team.tethers) == 2
    pts = np.array([
        [1.0, 2.0, 0.2],     # the body
        [1.0, 2.0, 0.45],    # its inclined top plate
        [0.0, 1.5, 0.225],   # halfway along tether A (exit 0.3 m up, attachment 0.15 m up)
        [1.0, 3.0, 0.0],     # the ground 1 m ahead of it
        [1.4, 2.0, 0.2],     # 0.4 m to its right: beyond its half width (0.23 m) and the margin
        [1.0, 2.0, 0.9],     # above its top
    ])
    masked = team_mask(pts, None, team)
    assert masked.tolist() == [True, True, True, False, False, False]
    # the box turns with the surveyed heading: 0.4 m off the centre along its length is on it
    turned = site_team(_cfg(0.0))
    assert turned is not None and team_mask(pts[4:5], None, turned)[0]
    # the box reaches under the start's ground (its height is known from the anchors' only)
    assert team_mask(np.array([[1.0, 2.0, -0.1]]), None, team)[0]
    assert not math.isnan(float(team.boxes[0].center[2]))


def test_the_anchorbots_are_masked_and_the_ground_under_the_tethers_kept() -> None:
    team = site_team(_cfg(90.0))
    assert team is not None
    # Anchorbot A stands on (-1, 1, 0): its body is masked, the plateau beside it is not
    body = np.array([[-1.0, 1.0, 0.3], [-0.75, 1.2, 0.1], [-1.0, 1.0, 0.42]])
    beside = np.array([[-1.0, 0.4, 0.0], [-1.6, 1.0, 0.01]])
    # under tether A (exit (-1, 1, 0.3) to the attachment (1, 2, 0.15)): the ground, and the
    # tether itself halfway along (0.225 m up)
    under = np.array([[0.0, 1.5, 0.0], [0.5, 1.75, 0.005], [-0.5, 1.25, -0.05]])
    on_tether = np.array([[0.0, 1.5, 0.225], [0.0, 1.5, 0.19]])
    pts = np.concatenate([body, beside, under, on_tether])
    cov = np.tile(np.diag([0.01**2] * 3), (len(pts), 1, 1))
    eye = np.array([0.0, -2.0, 1.5])  # the mast, looking along the tethers
    masked = team_mask(pts, cov, team, eye=eye)
    assert masked.tolist() == [True] * 3 + [False] * 5 + [True] * 2
    # without the ground under the tethers known, their tube and sight test take it
    bare = dataclasses.replace(team, tethers=tuple(dataclasses.replace(t, ground=None) for t in team.tethers))
    assert team_mask(under, cov[:3], bare, eye=eye).any()
    # with a wide point error a point well above the ground line is still the tether's
    wide = np.tile(np.diag([0.03**2] * 3), (2, 1, 1))
    assert team_mask(on_tether, wide, team, eye=eye).all()


def test_the_recon_bots_site_is_the_cliffbots() -> None:
    from fsw.core.geometry import MapGrid
    from hil_sim.team.team_bench import TeamFrame, recon_site
    from hil_sim.world import load_scenario

    world = load_scenario("cliff-team", seed=0)
    assert world.team is not None
    cfg = load_settings()
    site = recon_site(world, MapGrid.from_config(world.map_grid), cfg.tether)
    assert site.mask_team
    x0, y0, yaw0 = (float(v) for v in world.rover_start)
    frame = TeamFrame(x0, y0, yaw0, float(world.ground_at(x0, y0)))
    assert np.allclose(frame.to_world(np.array(site.start_xy)), world.team.cliffbot_start_xy, atol=1e-9)
    # the mask's box stands on the true ground at the start (its height from the anchors')
    team = site_team(dataclasses.replace(cfg, cliffbot_site=site))
    assert team is not None
    box = team.boxes[0]
    ground = box.center[2] - box.half[2] + SITE_BELOW_M
    truth = float(world.ground_at(*world.team.cliffbot_start_xy)) - frame.datum_m
    assert abs(ground - truth) < 0.05, (ground, truth)
    # heading away from the anchors: the start lies ahead of the anchors' midpoint
    mid = frame.to_map(np.asarray(world.team.anchors_xy, float)).mean(axis=0)
    yaw = math.radians(site.start_yaw_deg)
    assert (np.array(site.start_xy) - mid) @ np.array([math.cos(yaw), math.sin(yaw)]) > 0
