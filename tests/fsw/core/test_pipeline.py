"""The sensing pipeline (``fsw.core.pipeline``): the one view -> map implementation, which the
perception task runs as its slack job; on rendered lab pairs (small images, ideal cameras)."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest
from step_count import count_steps

from fsw.core.pipeline import STAGES, SensingPipeline
from fsw.executive.executive import Executive
from fsw.framework.clock import SteppedClock
from fsw.settings import FswConfig, load_settings
from fsw.tasks.messages import CameraFrame
from hil_sim.lab.perception_eval import PERCEPTION_LAB, pit_view_poses
from hil_sim.render import StereoRenderer
from hil_sim.world import load_scenario

pytestmark = pytest.mark.slow
PRIOR = np.diag([math.radians(0.3) ** 2] * 3 + [0.02**2] * 3)
_LINKS = itertools.count()


@pytest.fixture(scope="module")
def small() -> tuple[FswConfig, list[CameraFrame]]:
    """A 320x240 ideal camera on the lab pit, and two frames of it with a pose prior."""
    world = load_scenario(PERCEPTION_LAB)
    cfg = load_settings()
    cfg = dataclasses.replace(cfg, map=world.map_grid,
                              camera=dataclasses.replace(cfg.camera, width_px=320, height_px=240, calibration_file=""),
                              stereo=dataclasses.replace(cfg.stereo, num_disparities_px=64))
    rend = StereoRenderer(world, cfg.camera, world.noise_sigma, seed=0)
    poses = pit_view_poses(world, cfg.mast, 2, x_span_m=0.6, seed=2)
    return cfg, [CameraFrame(i, 0.0, *rend.render(p), p, PRIOR) for i, p in enumerate(poses)]


def test_stages_are_announced_once_each_in_order(small: tuple[FswConfig, list[CameraFrame]]) -> None:
    cfg, frames = small
    pipeline = SensingPipeline(cfg, None)
    for fr in frames:
        seen: list[str] = []
        yields, sv = count_steps(pipeline.view_steps(fr, seen.append))
        assert seen == list(STAGES)
        assert yields > 10 and sv.merge.points_used > 1000 and sv.view_id == fr.view_id
    assert sv.placed.registration.status in ("registered", "unregistered")  # the second view met a map


def test_the_same_views_give_the_same_map(small: tuple[FswConfig, list[CameraFrame]]) -> None:
    """Deterministic: two pipelines fed the same frames end with identical maps and poses."""
    cfg, frames = small
    a, b = SensingPipeline(cfg, None), SensingPipeline(cfg, None)
    ra = [a.view(fr) for fr in frames]
    rb = [b.view(fr) for fr in frames]
    for x, y in zip(ra, rb, strict=True):
        assert x.merge == y.merge and np.array_equal(x.placed.pose.t, y.placed.pose.t)
    assert np.array_equal(a.map.z, b.map.z, equal_nan=True) and np.array_equal(a.map.var, b.map.var, equal_nan=True)


def test_the_perception_task_merges_through_the_pipeline(small: tuple[FswConfig, list[CameraFrame]]) -> None:
    """The task's update is the pipeline's result: the same map as a bare pipeline's, the
    registration and the edge it fitted."""
    cfg, frames = small
    link = dataclasses.replace(cfg.link, transport=f"inproc://pipeline-test-{next(_LINKS)}")
    task = Executive(dataclasses.replace(cfg, link=link), SteppedClock()).tasks["perception"]
    bare = SensingPipeline(cfg, None)
    for fr in frames:
        _, up = count_steps(task.merge_view(fr))
        sv = bare.view(fr)
        reg = sv.placed.registration
        assert up.points == sv.merge.points_used and up.registration is not None
        assert (up.registration["status"], up.registration["points"]) == (reg.status, reg.points)
        assert up.edge_points == sv.edge_cells.points_xy.shape[0]
        assert up.roi_mapped_fraction == sv.roi_mapped_fraction
    assert task.views == len(frames)
    assert np.array_equal(task.map.z, bare.map.z, equal_nan=True)
    assert np.array_equal(up.snapshot.n, bare.map.n)
