"""The Cliff-bot is held where the lengths' errors may put it (fsw.core.team.held_tension,
fsw.core.team.face_planner, fsw.tasks.cliffbot.legs; docs/team.md, "The planner"),
and the off-the-way test the place's uncertainty requires."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from fsw.core.geometry import MapGrid
from fsw.core.team.cliffbot_nav import NavConfig
from fsw.core.team.climber_ground import ClimberConfig, ground_layers
from fsw.core.team.face_planner import place_covariance, way_reason
from fsw.core.team.held_tension import (
    LengthErrors,
    held_reason,
    leaned_reason,
    length_covariance,
    length_offsets,
    statics_reason,
)
from fsw.core.team.tether import TetherConfig, anchor_points, attach_point, tether_state
from fsw.core.team.tether_settle import settle, settle_many
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


ERRORS = LengthErrors(0.02, 0.03)  # the winches' tolerance, the reduced map's bound


def test_the_maps_error_is_shared_by_both_tethers_and_the_winches_are_their_own() -> None:
    """The map's height error under the body moves both lengths together (along ``s_i = -u_iz``);
    the winches' errors are independent."""
    z, grid, anchors = _cliff()
    st = tether_state(z, grid, anchors, FACE, TetherConfig(), ClimberConfig().footprint_m)
    assert st is not None
    s = np.array([-st.paths[0].pull[2], -st.paths[1].pull[2]])
    assert s.min() < -0.5  # on the face both tethers pull up: the body raised shortens both
    shared = length_covariance(st, LengthErrors(0.0, 0.03))
    np.testing.assert_allclose(shared, 0.03 ** 2 / 3 * np.outer(s, s), rtol=1e-12)
    assert abs(np.linalg.det(shared)) < 1e-15  # one error, both tethers: rank one
    own = length_covariance(st, LengthErrors(0.02, 0.0))
    np.testing.assert_allclose(own, 0.02 ** 2 / 3 * np.eye(2), rtol=1e-12)
    np.testing.assert_allclose(length_covariance(st, ERRORS), shared + own, rtol=1e-12)


def test_the_offsets_bound_every_linear_function_of_the_error_at_its_sigmas() -> None:
    """Each offset lies on the polygon circumscribing the z-sigma ellipse, so the largest value
    of any linear function over them is at least its z-sigma value (what a linear margin
    would have required), and the offsets scale with z."""
    cov = np.array([[4e-4, 3e-4], [3e-4, 5e-4]])
    off = length_offsets(cov, 2.326)
    rng = np.random.default_rng(0)
    for g in rng.standard_normal((200, 2)):
        assert float(np.max(off @ g)) >= 2.326 * math.sqrt(g @ cov @ g) - 1e-12
    r = np.einsum("ki,ij,kj->k", off, np.linalg.inv(cov), off)
    np.testing.assert_allclose(r, (2.326 / math.cos(math.pi / len(off))) ** 2, rtol=1e-6)
    np.testing.assert_allclose(length_offsets(cov, 1.0) * 2.326, off, rtol=1e-12)


def test_many_places_settle_where_one_at_a_time_does() -> None:
    z, grid, anchors = _cliff()
    t = TetherConfig()
    st = tether_state(z, grid, anchors, FACE, t, ClimberConfig().footprint_m)
    assert st is not None
    lengths = np.asarray(st.lengths_m) + length_offsets(length_covariance(st, ERRORS), 2.326)
    lengths = np.vstack([lengths, [st.lengths_m[0] + 3.0, st.lengths_m[1] - 3.0]])  # not both taut
    guesses = np.repeat(FACE[None, :], len(lengths), axis=0)
    got_many = settle_many(z, grid, anchors, lengths, guesses, t)
    assert not got_many.unsettled.any()
    many = got_many.places
    for (l1, l2), got in zip(lengths, many, strict=True):
        one = settle(z, grid, anchors, (float(l1), float(l2)), FACE, t)
        assert (got is None) == (one is None)
        if got is not None and one is not None:
            # within settle's own acceptance (its search on a kink accepts a quarter cell more)
            assert np.max(np.abs(np.asarray(got[1].lengths_m) - (l1, l2))) < 1e-2 + 0.25 * grid.cell
            assert float(np.hypot(*(got[0] - one[0]))) < 0.01
    assert sum(g is not None for g in many) == len(lengths) - 1


def test_a_node_inside_the_hard_limits_but_not_held_at_its_lengths_errors_is_not_usable() -> None:
    """The statics re-solved where the body settles at each length error: a node 0.5 N above
    slack is refused for its errors and usable without them; far from the limits it holds."""
    z, grid, anchors = _cliff()
    c = ClimberConfig()
    st = tether_state(z, grid, anchors, FACE, TetherConfig(), c.footprint_m)
    assert st is not None and st.statics.ok and st.statics.tilt_deg > c.free_slope_deg
    low = min(st.statics.tensions_n)
    t = dataclasses.replace(TetherConfig(), t_min_n=low - 0.5)  # held, 0.5 N above slack
    assert held_reason(z, grid, anchors, FACE, st, t, c.free_slope_deg, LengthErrors()) == ""
    assert held_reason(z, grid, anchors, FACE, st, t, c.free_slope_deg, ERRORS) == "slack"
    high = dataclasses.replace(TetherConfig(), t_max_n=max(st.statics.tensions_n) + 0.5)
    assert held_reason(z, grid, anchors, FACE, st, high, c.free_slope_deg, ERRORS) == "over-tension"
    roomy = dataclasses.replace(TetherConfig(), t_min_n=max(0.0, low - 200.0))
    assert held_reason(z, grid, anchors, FACE, st, roomy, c.free_slope_deg, ERRORS) == ""


def test_the_check_judges_the_statics_where_the_body_settles_not_a_linear_margin() -> None:
    """The tension where the body settles at each offset is what is judged: the tightest limit
    the check accepts is the least tension over the offsets' settled places (to the solver's
    millimetre), which a linear margin only approximates."""
    z, grid, anchors = _cliff()
    c, t = ClimberConfig(), TetherConfig()
    st = tether_state(z, grid, anchors, FACE, t, c.footprint_m)
    assert st is not None
    off = length_offsets(length_covariance(st, ERRORS), ERRORS.z)
    got = settle_many(z, grid, anchors, np.asarray(st.lengths_m) + off, np.repeat(FACE[None, :], len(off), 0),
                      t).places
    least = min(min(g[1].statics.tensions_n) for g in got if g is not None)
    assert least < min(st.statics.tensions_n) - 0.1  # the errors move the tension
    ok = dataclasses.replace(t, t_min_n=least - 0.05)
    tight = dataclasses.replace(t, t_min_n=least + 0.05)
    assert held_reason(z, grid, anchors, FACE, st, ok, c.free_slope_deg, ERRORS) == ""
    assert held_reason(z, grid, anchors, FACE, st, tight, c.free_slope_deg, ERRORS) == "slack"


def test_a_place_on_ground_the_wheels_hold_needs_no_tension() -> None:
    z, grid, anchors = _cliff()
    c = ClimberConfig()
    flat = np.array([0.0, 0.6])
    st = tether_state(z, grid, anchors, flat, TetherConfig(), c.footprint_m)
    assert st is not None and st.statics.tilt_deg <= c.free_slope_deg
    strict = dataclasses.replace(TetherConfig(), t_min_n=1e3)
    assert statics_reason(st, strict, c.free_slope_deg) == ""
    assert statics_reason(None, strict, c.free_slope_deg) == "slack"


def test_off_the_way_is_an_offset_beyond_the_estimate_and_the_place_uncertainty() -> None:
    z, grid, anchors = _cliff()
    m = CliffbotMission(CliffbotMissionConfig(), TetherConfig(), ClimberConfig(), NavConfig(), anchors,
                        np.array([0.0, 0.6]), -math.pi / 2, FACE[None, :])
    m.set_map(z, grid, 0.03)
    got = place_covariance(z, grid, anchors, FACE, m.tcfg, m.ccfg, m.route().errors())
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
    assert back.error_bound_m == 0.03 and back.route().errors() == m.route().errors()
    assert back.route().errors().map_error_m == 0.03


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


def _route(z: np.ndarray, grid: MapGrid, anchors: np.ndarray, tcfg: TetherConfig, lean_deg: float = 0.0) -> Route:
    """The mission's route on ``z``; the plane's lean (``plane_error_deg``) off unless asked."""
    return Route(z, grid, 0.03, CliffbotMissionConfig(plane_error_deg=lean_deg), tcfg, ClimberConfig(), anchors)


def test_a_way_is_judged_where_the_body_settles_at_its_lengths_errors() -> None:
    """Along a way the body is settled at the lengths off by each error too (moving from one
    end's offsets to the other's) and the statics judged there: a tension limit the way passes
    without the errors (its least tension 0.05 N above it) it fails with them; the least
    tension over the offsets' places is lower than the way's own."""
    z, grid, anchors = _cliff()
    t, c = TetherConfig(), ClimberConfig()
    a, b = np.array([1.2, -0.8]), np.array([1.2, -0.86])  # tether A at about 11 N, B at 95 N
    r = _route(z, grid, anchors, t)

    def least(errors: LengthErrors | None) -> float:  # the highest T_min the way passes, to 0.01 N
        def passes(t_min: float) -> bool:
            return way_reason(z, grid, anchors, a, b, dataclasses.replace(t, t_min_n=t_min), c, r.ground,
                              errors=errors) == ""

        lo, hi = 0.0, 50.0
        assert passes(lo) and not passes(hi)
        while hi - lo > 0.01:
            lo, hi = ((lo + hi) / 2, hi) if passes((lo + hi) / 2) else (lo, (lo + hi) / 2)
        return lo

    bare, held = least(None), least(r.errors())
    assert held < bare - 0.1
    assert not _route(z, grid, anchors, dataclasses.replace(t, t_min_n=bare - 0.05)).passable(a, b)
    assert _route(z, grid, anchors, dataclasses.replace(t, t_min_n=held - 0.05)).passable(a, b)


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


def test_the_screen_gives_the_verdicts_the_settled_statics_give(monkeypatch: pytest.MonkeyPatch) -> None:
    """A place whose tensions keep SCREEN times their linear change inside the limits is held
    without settling: over places of the face and tension limits from roomy to tight, the
    verdicts equal those of settling at every offset, and some places were settled."""
    import fsw.core.team.held_tension as ht

    z, grid, anchors = _cliff()
    c = ClimberConfig()
    rng = np.random.default_rng(3)
    cases = []
    for xy in rng.uniform([-1.5, -1.6], [1.5, -0.2], size=(12, 2)):
        st = tether_state(z, grid, anchors, xy, TetherConfig(), c.footprint_m)
        if st is None or not st.statics.ok:
            continue
        low = min(st.statics.tensions_n)
        for room in (0.3, 1.0, 3.0, 30.0):
            cases.append((xy, st, dataclasses.replace(TetherConfig(), t_min_n=max(0.0, low - room))))
    screened = [held_reason(z, grid, anchors, xy, st, t, c.free_slope_deg, ERRORS) for xy, st, t in cases]
    monkeypatch.setattr(ht, "SCREEN", 1e12)  # every place settled at every offset
    settled = [held_reason(z, grid, anchors, xy, st, t, c.free_slope_deg, ERRORS) for xy, st, t in cases]
    assert len(cases) >= 20 and screened == settled
    assert "slack" in settled and "" in settled


def test_a_place_whose_settling_ends_undecided_is_refused_as_not_held_at_a_bounded_cost(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """At the foot of the face one length error leaves the body neither settled within its
    acceptance nor shown slack: the node is refused as ``tension not held`` (not called slack,
    never accepted), and settling its eight errors costs at most the batch's bound of tether
    states per error (no unbounded per-place search after it)."""
    import fsw.core.team.held_tension as ht
    import fsw.core.team.tether as tether_mod
    import fsw.core.team.tether_settle as settle_mod

    z, grid, anchors = _cliff()
    t = TetherConfig()
    xy = np.array([-0.60, -1.16])
    st = tether_state(z, grid, anchors, xy, t, ClimberConfig().footprint_m)
    assert st is not None and st.statics.ok
    off = length_offsets(length_covariance(st, ERRORS), ERRORS.z)
    got = settle_many(z, grid, anchors, np.asarray(st.lengths_m) + off, np.repeat(xy[None, :], len(off), 0), t)
    assert got.unsettled.any() and not got.unsettled.all()
    assert all(p is None for p, u in zip(got.places, got.unsettled, strict=True) if u)

    evaluated = [0]
    real = tether_mod.tether_states

    def counted(*args: object, **kw: object) -> list[object]:
        evaluated[0] += len(np.asarray(args[3]).reshape(-1, 2))
        return real(*args, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(tether_mod, "tether_states", counted)
    monkeypatch.setattr(settle_mod, "tether_states", counted)
    monkeypatch.setattr(ht, "tether_states", counted)
    roomy = dataclasses.replace(t, t_min_n=min(st.statics.tensions_n) - 30.0)  # no settled error is slack
    assert held_reason(z, grid, anchors, xy, st, roomy, 0.0, ERRORS) == ht.NOT_HELD
    steps = settle_mod.SETTLE_MANY_ITERATIONS
    per_error = (5 * (settle_mod.FULL_STEPS + 1) + 5 * (steps + 1) + settle_mod._BACKTRACK * steps
                 + 16 * len(settle_mod.SEARCH_RADII))
    assert 4 < evaluated[0] <= 4 + len(off) * per_error


def test_a_legs_plans_judge_each_node_once_and_the_kept_verdicts_are_the_same(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A leg planned again (its edges cut, its approach) reads the node verdicts its map already
    has: planning with the kept verdicts gives the same plan as planning afresh, and judges no
    node a second time."""
    import fsw.core.team.face_planner as fp

    z, grid, anchors = _cliff()
    t, c = TetherConfig(), ClimberConfig()
    start, goal = np.array([0.0, 0.6]), np.array([0.6, -0.9])
    judged: list[tuple[int, int]] = []
    real = fp._verdict

    def counted(*args: object) -> str:
        judged.append((int(args[-2]), int(args[-1])))  # type: ignore[call-overload]
        return real(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(fp, "_verdict", counted)
    r = _route(z, grid, anchors, t)
    fresh = fp.plan_targets(z, grid, anchors, start, goal[None, :], t, c, r.margins(), start_usable=True,
                            ground=r.ground)
    n_fresh = len(judged)
    kept: dict[int, str] = {}
    first = fp.plan_targets(z, grid, anchors, start, goal[None, :], t, c, r.margins(), start_usable=True,
                            ground=r.ground, verdicts=kept)
    judged.clear()
    again = fp.plan_targets(z, grid, anchors, start, goal[None, :], t, c, r.margins(), start_usable=True,
                            ground=r.ground, verdicts=kept)
    assert n_fresh > 10 and len(kept) == n_fresh and judged == []
    for p in (first, again):
        assert p.reasons == fresh.reasons and p.lengths_m == fresh.lengths_m
        np.testing.assert_array_equal(p.paths[0], fresh.paths[0])
    judged.clear()
    plan, _ = r.plan(start, goal)
    r.plan(start, goal)
    assert plan.reasons == fresh.reasons and len(judged) == len(set(judged)) == len(r.nodes)



def test_a_way_whose_tether_touches_a_rock_between_two_of_its_steps_is_refused() -> None:
    """The way is judged at steps of tether; a tether that sweeps over a rock of a cell touches
    it between two steps and not at either (seed 27 of ``experiment team``: tether A touched a
    one-cell rock 0.7 of the way between two waypoints, between two steps 3 cm of tether apart,
    and the bench counted it). Where a step's ends pass over a rock or next to one, the step is
    judged again at sub-steps and the way is refused."""
    grid = MapGrid(-1.5, -1.5, 0.03, 100, 100)
    z = np.zeros((100, 100))
    t, c = TetherConfig(), ClimberConfig()
    anchors = anchor_points(z, grid, np.array([[-1.2, 1.3], [1.2, 1.3]]), t)
    p = anchors[0, :2] + 0.3 * (np.array([-0.3, -0.6]) - anchors[0, :2])
    iy, ix, _ = grid.cell_index(p[:1], p[1:])
    r, k = int(iy[0]), int(ix[0])
    centre = np.array([grid.x0 + (k + 0.5) * grid.cell, grid.y0 + (r + 0.5) * grid.cell])
    d = centre - anchors[0, :2]
    mid = anchors[0, :2] + d * (-0.6 - anchors[0, 1]) / d[1]  # tether A right over the rock with the body here
    a, b = mid - np.array([0.075, 0.0]), mid + np.array([0.225, 0.0])  # flat; mid a quarter of the way
    bot = attach_point(z, grid, mid, t, c.footprint_m)
    assert bot is not None
    f = float(np.hypot(*(centre - anchors[0, :2])) / np.hypot(*(bot[:2] - anchors[0, :2])))
    z[r, k] = anchors[0, 2] + f * (bot[2] - anchors[0, 2]) + 0.02  # one cell, 2 cm above the tether's line
    g = ground_layers(z, grid, c)
    assert g.rock[r, k]
    step = 0.2  # two steps: at half the way and at its end, the rock swept between the start and the first
    for xy in (a, a + 0.5 * (b - a), b):
        st = tether_state(z, grid, anchors, xy, t, c.footprint_m)
        assert st is not None and not len(st.paths[0].contacts)  # the tether misses the rock at every step
    st = tether_state(z, grid, anchors, mid, t, c.footprint_m)
    assert st is not None and len(st.paths[0].contacts)  # and touches it between them
    assert way_reason(z, grid, anchors, a, b, t, c, g, step_m=step) == "tether over a rock"
    assert way_reason(z, grid, anchors, a, b, t, c, g, step_m=step, errors=ERRORS) == "tether over a rock"


def test_a_tether_that_carries_little_on_the_maps_plane_must_hold_at_its_lean() -> None:
    """The tensions split the weight by the fall line of the plane the map puts under the body,
    and that plane leans from the ground's where the face is steep. A way whose least tension
    keeps its limit on the map's plane but not with the plane leaned by ``plane_error_deg`` is
    refused (the lean's reason), and the refusal grows with the lean; a lean of 0 is the old
    check, and the truth's judge (no map, no lean) is unchanged by it."""
    z, grid, anchors = _cliff()
    t = TetherConfig()
    a, b = np.array([1.2, -0.8]), np.array([1.2, -0.86])  # tether A at about 11 N, B at 95 N
    assert _route(z, grid, anchors, t).passable(a, b)
    assert not _route(z, grid, anchors, t, lean_deg=8.0).passable(a, b)
    st = tether_state(z, grid, anchors, a, t, ClimberConfig().footprint_m)
    assert st is not None and st.statics.ok
    assert leaned_reason(st, t, ClimberConfig().free_slope_deg, 0.0) == ""
    assert leaned_reason(st, t, ClimberConfig().free_slope_deg, 8.0) == "slack"
    # The lean that refuses it: the least tension over the leans falls as the lean grows.
    refused = [leaned_reason(st, t, ClimberConfig().free_slope_deg, d) != "" for d in (0.5, 2.0, 4.0, 8.0, 16.0)]
    assert refused == sorted(refused) and refused[-1]
    # A place both tethers pull hard: held at the same lean.
    mid = tether_state(z, grid, anchors, FACE, t, ClimberConfig().footprint_m)
    assert mid is not None and min(mid.statics.tensions_n) > 30.0
    assert leaned_reason(mid, t, ClimberConfig().free_slope_deg, 8.0) == ""
