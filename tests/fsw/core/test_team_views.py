"""Team views (fsw.core.planning.team_views, docs/algorithm.md §8): the sequential-greedy choice,
the corridor, the discount of Eq 3 and the Cliff-bot's tether motion, on small synthetic maps."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from fsw.core.geometry import CameraConfig, MapGrid
from fsw.core.map.elevation_map import ElevationMap
from fsw.core.planning.nbv import NbvConfig, cell_values, h2, predicted_visibility
from fsw.core.planning.team_views import (
    AgentInterest,
    AgentViews,
    TeamViewConfig,
    ViewCentre,
    choose_team_views,
    cliffbot_centres,
    corridor_lattice,
    corridor_mask,
    corridor_places,
    corridor_weights,
)
from fsw.core.team.tether import TetherConfig, anchor_points, tether_states
from fsw.settings import load_settings

GRID = MapGrid(0.0, 0.0, 0.1, 60, 60)
CAM = CameraConfig(width_px=160, height_px=120, hfov_deg=50.0, baseline_m=0.15, min_range_m=0.3, max_range_m=5.0)
NBV = NbvConfig()


def _flat_map() -> ElevationMap:
    emap = ElevationMap(GRID, load_settings(check_calibration=False).fusion)
    emap.z[:] = 0.0
    emap.var[:] = 0.01**2
    emap.n[:] = 0  # flat ground, nothing measured: the prior knows its height
    return emap


def _centre(x: float, y: float) -> ViewCentre:
    yaws = np.radians(np.arange(0.0, 360.0, 30.0))
    tilts = np.radians([-30.0, -60.0])
    return ViewCentre((x, y, 1.5), yaws, tilts, np.zeros(yaws.size * tilts.size),
                      np.zeros(yaws.size * tilts.size), (x, y))


def _overlap(emap: ElevationMap, views: list) -> float:
    a, b = (predicted_visibility(emap, v.pose(), CAM, NBV.visibility) > 0.5 for v in views)
    return float((a & b).sum()) / max(1, int((a | b).sum()))


def test_the_second_agent_does_not_look_where_the_first_will() -> None:
    """Two agents at the same place: rated alone each takes the same view; chosen one after the
    other, the second turns away from the cells the first will see."""
    emap = _flat_map()
    agents = [AgentViews("recon", CAM, (_centre(3.0, 3.0),)), AgentViews("cliffbot", CAM, (_centre(3.0, 3.0),))]
    views, planned = choose_team_views(emap, agents, NBV)
    assert [v.order for v in views] == [0, 1] and {v.agent for v in views} == {"recon", "cliffbot"}
    alone = [choose_team_views(emap, [a], NBV)[0][0] for a in agents]
    assert (alone[0].yaw, alone[0].tilt) == (alone[1].yaw, alone[1].tilt)  # the same best view
    assert _overlap(emap, alone) > 0.9
    assert _overlap(emap, views) < 0.15
    assert views[1].discounted_cells < 0.15 * views[1].expected_new_cells + 1.0
    assert planned.max() > 0.5 and f"after {views[0].agent}'s view" in views[1].why


def test_a_cell_an_earlier_view_sees_adds_only_what_this_view_adds() -> None:
    """The second view's bits are its marginal gain on the cycle's one measurement of the cell
    (§8.2): nothing where the earlier view surely sees it, the rest of h2 where it may."""
    pv = np.array([1.0, 1.0, 1.0])
    n = np.array([0, 0, 0], np.int32)
    bits0, new0 = cell_values(pv, n, 2, None)
    bits1, new1 = cell_values(pv, n, 2, None, planned=np.array([0.0, 1.0, 0.5]))
    assert bits1[0] == bits0[0] and new1[0] == new0[0] == 1.0
    assert bits1[1] == 0.0 and new1[1] == 0.0  # the earlier view surely sees it: nothing left
    assert math.isclose(bits1[2], 1.0 - float(h2(np.array([0.25]))[0])) and new1[2] == 0.5


def test_two_views_of_one_cell_are_worth_the_same_in_either_order_and_less_than_two_cells() -> None:
    """The cycle's bits of a cell are a set function of its views (submodular): the same total in
    either order of choice, and two views of one cell worth less than one view of each of two."""
    for a, b in ((0.9, 0.3), (0.6, 0.6), (0.2, 0.7)):
        for n in (0, 1):
            nn = np.array([n], np.int32)
            first_a = cell_values(np.array([a]), nn, 2, None)[0] + cell_values(np.array([b]), nn, 2, None,
                                                                               planned=np.array([a]))[0]
            first_b = cell_values(np.array([b]), nn, 2, None)[0] + cell_values(np.array([a]), nn, 2, None,
                                                                               planned=np.array([b]))[0]
            assert math.isclose(float(first_a[0]), float(first_b[0]), rel_tol=1e-12)
            apart = cell_values(np.array([a, b]), np.array([n, n], np.int32), 2, None)[0].sum()
            assert float(first_a[0]) < float(apart)


def test_the_corridor_is_the_path_grown_by_its_half_width() -> None:
    path = np.array([[1.0, 1.0], [4.0, 1.0], [4.0, 5.0]])
    mask = corridor_mask(GRID, path, 0.5)
    x, y = GRID.centers()
    d = np.minimum(np.where((x >= 1.0) & (x <= 4.0), np.abs(y - 1.0), np.hypot(x - np.clip(x, 1.0, 4.0), y - 1.0)),
                   np.where((y >= 1.0) & (y <= 5.0), np.abs(x - 4.0), np.hypot(x - 4.0, y - np.clip(y, 1.0, 5.0))))
    inner, outer = d <= 0.5 - GRID.cell, d > 0.5 + GRID.cell  # the path is drawn on cells: one cell of slack
    assert mask[inner].all() and not mask[outer].any()
    w = corridor_weights(mask, TeamViewConfig(corridor_weight=4.0))
    assert np.all(w[mask] == 4.0) and np.all(w[~mask] == 1.0)


def test_the_cliffbots_views_cost_tether_motion() -> None:
    """On a plateau and a 60 deg face, places farther down the path pay out more tether: their
    views cost more, and where it stands costs only the head's turn."""
    x, y = GRID.centers()
    z = np.where(y > 4.0, 0.0, -(4.0 - y) * math.tan(math.radians(60.0)))
    tcfg = TetherConfig()
    anchors = anchor_points(z, GRID, np.array([[2.0, 5.5], [4.0, 5.5]]), tcfg)
    path = np.column_stack([np.full(20, 3.0), np.linspace(4.6, 2.7, 20)])
    cfg = TeamViewConfig(station_spacing_m=0.5, max_travel_m=2.0)
    cs = cliffbot_centres(z, GRID, anchors, path, path[0], (0.0, 0.0), tcfg, cfg)
    assert len(cs) >= 3
    least = [float(c.motion.min()) for c in cs]
    assert least[0] == 0.0 and all(b > a for a, b in zip(least, least[1:], strict=False))
    assert all(c.place[2] > 0 and c.place[3] > 0 for c in cs)  # both tether lengths
    assert len(cliffbot_centres(z, GRID, anchors, path, path[0], (0.0, 0.0), tcfg, cfg, stay=False)) == len(cs) - 1
    # both winches run at once, paced to arrive together: the move takes the larger change of the
    # two lengths over the winch rate (a_tether = 1 / rate^2), not their root sum of squares
    dl = np.array([np.abs(np.subtract(c.place[2:], cs[0].place[2:])) for c in cs])
    assert np.allclose(least, np.sqrt(cfg.a_tether) * dl.max(axis=1))
    assert np.all(dl.min(axis=1)[1:] > 0.0)  # both lengths change: the sum of squares would cost more


def test_each_view_carries_the_visibility_it_was_rated_with() -> None:
    """The chosen views' P_V (what their misses are recorded against, §3.4) make ``planned``, the
    probability that some view sees each cell: each the view's own prediction on the map, in [0, 1]."""
    emap = _flat_map()
    agents = [AgentViews("recon", CAM, (_centre(2.0, 3.0),)), AgentViews("cliffbot", CAM, (_centre(4.0, 3.0),))]
    views, planned = choose_team_views(emap, agents, NBV)
    pvs = [v.p_visible for v in views]
    assert all(p is not None and p.shape == GRID.shape and p.min() >= 0.0 and p.max() <= 1.0 for p in pvs)
    assert np.allclose(1.0 - np.prod([1.0 - p for p in pvs if p is not None], axis=0), planned)
    for v, p in zip(views, pvs, strict=True):
        assert np.allclose(p, predicted_visibility(emap, v.pose(), CAM, NBV.visibility))


def test_corridor_places_lie_on_the_path_either_way_within_reach() -> None:
    """Places every spacing along an out-and-back path, either way from where the Cliff-bot
    stands, none farther than max_travel, each once."""
    path = np.column_stack([np.full(41, 3.0), np.linspace(1.0, 5.0, 41)])
    route = np.vstack([path, path[::-1]])
    now = np.array([3.0, 3.0])
    p = corridor_places(route, now, 0.5, 1.2)
    assert np.allclose(p[:, 0], 3.0)
    assert np.all(np.linalg.norm(p - now, axis=1) <= 1.2 + 1e-9)
    assert p[:, 1].min() < 2.5 and p[:, 1].max() > 3.5  # behind and ahead of it
    assert len(np.unique(np.round(p, 3), axis=0)) == len(p) == 5  # 2.0 ... 4.0, the way back adds none
    assert corridor_places(np.zeros((0, 2)), now, 0.5, 1.2).shape == (0, 2)


def test_corridor_lattice_fills_the_corridor_off_the_path_within_reach() -> None:
    """Places across the corridor: lattice nodes through where the Cliff-bot stands, within the
    corridor's half width of the path and more than half a spacing off it, within max_travel."""
    path = np.column_stack([np.full(41, 3.0), np.linspace(1.0, 5.0, 41)])
    now = np.array([3.0, 3.0])
    p = corridor_lattice(path, now, 0.5, 1.2, 1.0)
    off = np.abs(p[:, 0] - 3.0)
    assert len(p) > 0 and np.all((off > 0.25) & (off <= 1.0 + 1e-9))
    assert np.all(np.linalg.norm(p - now, axis=1) <= 1.2 + 1e-9)
    assert np.allclose((p - now) / 0.5, np.round((p - now) / 0.5))  # on the lattice through now
    assert {round(float(v), 3) for v in p[:, 0]} == {2.0, 2.5, 3.5, 4.0}  # both sides, to the full half width
    assert corridor_lattice(path, now, 0.5, 1.2, 0.2).shape == (0, 2)  # a corridor no wider than the path's places


def _corridor_face() -> tuple[np.ndarray, np.ndarray, TetherConfig, np.ndarray, np.ndarray, TeamViewConfig]:
    """A 60 deg face below y = 4 m, two anchors above it, a path down it at x = 3 m, a 1 m corridor:
    the cells' x, the heights, the tether config, the anchors, the path and the team view config."""
    x, y = GRID.centers()
    z = np.where(y > 4.0, 0.0, -(4.0 - y) * math.tan(math.radians(60.0)))
    tcfg = TetherConfig()
    anchors = anchor_points(z, GRID, np.array([[2.0, 5.5], [4.0, 5.5]]), tcfg)
    path = np.column_stack([np.full(20, 3.0), np.linspace(4.6, 2.7, 20)])
    return x, z, tcfg, anchors, path, TeamViewConfig(station_spacing_m=0.5, max_travel_m=2.0, corridor_half_m=1.0)


def test_the_cliffbots_places_across_its_corridor_are_on_known_ground_only() -> None:
    """On a 60 deg face the Cliff-bot's candidates include places beside its path inside the
    corridor, but only where the map knows the ground."""
    x, z, tcfg, anchors, path, cfg = _corridor_face()
    known = x < 3.0  # the map knows the ground west of the path only
    on = cliffbot_centres(z, GRID, anchors, path, path[0], (0.0, 0.0), tcfg, cfg, both_ways=True,
                          known=known, free_slope_deg=90.0)
    px = np.array([c.place[0] for c in on])
    assert np.any(px < 2.75) and not np.any(px > 3.25)  # beside the path, on the known side only
    narrow = cliffbot_centres(z, GRID, anchors, path, path[0], (0.0, 0.0), tcfg,
                              dataclasses.replace(cfg, corridor_half_m=0.0), both_ways=True, known=known)
    assert np.allclose([c.place[0] for c in narrow], 3.0)


def test_an_agent_pays_only_for_the_motion_beyond_the_earlier_choices() -> None:
    """The agents move at once, so a cycle lasts as long as its slowest move: the first agent's
    view costs its whole motion, the next agent's only what its move takes beyond that."""
    emap = _flat_map()
    focus = np.full(GRID.shape, 4.0)  # the recon's cells weigh 4 times theirs: it chooses first
    k = 24
    first = ViewCentre((2.0, 3.0, 1.5), np.radians(np.arange(0.0, 360.0, 30.0)), np.radians([-30.0, -60.0]),
                       np.full(k, 4.0), np.zeros(k), (2.0, 3.0))
    near = dataclasses.replace(first, xyz=(5.0, 3.0, 1.5), motion=np.full(k, 2.0), place=(5.0, 3.0))
    far = dataclasses.replace(near, motion=np.full(k, 7.0))
    for second, extra in ((near, 0.0), (far, 3.0)):
        agents = [AgentViews("recon", CAM, (first,), weight=focus), AgentViews("cliffbot", CAM, (second,))]
        views, _ = choose_team_views(emap, agents, NBV)
        assert [v.agent for v in views] == ["recon", "cliffbot"]
        assert math.isclose(views[0].utility, views[0].info_bits - NBV.w_motion * 4.0, rel_tol=1e-9)
        assert math.isclose(views[1].utility, views[1].info_bits - NBV.w_motion * extra, rel_tol=1e-9)


def test_the_corridor_weight_leaves_the_interest_inside_h2() -> None:
    """On a corridor cell the weight multiplies the bits and the decayed interest stays in
    h2(IF P_V / 2) (§3.4): a corridor cell is worth ``corridor_weight`` times the same cell off
    the corridor at every interest, so a miss lowers it the same way on and off the corridor."""
    mask = np.array([True, False])
    w = corridor_weights(mask, TeamViewConfig(corridor_weight=4.0))
    pv, n = np.array([0.9, 0.9]), np.zeros(2, np.int32)
    full = cell_values(pv, n, 2, np.ones(2), weight=w)[0]
    for i in (0.9, 0.6, 0.3):
        bits = cell_values(pv, n, 2, np.full(2, i), weight=w)[0]
        assert math.isclose(bits[0], 4.0 * bits[1], rel_tol=1e-12)
        assert math.isclose(bits[0] / full[0], bits[1] / full[1], rel_tol=1e-12)  # h2(i P_V / 2) / h2(P_V / 2)
        assert bits[0] < full[0]


def test_an_agents_misses_decay_only_its_own_interest() -> None:
    """A RECON-bot view expected to see cells it missed (its prior wrong there) lowers the
    RECON-bot's interest of them, not the Cliff-bot's: the Cliff-bot's best view of those cells
    keeps its bits while the RECON-bot's same view loses them (§8.2)."""
    emap = _flat_map()
    ai = AgentInterest(GRID.shape, beta=2.0)
    pv = np.zeros(GRID.shape)
    pv[:, 10:] = 0.9
    hit = np.zeros(GRID.shape, bool)
    hit[:, 10:15] = True  # a few cells got points
    assert ai.record("recon", pv, hit) == 60 * 45
    assert np.all(ai.of("cliffbot") == 1.0)
    assert math.isclose(float(ai.of("recon")[30, 30]), math.exp(-1.8)) and ai.of("recon")[30, 12] == 1.0
    c = _centre(3.0, 3.0)
    bits = {}
    for name in ("recon", "cliffbot"):
        views, _ = choose_team_views(emap, [AgentViews(name, CAM, (c,), ai.of(name))], NBV)
        bits[name] = views[0].info_bits
    fresh, _ = choose_team_views(emap, [AgentViews("cliffbot", CAM, (c,))], NBV)
    assert math.isclose(bits["cliffbot"], fresh[0].info_bits, rel_tol=1e-12)
    assert bits["recon"] < 0.9 * bits["cliffbot"]
    for bad in (np.full(GRID.shape, np.nan), np.full(GRID.shape, 1.5), np.zeros((3, 3))):
        with pytest.raises(ValueError, match="p_visible"):
            ai.record("cliffbot", bad, np.zeros(GRID.shape, bool))
    assert np.all(ai.of("cliffbot") == 1.0)


def test_the_cliffbots_places_across_its_corridor_are_where_the_tethers_hold_it() -> None:
    """Off its path, a place on the face is a candidate only where both tethers hold the Cliff-bot
    (the statics hold); on ground no steeper than free_slope_deg it stands on its wheels anyway."""
    x, z, tcfg, anchors, path, cfg = _corridor_face()
    cs = cliffbot_centres(z, GRID, anchors, path, path[0], (0.0, 0.0), tcfg, cfg, both_ways=True, free_slope_deg=25.0)
    off = np.array([c.place[:2] for c in cs if abs(c.place[0] - 3.0) > 1e-6])
    states = tether_states(z, GRID, anchors, off, tcfg)
    assert all(st is not None and (st.statics.ok or st.statics.tilt_deg <= 25.0) for st in states)
    lattice = corridor_lattice(path, path[0], 0.5, 2.0, 1.0)
    slack = [p for p, st in zip(lattice, tether_states(z, GRID, anchors, lattice, tcfg), strict=True)
             if st is not None and not st.statics.ok and st.statics.tilt_deg > 25.0]
    assert slack and not any(np.allclose(p, q) for p in slack for q in off)  # slack places on the face left out
    assert any(st is not None and st.statics.tilt_deg > 25.0 for st in states)  # held places on the face kept


def test_an_agent_with_a_scan_takes_its_views_from_one_place_each_where_the_others_are_not() -> None:
    """``AgentViews.views``: the Cliff-bot's head scan per cycle. Its first view from any of its
    centres, the rest from that centre at no motion, each chosen in the sequential greedy: every
    view turns away from what the views before it will see."""
    emap = _flat_map()
    k = 24
    here = ViewCentre((2.0, 3.0, 1.5), np.radians(np.arange(0.0, 360.0, 30.0)), np.radians([-30.0, -60.0]),
                      np.full(k, 1.0), np.zeros(k), (2.0, 3.0))
    there = dataclasses.replace(here, xyz=(4.0, 3.0, 1.5), place=(4.0, 3.0), motion=np.full(k, 3.0))
    n = 4
    agents = [AgentViews("recon", CAM, (_centre(3.0, 1.5),)), AgentViews("cliffbot", CAM, (here, there), views=n)]
    views, planned = choose_team_views(emap, agents, NBV)
    scan = [v for v in views if v.agent == "cliffbot"]
    assert len(views) == n + 1 and len(scan) == n and [v.order for v in views] == list(range(n + 1))
    assert len({v.place for v in scan}) == 1  # one place: the first view's
    assert all(v.motion == 0.0 for v in scan[1:])  # the rest of the scan pays no tether motion
    assert len({(v.yaw, v.tilt) for v in scan}) == n  # each view looks elsewhere
    seen = [predicted_visibility(emap, v.pose(), CAM, NBV.visibility) > 0.5 for v in views]
    for i in range(1, len(seen)):  # no view looks mostly where the views before it will
        before = np.logical_or.reduce(seen[:i])
        assert float((seen[i] & before).sum()) < 0.5 * max(1, int(seen[i].sum()))
    assert np.allclose(planned, 1.0 - np.prod([1.0 - np.clip(v.p_visible, 0.0, 1.0) for v in views], axis=0))
    one = choose_team_views(emap, [dataclasses.replace(agents[1], views=1)], NBV)[0]
    assert len(one) == 1  # the default: one view per agent
    emap.n[:] = 1  # every cell mapped: after its first view no pointing is expected to map a new cell
    done = choose_team_views(emap, agents, NBV)[0]
    assert [v.agent for v in done].count("cliffbot") == 1  # the scan ends there
