"""A start boxed in by a close edge is left for a reachable station (docs/algorithm.md §3, issue 30
item 1): the rule's parts at unit level, and one search on a tiny map (no mission)."""

from __future__ import annotations

import dataclasses

import numpy as np
from shapely.geometry import box

from fsw.core.edge.known_ground import KnownGround
from fsw.core.geometry import CameraConfig, MapGrid, MastConfig
from fsw.core.map.elevation_map import ElevationMap
from fsw.core.planning.info_planners import InformationPlanner, boxed_start, leave_or_stay
from fsw.core.planning.nbv import NbvConfig
from fsw.core.planning.planners import PlannerState
from fsw.core.planning.view_candidates import CandidateView

CAM, MAST = CameraConfig(), MastConfig()
TINY = NbvConfig(max_travel_m=0.5, pan_step_deg=60.0, tilts_deg=(-45.0,), coarse_cell_m=0.0)


def _ok(a: tuple, b: tuple) -> bool:
    return True


def _state(edge_y: float, at_start: bool = True) -> PlannerState:
    emap = ElevationMap(MapGrid(-1.0, -2.0, 0.1, 20, 30))
    path = np.array([[-1.0, 0.0], [1.0, 0.0]])
    edge = np.array([[-1.0, edge_y], [0.0, edge_y], [1.0, edge_y]])
    return PlannerState(emap, (0.0, 0.0, 0.0), (0.0, 0.0, 0.5), path, _ok, edge_xy=edge, at_start=at_start)


def _view(utility: float, x: float) -> CandidateView:
    return CandidateView((x, 0.0, 0.0), (0.0, -0.8, 0.5), utility=utility, method="5")


def test_boxed_start_needs_the_start_and_a_close_fitted_edge() -> None:
    cfg = NbvConfig(leave_start_edge_m=1.2)
    assert boxed_start(_state(-0.9), cfg)
    assert not boxed_start(_state(-1.5), cfg)  # the edge farther than the bound
    assert not boxed_start(_state(-0.9, at_start=False), cfg)  # the rover has moved
    assert not boxed_start(_state(-0.9), dataclasses.replace(cfg, leave_start_edge_m=0.0))  # rule off
    assert not boxed_start(dataclasses.replace(_state(-0.9), edge_xy=None), cfg)  # no edge fitted
    nan_edge = dataclasses.replace(_state(-0.9), edge_xy=np.array([[np.nan, np.nan], [0.0, -2.0]]))
    assert not boxed_start(nan_edge, cfg)  # a non-finite point is no edge point


def test_a_boxed_start_leaves_unless_the_start_rates_clearly_better() -> None:
    stay = _view(1000.0, 0.0)
    assert leave_or_stay(stay, _view(800.0, 0.25), 0.25).rover[0] == 0.25  # within 25 %: the move
    kept = leave_or_stay(stay, _view(700.0, 0.25), 0.25)  # more than 25 % below: stays, says why
    assert kept.rover == stay.rover and "boxed-in start" in kept.note and "700" in kept.note
    assert leave_or_stay(stay, _view(999.0, 0.25), 0.0).rover == stay.rover  # tol 0: the plain rating
    assert leave_or_stay(_view(-10.0, 0.0), _view(-12.0, 0.25), 0.25).rover[0] == 0.25  # negative utilities


def test_the_start_is_left_only_while_the_rover_has_not_moved() -> None:
    kg = KnownGround(0.0)
    kg.stood_on(box(-0.3, -0.4, 0.3, 0.4))
    kg.stood_on(box(-0.29, -0.4, 0.31, 0.4))  # a few mm of pose noise: the same place
    assert kg.stood_only_near(0.0, 0.0, 0.125)
    kg.stood_on(box(0.2, -0.4, 0.8, 0.4))  # a move of 0.5 m
    assert not kg.stood_only_near(0.5, 0.0, 0.125)


def _patch_state() -> PlannerState:
    """At the start, 0.75 m from the edge, all ground mapped but a patch beyond the edge in front
    of the rover: the view from where it stands rates best, a station 0.25 m away nearly as well."""
    state = _state(-0.75)
    xs, ys = state.map.grid.centers()
    known = ~((np.abs(xs) < 0.35) & (ys < -0.8) & (ys > -1.8))
    state.map.n[known], state.map.var[known], state.map.z[known] = 2, 1e-4, 0.0
    return state


def test_search_from_a_boxed_start_leaves_or_says_why() -> None:
    off = InformationPlanner("5", dataclasses.replace(TINY, leave_start_edge_m=0.0), CAM, MAST, use_interest=True)
    on = InformationPlanner("5", TINY, CAM, MAST, use_interest=True)
    base, got = off.next_view(_patch_state()), on.next_view(_patch_state())
    assert base is not None and got is not None
    assert base.rover == (0.0, 0.0, 0.0)  # the plain rating keeps the view from the start
    assert float(np.hypot(got.rover[0], got.rover[1])) >= TINY.station_spacing_m / 2  # the rule leaves
    assert got.utility >= (1 - TINY.leave_start_tol) * base.utility and not got.note
    moved = dataclasses.replace(_patch_state(), at_start=False)  # not the start: the plain rating
    assert on.next_view(moved) == off.next_view(moved)
    costly = InformationPlanner("5", dataclasses.replace(TINY, w_motion=10.0), CAM, MAST, use_interest=True)
    kept = costly.next_view(_patch_state())  # every move rates far below the start's view: it stays, says why
    assert kept is not None and kept.rover == (0.0, 0.0, 0.0) and "boxed-in start" in kept.note
