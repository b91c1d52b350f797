"""The tension margins and the off-the-way test the place's uncertainty requires
(fsw.core.team.face_planner.tension_margins, fsw.tasks.cliffbot.legs; docs/team.md, "The planner")."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from fsw.core.geometry import MapGrid
from fsw.core.team.cliffbot_nav import NavConfig
from fsw.core.team.face_planner import (
    ClimberConfig,
    Margins,
    margin_reason,
    place_covariance,
    tension_margins,
    way_reason,
)
from fsw.core.team.tether import TetherConfig, anchor_points, tether_state
from fsw.sections import CliffbotMissionConfig
from fsw.tasks.cliffbot.legs import Route
from fsw.tasks.cliffbot_mission import CliffbotMission

SLOPE = math.radians(70.0)
FACE = np.array([0.2, -0.5])  # on the face, 0.5 m below the lip


def _cliff() -> tuple[np.ndarray, MapGrid, np.ndarray]:
    grid = MapGrid(-3.0, -2.0, 0.03, 200, 150)
    _, y = grid.centers()
    z = np.where(y > 0, 0.0, np.maximum(math.tan(SLOPE) * y, -2.5)).astype(np.float64)
    return z, grid, anchor_points(z, grid, np.array([[-1.5, 1.5], [1.5, 1.5]]), TetherConfig())


def test_margins_grow_with_the_lengths_error_and_vanish_without_it() -> None:
    z, grid, anchors = _cliff()
    t, c = TetherConfig(), ClimberConfig()
    one = tension_margins(z, grid, anchors, FACE, t, c, Margins(length_sigma_m=0.01))
    two = tension_margins(z, grid, anchors, FACE, t, c, Margins(length_sigma_m=0.02))
    assert one is not None and two is not None and min(one) > 0.1
    np.testing.assert_allclose(two, 2 * np.asarray(one), rtol=1e-9)
    assert tension_margins(z, grid, anchors, FACE, t, c, Margins(length_sigma_m=0.0)) == (0.0, 0.0)
    cov, _, st = place_covariance(z, grid, anchors, FACE, t, c, 0.02) or (None, None, None)
    assert cov is not None and st is not None and np.all(np.linalg.eigvalsh(cov) > 0)
    # off the map's known ground there is no margin to work out
    unknown = z.copy()
    unknown[:, :] = np.nan
    assert tension_margins(unknown, grid, anchors, FACE, t, c, Margins(length_sigma_m=0.02)) is None


def test_a_node_inside_the_hard_limits_but_within_its_margin_is_not_usable() -> None:
    z, grid, anchors = _cliff()
    c = ClimberConfig()
    st = tether_state(z, grid, anchors, FACE, TetherConfig(), c.footprint_m)
    assert st is not None and st.statics.ok and st.statics.tilt_deg > c.free_slope_deg
    low = min(st.statics.tensions_n)
    t = dataclasses.replace(TetherConfig(), t_min_n=low - 0.5)  # held, 0.5 N above slack
    assert margin_reason(z, grid, anchors, FACE, t, c, Margins(length_sigma_m=0.0)) == ""
    assert margin_reason(z, grid, anchors, FACE, t, c, Margins(length_sigma_m=0.02)) == "slack"
    roomy = dataclasses.replace(TetherConfig(), t_min_n=max(0.0, low - 200.0))
    assert margin_reason(z, grid, anchors, FACE, roomy, c, Margins(length_sigma_m=0.02)) == ""


def test_off_the_way_is_an_offset_beyond_the_estimate_and_the_place_uncertainty() -> None:
    z, grid, anchors = _cliff()
    m = CliffbotMission(CliffbotMissionConfig(), TetherConfig(), ClimberConfig(), NavConfig(), anchors,
                        np.array([0.0, 0.6]), -math.pi / 2, FACE[None, :])
    m.set_map(z, grid, 0.03)
    got = place_covariance(z, grid, anchors, FACE, m.tcfg, m.ccfg, m.route().length_sigma())
    assert got is not None
    w, v = np.linalg.eigh(got[0])
    tight = v[:, 0]  # the direction the lengths pin the place best
    sd = math.sqrt(w[0] + 1e-6)
    P = np.diag([1e-6, 1e-6, 1e-4])  # an estimate that claims a millimetre
    for k, expect in ((0.5, False), (4.0, True)):
        off = m.ccfg.node_m + k * m.cfg.margin_sigmas * sd
        m.on_estimate(np.array([*(FACE + off * tight), 0.0]), P)
        assert m.route().elsewhere(m.est.xy, m.est.P[:2, :2], FACE)[0] is expect
    m.on_estimate(np.array([*(FACE + 0.5 * m.ccfg.node_m * tight), 0.0]), P)
    assert m.route().elsewhere(m.est.xy, m.est.P[:2, :2], FACE)[0] is False  # within a lattice spacing


def test_a_checkpoint_keeps_the_map_bound_the_margins_rest_on() -> None:
    from fsw.tasks.cliffbot.checkpoint import restore, snapshot

    z, grid, anchors = _cliff()

    def mission() -> CliffbotMission:
        return CliffbotMission(CliffbotMissionConfig(), TetherConfig(), ClimberConfig(), NavConfig(), anchors,
                               np.array([0.0, 0.6]), -math.pi / 2, FACE[None, :])

    m = mission()
    m.set_map(z, grid, 0.03)
    back = mission()
    restore(back, snapshot(m, 1.0), z, grid)
    bare = math.sqrt(CliffbotMissionConfig().length_tol_m ** 2 / 3.0)  # the winches' tolerance alone
    assert back.error_bound_m == 0.03 and back.route().length_sigma() == m.route().length_sigma() > bare


def test_a_checkpoint_keeps_the_cells_no_sensor_measured() -> None:
    """The plane carried under the body stays unknown ground for the planner after a restart."""
    from fsw.tasks.cliffbot.checkpoint import CheckpointError, restore, snapshot

    z, grid, anchors = _cliff()
    hole = z.copy()
    x, y = grid.centers()
    hole[(np.hypot(x, y - 0.6) > 0.36) & (np.hypot(x, y - 0.6) < 0.45)] = np.nan  # a ring round the start, unseen

    def mission() -> CliffbotMission:
        return CliffbotMission(CliffbotMissionConfig(), TetherConfig(), ClimberConfig(), NavConfig(), anchors,
                               np.array([0.0, 0.6]), -math.pi / 2, FACE[None, :])

    m = mission()
    m.set_map(hole, grid, 0.03)
    assert m.carried is not None and m.carried.any()
    back = mission()
    restore(back, snapshot(m, 1.0), m.z, grid)
    assert back.carried is not None and np.array_equal(back.carried, m.carried)
    bad = snapshot(m, 1.0) | {"carried": [z.size]}
    with pytest.raises(CheckpointError, match="outside the map"):
        restore(mission(), bad, m.z, grid)


def _route(z: np.ndarray, grid: MapGrid, anchors: np.ndarray, tcfg: TetherConfig) -> Route:
    return Route(z, grid, 0.03, CliffbotMissionConfig(), tcfg, ClimberConfig(), anchors)


def test_a_way_keeps_each_tethers_own_margin() -> None:
    """Every place of a way keeps, per tether, the larger of its ends' margins for THAT tether:
    tether A, the slack one here, keeps its own margin, not tether B's larger one."""
    z, grid, anchors = _cliff()
    t, c = TetherConfig(), ClimberConfig()
    a, b = np.array([1.2, -0.8]), np.array([1.2, -0.86])  # tether A at about 11 N, B at 95 N
    r = _route(z, grid, anchors, t)
    ends = [tension_margins(z, grid, anchors, p, t, c, r.margins()) for p in (a, b)]
    assert ends[0] is not None and ends[1] is not None
    own = max(ends[0][0], ends[1][0])
    other = max(ends[0][1], ends[1][1])
    assert other > own + 0.1  # B's margin is the larger here

    def passes(t_min: float) -> bool:  # the way with no margins, at a lower tension limit
        return way_reason(z, grid, anchors, a, b, dataclasses.replace(t, t_min_n=t_min), c, r.ground) == ""

    lo, hi = 0.0, 50.0  # the least tension along the way, to 0.01 N
    assert passes(lo) and not passes(hi)
    while hi - lo > 0.01:
        lo, hi = ((lo + hi) / 2, hi) if passes((lo + hi) / 2) else (lo, (lo + hi) / 2)
    # the limit where tether A's own margin holds along the way and B's would not
    limit = lo - 0.5 * (own + other)
    held = _route(z, grid, anchors, dataclasses.replace(t, t_min_n=limit))
    assert held.passable(a, b)
    assert not _route(z, grid, anchors, dataclasses.replace(t, t_min_n=lo - own + 0.05)).passable(a, b)


def test_a_legs_nodes_are_judged_on_the_ground_its_ways_are() -> None:
    """A target whose tethers touch the rocks the ways keep clear of (the map's rocks grown by a
    lattice spacing) is the end of no way: the leg refuses it for its tethers at once instead of
    cutting the ways into it one by one until it gives up with ``no safe path``."""
    z, grid, anchors = _cliff()
    t, c = TetherConfig(), ClimberConfig()
    r = _route(z, grid, anchors, t)
    st = tether_state(z, grid, anchors, FACE, t, c.footprint_m)
    assert st is not None
    cy, cx, inside = grid.cell_index(st.paths[1].contacts[:, 0], st.paths[1].contacts[:, 1])
    assert inside.all()
    rock = r.ground.rock.copy()
    rock[cy, cx] = True  # tether B's contacts on the lip, as near a rock as the ways allow
    r.ground = dataclasses.replace(r.ground, rock=rock)
    plan, wps = r.plan(np.array([0.0, 0.6]), FACE)
    assert plan.reasons == ("tether over a rock",) and wps == []
    assert not r.ways  # no way was judged to find it out
