"""The next-view task (fsw/tasks/nbv.py) on a stepped clock: a planning request becomes a
slack job whose result is published once (issue 11, item 5)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
from task_rig import TaskRig, task_config

from fsw.core.geometry import MapGrid
from fsw.core.map.elevation_map import ElevationMap
from fsw.tasks import nbv as nbv_task
from fsw.tasks.messages import NBV_REQUEST, NBV_RESULT

CFG = task_config(("nbv", "nbv"))
GRID = MapGrid(-0.5, -1.5, 0.05, 60, 60)


def _request(rig: TaskRig, emap: Any = None, motion_ok: Any = lambda a, b: False) -> None:
    state = nbv_task.PlannerState(
        map=ElevationMap(GRID) if emap is None else emap,
        rover=(0.0, 0.0, 0.0),
        joints=(0.0, math.radians(-30.0), 0.5),
        path=np.zeros((0, 3)),
        motion_ok=motion_ok,
    )
    rig.publish(NBV_REQUEST, state)


def _planned_map() -> ElevationMap:
    """Flat known ground behind the rover; unknown ahead (where a view has something to map)."""
    emap = ElevationMap(GRID)
    xs, _ = GRID.centers()
    behind = np.broadcast_to(xs < 0.3, GRID.shape)
    emap.z[behind], emap.var[behind], emap.n[behind] = 0.0, 1e-4, 3
    return emap


def test_a_request_is_searched_in_slack_and_answered_once() -> None:
    rig = TaskRig(CFG)
    results = rig.tap(NBV_RESULT)
    _request(rig, _planned_map())
    frames = rig.run_until(lambda: len(results) > 0, 3000)
    assert frames > 2  # the search ran over several frames' slack, not in one activation
    (view,) = results.drain()
    assert view is not None and view.rover == (0.0, 0.0, 0.0)  # no move allowed: mast-only views
    assert CFG.mast.within_limits(*view.joints) and view.info_bits > 0
    assert rig.tlm("nbv.searches") == 1 and rig.tlm("nbv.best_info_bits") == view.info_bits
    assert rig.tlm("nbv.search_slices") > 1 and len(rig.events("nbv.VIEW_CHOSEN")) == 1
    rig.run(20)
    assert not results.drain()


def test_a_failing_search_is_an_event_and_a_none_result() -> None:
    rig = TaskRig(CFG)
    results = rig.tap(NBV_RESULT)
    _request(rig, emap=object())  # not a map: the planner raises inside the job
    rig.run_until(lambda: len(results) > 0, 100)
    assert results.drain() == [None]
    assert len(rig.events("nbv.SEARCH_FAILED")) == 1 and rig.task("nbv").exceptions == 0


def test_requests_while_busy_keep_only_the_newest() -> None:
    """The request mailbox holds one: of three requests made during a search, the last is
    searched next, the others are dropped (and counted by the bus)."""
    rig = TaskRig(CFG)
    results = rig.tap(NBV_RESULT)
    _request(rig, _planned_map())
    rig.run(1)
    for _ in range(3):
        _request(rig, _planned_map())
    rig.run_until(lambda: len(results) >= 2, 6000)
    rig.run(200)
    assert len(results.drain()) == 2 and rig.tlm("nbv.searches") == 2


def test_with_no_edge_fitted_the_raster_methods_search_for_it_by_information() -> None:
    """The edge search (§2): no edge path, so Method 1's raster has nothing to follow; the
    task chooses the view by expected new information among the stations around the rover
    (here every move is allowed) instead of answering "nothing to do"."""
    cfg = dataclasses.replace(CFG, mission=dataclasses.replace(CFG.mission, method="1"))
    rig = TaskRig(cfg)
    results = rig.tap(NBV_RESULT)
    _request(rig, _planned_map(), motion_ok=lambda a, b: True)
    rig.run_until(lambda: len(results) > 0, 5000)
    (view,) = results.drain()
    assert view is not None and view.method == "search" and view.expected_new_cells > 0
    assert view.rover != (0.0, 0.0, 0.0) and view.rover[0] > 0.0  # toward the unknown ground
