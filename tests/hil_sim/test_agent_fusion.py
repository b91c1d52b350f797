"""Both harnesses fuse each agent's views as its flight program does (``hil_sim.team.agent_fusion``;
docs/team.md, "Both agents sense"): the Cliff-bot's through the flight Cliff-bot's pipeline
settings (``fsw.tasks.cliffbot.sensing.CliffbotPipelineSettings``), not the configuration's
default fusion."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from fsw.core.geometry import MapGrid
from fsw.core.map.elevation_map import ElevationMap
from fsw.settings import load_settings
from fsw.tasks.cliffbot.sensing import CliffbotPipelineSettings


def _steep_view(rng: np.random.Generator) -> tuple[MapGrid, np.ndarray, np.ndarray, np.ndarray]:
    """Points on a 70 deg face seen from a camera 1.5 m out and along it (the Cliff-bot's
    grazing look), each with a stereo covariance 1 cm across its sight line, 3 cm along it."""
    g = MapGrid(0.0, 0.0, 0.1, 20, 20)
    x = rng.uniform(0.2, 1.8, 3000)
    y = rng.uniform(0.2, 1.8, 3000)
    p = np.column_stack([x, y, math.tan(math.radians(70.0)) * y])
    eye = np.array([1.0, 3.5, 8.0])
    d = p - eye
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    dd = d[:, :, None] * d[:, None, :]
    cov = 0.03**2 * dd + 0.01**2 * (np.eye(3)[None] - dd)
    return g, p, cov, eye


def test_a_cliffbot_view_into_a_shared_map_takes_the_flight_cliffbots_fusion() -> None:
    """``merge_as``: the same points merged as the Cliff-bot's view carry the source-reach
    variance of its flight settings (on a steep face not what the configuration's fusion gives),
    exactly what a map on those settings fused from the camera centre holds; the shared map
    keeps its own settings after the merge."""
    from fsw.core.steps import run_to_end
    from hil_sim.team.agent_fusion import agent_settings, merge_as

    cfg = load_settings("config/fsw.toml", check_calibration=False)
    settings = agent_settings(cfg)
    flight = CliffbotPipelineSettings.of(cfg).fusion
    assert settings["cliffbot"].fusion == flight and settings["recon"].fusion == cfg.fusion
    assert flight != cfg.fusion  # else this test would show nothing
    g, p, cov, eye = _steep_view(np.random.default_rng(5))
    shared, plain = ElevationMap(g, cfg.fusion), ElevationMap(g, cfg.fusion)
    merge_as(shared, [(p, cov, None)], flight, eye)
    assert shared.cfg == cfg.fusion
    run_to_end(plain.merge_parts_steps([(p.copy(), cov.copy(), None)], eye=eye))
    own = ElevationMap(g, flight)
    run_to_end(own.merge_parts_steps([(p.copy(), cov.copy(), None)], eye=eye))
    m = shared.mapped & plain.mapped
    assert m.sum() > 100
    np.testing.assert_array_equal(shared.var[m], own.var[m])
    assert not np.allclose(shared.var[m], plain.var[m])


def test_the_team_views_harness_fuses_the_cliffbots_views_with_its_flight_settings() -> None:
    """The team-views harness's Cliff-bot view into its own map: the flight Cliff-bot's fusion
    (the source-reach variance from the camera centre), the RECON-bot's view of the same points
    the configuration's."""
    from fsw.core.stereo.occlusion import LipGuard
    from hil_sim.team.team_views_run import TeamViewsRun
    from hil_sim.world import load_scenario

    run = TeamViewsRun(load_scenario("cliff-team", 0), 0, team=True)
    cfg = load_settings(check_calibration=False)
    g = run.grid
    _, p, cov, eye = _steep_view(np.random.default_rng(7))
    p = p + np.array([g.x0 + 1.0, g.y0 + 1.0, 0.0])
    eye = eye + np.array([g.x0 + 1.0, g.y0 + 1.0, 0.0])
    no_lips = LipGuard(g, np.zeros((0, 3)), np.zeros((0, 3)), run.fusion.lip_min_drop_m)
    maps = {}
    for agent in ("recon", "cliffbot"):
        maps[agent] = ElevationMap(g, run.fusion)
        run._merge(maps[agent], agent, agent, eye, no_lips, p, cov, None)
    own = ElevationMap(g, CliffbotPipelineSettings.of(cfg).fusion)
    from fsw.core.steps import run_to_end

    run_to_end(own.merge_parts_steps([(p.copy(), cov.copy(), None)], eye=eye))
    m = maps["cliffbot"].mapped
    assert m.sum() > 20
    np.testing.assert_array_equal(maps["cliffbot"].var[m], own.var[m])
    assert not np.allclose(maps["cliffbot"].var[m], maps["recon"].var[m])


@pytest.mark.slow
def test_the_face_map_bench_runs_the_cliffbots_views_through_its_flight_pipeline(monkeypatch: Any) -> None:
    """The face-map bench builds the Cliff-bot's sensing pipeline on the flight Cliff-bot's
    settings (its camera, disparity search and fusion: the lip guard on the sight line), and the
    RECON-bot's on the configuration."""
    import hil_sim.team.face_scene as fs
    from fsw.core.pipeline import SensingPipeline

    built: list[Any] = []

    class Recording(SensingPipeline):
        def __init__(self, cfg: Any, *args: Any, **kwargs: Any) -> None:
            built.append(cfg)
            super().__init__(cfg, *args, **kwargs)

    monkeypatch.setattr(fs, "SensingPipeline", Recording)
    scene = fs.FaceScene("cliff-team", 3, "config/fsw.toml")
    scene.measure(1, 1)
    flight = CliffbotPipelineSettings.of(scene.cfg)
    assert len(built) == 2
    assert built[0].fusion == scene.cfg.fusion and built[0].camera == scene.cfg.camera
    assert built[1].fusion == flight.fusion and built[1].fusion.lip_sight_line
    assert built[1].camera == flight.camera and built[1].stereo == flight.stereo


def test_the_cliffbots_pipeline_settings_build_on_the_configurations_fusion_and_stereo() -> None:
    """``CliffbotPipelineSettings.of``: the Cliff-bot's two fusion overrides and its disparity
    search sit on top of the configuration's ``[fusion]`` and ``[stereo]``, so a key set there
    reaches the Cliff-bot's views too (built on the library defaults, it was silently ignored)."""
    from dataclasses import replace

    cfg = load_settings("config/fsw.toml", check_calibration=False)
    cfg = replace(cfg, fusion=replace(cfg.fusion, gate_sigma=cfg.fusion.gate_sigma + 1.0),
                  stereo=replace(cfg.stereo, uniqueness_ratio_pct=cfg.stereo.uniqueness_ratio_pct + 5))
    settings = CliffbotPipelineSettings.of(cfg)
    assert settings.fusion.gate_sigma == cfg.fusion.gate_sigma
    assert settings.stereo.uniqueness_ratio_pct == cfg.stereo.uniqueness_ratio_pct
    assert settings.fusion.lip_sight_line and settings.fusion.source_reach_sigma > 0
