"""Each agent's views fused as its own flight program fuses them, for the harnesses that fuse both
agents' views into maps they share (``hil_sim.team.face_scene``, ``hil_sim.team.team_views_run``;
docs/team.md, "Both agents sense").

The RECON-bot's sensing pipeline runs on the configuration itself (``FswConfig``: its camera,
``[stereo]``, ``[fusion]``); the Cliff-bot's on
:class:`fsw.tasks.cliffbot.sensing.CliffbotPipelineSettings` built from the same configuration
(its camera from ``[cliffbot_sensing]``, its disparity search, and its own fusion: the lip guard
on the sight line and the source-reach variance, docs/algorithm.md §1.2, §4). The harnesses read
both here, from where the flight reads them, so a change to the flight's settings is measured
without a copy to keep in step.

A map a harness shares between the agents takes each view with that view's agent's fusion
settings (:func:`merge_as`): the flight fuses per pipeline, each with its own settings, while an
``ElevationMap`` holds one ``FusionConfig``; and, as the flight's pipeline does, the merge is
given the camera centre (the source-reach variance needs the lines of sight, §1.2).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from fsw.core.map.elevation_map import ElevationMap, FusionConfig, MergeStats
from fsw.core.pipeline import PipelineSettings
from fsw.core.steps import run_to_end
from fsw.settings import FswConfig
from fsw.tasks.cliffbot.sensing import CliffbotPipelineSettings

F64 = NDArray[np.float64]


def agent_settings(cfg: FswConfig) -> dict[str, PipelineSettings]:
    """Each agent's sensing pipeline settings as its flight program builds them from ``cfg``."""
    return {"recon": cfg, "cliffbot": CliffbotPipelineSettings.of(cfg)}


def merge_as(emap: ElevationMap, parts: Sequence[tuple[F64, F64, F64 | None]], fusion: FusionConfig,
             eye: F64 | None, p_visible: F64 | NDArray[np.bool_] | None = None) -> MergeStats:
    """One view's parts ``(xyz, cov, cov_common)`` into ``emap`` with the viewing agent's
    ``fusion`` settings (the map's own are lent out for this one merge) and its camera centre
    ``eye`` (world), as that agent's flight pipeline merges them (``SensingPipeline.fuse_steps``)."""
    own = emap.cfg
    emap.cfg = fusion
    try:
        return run_to_end(emap.merge_parts_steps(list(parts), p_visible=p_visible, eye=eye))
    finally:
        emap.cfg = own
