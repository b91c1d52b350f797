"""Perception configuration: the [stereo], [fusion], [localization], [cliffbot], [edge],
[geofence] and [checkpoint] sections of config/fsw.toml load, validate and match the bench."""

from __future__ import annotations

import numpy as np
import pytest

from fsw.core.edge.edge import EdgeConfig
from fsw.core.edge.geofence import GeofenceConfig
from fsw.core.localization.fiducials import CliffbotLayout
from fsw.core.localization.localization import LocalizationConfig
from fsw.core.map.checkpoint import CheckpointConfig
from fsw.core.map.elevation_map import FusionConfig
from fsw.core.stereo.stereo import StereoConfig
from fsw.framework.params import ConfigError, build
from fsw.settings import load_settings
from hil_sim.world.cliffbot import build_cliffbot

SECTIONS = {"stereo": StereoConfig, "fusion": FusionConfig, "localization": LocalizationConfig,
            "cliffbot": CliffbotLayout, "edge": EdgeConfig, "geofence": GeofenceConfig,
            "checkpoint": CheckpointConfig}


def test_shipped_config_sets_every_key_to_the_documented_default() -> None:
    cfg = load_settings()
    for name, cls in SECTIONS.items():
        assert getattr(cfg, name) == cls(), name


@pytest.mark.parametrize("section,data,match", [
    ("fusion", {"gate_sigma": 0.1}, "fusion.gate_sigma: 0.1 sigma is below the minimum"),
    ("fusion", {"view_correlation": 1.0}, "fusion.view_correlation"),
    ("fusion", {"gate": 3.0}, "fusion.gate: unknown key"),
    ("edge", {"step_m": "high"}, "edge.step_m: expected a number"),
    ("geofence", {"margin_m": -0.1}, "geofence.margin_m"),
    ("localization", {"corner_refinement": "magic"}, "localization.corner_refinement"),
    ("cliffbot", {"markers": [[1.0, 0, 0, 0, 1, 0, 0, 1, 0, 0]]}, "orthonormal"),
    ("cliffbot", {"markers": [[1.0, 0, 0]]}, "10 numbers"),
    ("checkpoint", {"keep": 1}, "checkpoint.keep"),
])
def test_bad_values_are_refused_with_file_key_reason(section: str, data: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        build(SECTIONS[section], data, "fsw.toml", section)


def test_cliffbot_layout_matches_the_bench_cliffbot() -> None:
    """The configured marker corners are those of the Cliff-bot the bench builds."""
    truth = build_cliffbot(0.0, 0.0, 0.0, 0.0)
    layout = CliffbotLayout().corners_body()
    for m in truth.markers:
        np.testing.assert_allclose(layout[m.id], m.corners_body, atol=1e-9)
