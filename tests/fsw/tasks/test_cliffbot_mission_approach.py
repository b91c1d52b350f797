"""A target whose ground the Cliff-bot's map does not know yet is approached: the mission drives
to the known node nearest it, looks, and plans again; it never drives onto unknown ground
(fsw.tasks.cliffbot_mission, fsw.tasks.cliffbot.legs; docs/team.md, "Approach: making the
unknown known")."""

from __future__ import annotations

import dataclasses

import numpy as np

from fsw.comm.team.team_can import WINCHES, WinchStatus
from fsw.core.geometry import MapGrid, MapGridConfig
from fsw.core.team.cliffbot_nav import NavConfig
from fsw.core.team.climber_ground import ClimberConfig, ground_layers, standing_cells
from fsw.core.team.tether import TetherConfig, tether_state
from fsw.drivers.cliffbot_devices import CliffbotDevices
from fsw.sections import CliffbotMissionConfig, CliffbotSensingConfig
from fsw.tasks.cliffbot_mission import LOOK_APART_M, CliffbotMission

GRID = MapGrid.from_config(MapGridConfig(origin_x_m=0.0, origin_y_m=-3.5, cell_m=0.1, nx=50, ny=45))
TARGET = np.array([2.0, -2.6])
START = np.array([2.5, -0.5])
P = np.diag([1e-4, 1e-4, 1e-4])


class FreshDevices(CliffbotDevices):
    """Statuses that never go stale (the mission's device supervision is not under test here)."""

    def stale(self, now: float) -> list[str]:
        return []


def _ground() -> np.ndarray:
    return np.zeros(GRID.shape)


def _unknown_below(y_m: float) -> np.ndarray:
    """The ground with every cell below ``y_m`` unknown (the target's neighbourhood among them)."""
    z = _ground()
    _, y = GRID.centers()
    z[y < y_m] = np.nan
    return z


def _mission(looks: int = 3, tcfg: TetherConfig | None = None, start: np.ndarray = START) -> CliffbotMission:
    anchors = np.array([[1.0, 0.6, 0.3], [4.0, 0.6, 0.3]])
    return CliffbotMission(CliffbotMissionConfig(approach_looks=looks, return_home=False), tcfg or TetherConfig(),
                           ClimberConfig(), NavConfig(), anchors, start, -np.pi / 2,
                           TARGET[None, :], sensing=CliffbotSensingConfig(enabled=True))


def _names(m: CliffbotMission) -> list[str]:
    return [name for _, name, _ in m.events]


def _look(m: CliffbotMission, dev: CliffbotDevices, t: float, z: np.ndarray) -> float:
    """Answer the mission's next fix request with NO_FIX and its view request with map ``z``."""
    for _ in range(5):
        t += 0.1
        cmd = m.step(t, dev)
        if cmd.request_fix:
            m.on_no_fix(m.fix_seq, "busy")
        if cmd.sense:
            m.set_map(z, GRID)
            m.sensed(m.sense_seq)
            return t
    raise AssertionError(f"no view request: {m.state}, {m.events[-3:]}")


def _drive(m: CliffbotMission, dev: CliffbotDevices, t: float, known: np.ndarray) -> tuple[float, list[np.ndarray]]:
    """Drive the leg as a perfect body would (the winches at each waypoint's lengths, the estimate
    on it), checking that every waypoint stands on ground the map the mission held then knows."""
    places = []
    while m.state == "DRIVE":
        wp = m.legs[m.leg_i].waypoints[m.wp_i]
        assert known[GRID.cell_index(wp[:1], wp[1:])[:2]].all(), f"waypoint {wp} on unknown ground"
        st = tether_state(m.z, GRID, m.anchors, wp, m.tcfg, m.ccfg.footprint_m)
        assert st is not None
        dev.winch = {w: WinchStatus(w, length, 50.0, True, frozenset(), 0)
                     for w, length in zip(WINCHES, st.lengths_m, strict=True)}
        m.on_estimate(np.array([wp[0], wp[1], -np.pi / 2]), P)
        places.append(wp)
        t += 0.1
        m.step(t, dev)
        assert len(places) < 200
    return t, places


def _start(m: CliffbotMission, dev: CliffbotDevices, z: np.ndarray) -> float:
    m.on_estimate(np.array([*m.start, -np.pi / 2]), P)
    m.set_map(z, GRID)
    t = _look(m, dev, 0.0, z)  # the views before the plan
    m.step(t + 0.1, dev)  # PLAN
    return t + 0.1


def test_a_target_on_unknown_ground_is_approached_looked_at_and_reached() -> None:
    m, dev = _mission(), FreshDevices()
    z0 = _unknown_below(-1.9)
    t = _start(m, dev, z0)
    assert "APPROACH" in _names(m) and "TARGET_UNREACHABLE" not in _names(m) and m.state == "WAIT_FIX"
    t += 0.1
    assert m.step(t, dev).request_fix
    m.on_no_fix(m.fix_seq, "busy")  # the leg planned: toward the known node nearest the target
    leg = m.legs[0]
    assert m.state == "DRIVE" and leg.via is not None
    known = ground_layers(m.z, GRID, m.ccfg, anchors=m.anchors).known  # the whole footprint known
    # the approach node is the known ground nearest the target: no known node is nearer by a lattice spacing
    iy, ix = np.nonzero(known)
    cx, cy = GRID.x0 + (ix + 0.5) * GRID.cell, GRID.y0 + (iy + 0.5) * GRID.cell
    nearest = float(np.hypot(cx - TARGET[0], cy - TARGET[1]).min())
    assert float(np.hypot(*(leg.via - TARGET))) <= nearest + m.ccfg.node_m + GRID.cell
    via = leg.via.copy()
    t, places = _drive(m, dev, t, known)
    assert m.state == "WAIT_FIX" and m.look_now and leg.looks == 1 and "LOOK" in _names(m)
    assert np.array_equal(places[-1], via)  # it stopped at the approach node to look
    # the look shows the target's ground: the leg is planned again, to the target, and driven
    t = _look(m, dev, t, _ground())
    assert m.state == "DRIVE" and leg.via is None and m.reasons[0] == ""
    t, _ = _drive(m, dev, t, ground_layers(m.z, GRID, m.ccfg, anchors=m.anchors).known)
    assert m.reached == [True] and "TARGET_REACHED" in _names(m)


def test_a_look_that_shows_nothing_new_gives_the_target_up_with_its_looks() -> None:
    m, dev = _mission(), FreshDevices()
    z0 = _unknown_below(-1.9)
    t = _start(m, dev, z0)
    m.step(t + 0.1, dev)
    m.on_no_fix(m.fix_seq, "busy")
    known = ground_layers(m.z, GRID, m.ccfg, anchors=m.anchors).known
    t, _ = _drive(m, dev, t + 0.1, known)
    # the views add nothing: it edges up to what known ground is left nearer the target (each step
    # more than a lattice spacing), looks there, and gives the target up when nothing nearer is left
    while m.state != "DONE":
        t = _look(m, dev, t, z0)
        t, _ = _drive(m, dev, t, known)
    n = m.legs[0].looks
    assert 1 <= n <= m.cfg.approach_looks and _names(m).count("LOOK") == n
    assert m.reached == [False] and m.reasons[0] == f"unknown ground ({n} looks)"


def test_without_looks_or_on_known_ground_a_target_is_not_approached() -> None:
    m, dev = _mission(looks=0), FreshDevices()
    _start(m, dev, _unknown_below(-1.9))
    assert m.reasons[0] == "unknown ground" and "APPROACH" not in _names(m) and m.state == "DONE"
    short = dataclasses.replace(TetherConfig(), spool_m=3.0)  # the target's ground known, out of reach
    m = _mission(tcfg=short)
    _start(m, dev, _ground())
    assert m.reasons[0] == "out of tether reach" and "APPROACH" not in _names(m)


def test_with_nothing_nearer_it_looks_again_from_where_it_stands_only_once_its_pose_is_sharper() -> None:
    for sharper in (True, False):
        m, dev = _mission(), FreshDevices()
        wide = np.diag([0.1 ** 2, 0.1 ** 2, np.radians(10.0) ** 2])  # the start's, before a fix
        m.on_estimate(np.array([2.5, -0.5, -np.pi / 2]), wide)
        z0 = _unknown_below(-0.75)  # no known ground nearer the target than where it stands
        x, y = GRID.centers()
        z0[(np.abs(x - 2.5) > 0.45) & (y < -0.2)] = np.nan  # (nor ground round it to carry its plane onto)
        m.set_map(z0, GRID)
        t = _look(m, dev, 0.0, z0)  # its first look, with the start's covariance
        m.step(t + 0.1, dev)  # PLAN: the target approached
        assert m.state == "WAIT_FIX" and "APPROACH" in _names(m)
        assert m.step(t + 0.2, dev).request_fix
        m.on_estimate(np.array([2.5, -0.5, -np.pi / 2]), P if sharper else wide)  # (a fix fused, or none)
        m.on_no_fix(m.fix_seq, "busy")
        if sharper:
            assert m.state == "SENSE" and _names(m).count("LOOK") == 1 and m.looks == [1]
        else:
            # not from where it stands: from elsewhere along its known ground (EXPLORE, below)
            assert "LOOK" not in _names(m) and m.state == "DRIVE" and "EXPLORE" in _names(m)
            # a place its scan shows some of the unknown ground the next step needs that none of its looks showed
            assert max(m._look_rating(TARGET)(m.legs[0].via)) > 0 and not np.allclose(m.legs[0].via, START)


def test_it_edges_up_to_known_ground_a_short_step_nearer_the_target_before_it_looks() -> None:
    """Known ground that ends a decimetre or two nearer the target than the start (a lip a few
    decimetres ahead) is an approach node: the head over it sees what the start cannot."""
    m, dev = _mission(), FreshDevices()
    z0 = _unknown_below(-1.0)
    t = _start(m, dev, z0)
    assert m.step(t + 0.1, dev).request_fix
    m.on_no_fix(m.fix_seq, "busy")
    leg = m.legs[0]
    assert m.state == "DRIVE" and leg.via is not None, m.events[-2:]
    here = float(np.hypot(*(np.array([2.5, -0.5]) - TARGET)))
    gain = here - float(np.hypot(*(leg.via - TARGET)))
    assert m.ccfg.node_m < gain < m.ccfg.footprint_m  # a short step, all it has
    via = leg.via.copy()
    known = ground_layers(z0, GRID, m.ccfg, anchors=m.anchors).known
    _, places = _drive(m, dev, t + 0.2, known)  # never onto ground the map does not know
    assert m.state == "WAIT_FIX" and m.look_now and np.array_equal(places[-1], via)


def test_the_plane_carried_beyond_where_its_wheels_stand_is_no_ground_to_step_onto() -> None:
    """The camera's ground ends three decimetres ahead of the start, inside the disc the plane
    under the body is carried over: the first approach step, like any leg, neither ends on nor
    crosses a node whose footprint holds a cell of that plane beyond where it stands."""
    start = np.array([2.55, -0.45])  # a cell's centre: the plane is carried beyond the body's outline
    m, dev = _mission(start=start), FreshDevices()
    z0 = _unknown_below(-0.75)
    t = _start(m, dev, z0)
    half_len, half_wid = CliffbotSensingConfig().body_half_m[:2]
    contact = standing_cells(GRID, start, m.ccfg, m.anchors, (-np.pi / 2, half_len, half_wid))
    assert m.carried is not None and m.carried.any() and not (m.carried & contact).any()
    assert m.reasons[0] == "unknown ground" or not m.reasons[0]  # the start itself is usable ground
    assert np.isfinite(m.z[m.carried]).all() and not np.isfinite(z0[m.carried]).any()
    sensed = np.isfinite(z0) | contact  # the camera's ground and the wheels' own
    known = ground_layers(np.where(sensed, 0.0, np.nan), GRID, m.ccfg, anchors=m.anchors).known
    if m.state == "WAIT_FIX":
        assert m.step(t + 0.1, dev).request_fix
        m.on_no_fix(m.fix_seq, "busy")
    assert m.state in ("DRIVE", "DONE"), m.events[-3:]
    if m.state == "DRIVE":
        leg = m.legs[0]
        assert leg.via is None or known[GRID.cell_index(leg.via[:1], leg.via[1:])[:2]].all()
        _drive(m, dev, t + 0.2, known)  # every waypoint's whole footprint sensed
    # the planner's own layers say the same: no usable node on the carried plane
    g = ground_layers(m.z, GRID, m.ccfg, m.carried, m.anchors)
    assert not (g.known & ~known).any()


def test_the_ground_under_its_body_outline_is_where_it_stands_so_the_first_step_is_known() -> None:
    """No camera sees the ground under the body (the RECON-bot's map leaves it unknown): the ground
    under its outline is where it stands, so the first step is onto known ground (were its corners
    the plane carried on, every node next to the start would hold one in its footprint and the
    target would be given up)."""
    start = np.array([2.55, -0.45])  # a cell's centre
    m, dev = _mission(start=start), FreshDevices()
    z0 = _unknown_below(-1.9)
    x, y = GRID.centers()
    half_len, half_wid = CliffbotSensingConfig().body_half_m[:2]
    under = (np.abs(y - start[1]) <= half_len) & (np.abs(x - start[0]) <= half_wid)  # heading -90 deg: along is -y
    z0[under] = np.nan
    t = _start(m, dev, z0)
    assert m.step(t + 0.1, dev).request_fix
    m.on_no_fix(m.fix_seq, "busy")
    assert m.state == "DRIVE" and m.legs[0].via is not None, m.events[-2:]
    assert m.carried is not None and not (m.carried & under).any()
    sensed = np.isfinite(z0) | standing_cells(GRID, start, m.ccfg, m.anchors, (-np.pi / 2, half_len, half_wid))
    _drive(m, dev, t + 0.2, ground_layers(np.where(sensed, 0.0, np.nan), GRID, m.ccfg, anchors=m.anchors).known)


def test_the_look_budget_counts_looks_without_progress_so_a_long_approach_goes_on() -> None:
    """Each look shows the ground a little further down (as a head over a lip sees the face
    below it): every approach node is nearer the target than the last, so the approach goes on
    past ``approach_looks`` looks in all, and the target is reached; it never steps onto ground
    its map does not know."""
    m, dev = _mission(looks=1), FreshDevices()
    views = [_unknown_below(y) for y in (-1.2, -1.6, -2.0)] + [_ground()]
    t = _start(m, dev, _unknown_below(-0.9))
    assert m.step(t + 0.1, dev).request_fix
    m.on_no_fix(m.fix_seq, "busy")
    t += 0.2
    shown = _unknown_below(-0.9)
    for z in views:
        assert m.state == "DRIVE" and m.legs[0].via is not None, m.events[-2:]
        t, _ = _drive(m, dev, t, ground_layers(m.z, GRID, m.ccfg, m.carried, m.anchors).known)
        assert m.state == "WAIT_FIX" and m.look_now, m.events[-2:]
        shown = z
        t = _look(m, dev, t, shown)
    assert m.state == "DRIVE" and m.legs[0].via is None and m.reasons[0] == "", m.events[-2:]
    t, _ = _drive(m, dev, t, ground_layers(m.z, GRID, m.ccfg, m.carried, m.anchors).known)
    assert m.reached == [True] and m.looks == [len(views)] > [m.cfg.approach_looks]


def test_the_ground_it_stood_on_stays_known_so_the_leg_home_reaches_its_start() -> None:
    """No camera ever sees the ground under the start (the RECON-bot's map leaves it unknown,
    and so does every later map): the body measured it by standing there, so once it has moved
    to the approach node and looked, the leg home is still planned onto it and driven (were it
    forgotten, the start's footprint would be unknown ground and the leg home refused)."""
    start = np.array([2.55, -0.45])
    anchors = np.array([[1.0, 0.6, 0.3], [4.0, 0.6, 0.3]])
    m = CliffbotMission(CliffbotMissionConfig(approach_looks=1, return_home=True), TetherConfig(), ClimberConfig(),
                        NavConfig(), anchors, start, -np.pi / 2, TARGET[None, :],
                        sensing=CliffbotSensingConfig(enabled=True))
    dev = FreshDevices()
    z0 = _unknown_below(-1.9)
    x, y = GRID.centers()
    half_len, half_wid = CliffbotSensingConfig().body_half_m[:2]
    under = standing_cells(GRID, start, m.ccfg, m.anchors, (-np.pi / 2, half_len, half_wid))
    z0[under] = np.nan
    t = _start(m, dev, z0)
    assert m.step(t + 0.1, dev).request_fix
    m.on_no_fix(m.fix_seq, "busy")
    assert m.state == "DRIVE" and m.legs[0].via is not None, m.events[-2:]
    t, _ = _drive(m, dev, t + 0.2, ground_layers(m.z, GRID, m.ccfg, m.carried, m.anchors).known)
    assert m.state == "WAIT_FIX" and float(np.hypot(*(m.est.xy - start))) > 1.0
    t = _look(m, dev, t, z0)  # the look shows nothing new; the map there still does not know the start
    assert np.isfinite(m.z[under]).all() and not (m.carried & under).any()
    assert m.legs[m.leg_i].target is None and m.state == "WAIT_FIX", m.events[-3:]  # the leg home
    assert m.step(t + 0.1, dev).request_fix
    m.on_no_fix(m.fix_seq, "busy")
    assert m.state == "DRIVE", m.events[-3:]  # planned onto the ground it stood on
    t, places = _drive(m, dev, t, ground_layers(m.z, GRID, m.ccfg, m.carried, m.anchors).known)
    assert "HOME" in _names(m) and m.state == "DONE"
    assert float(np.hypot(*(places[-1] - start))) <= m.ccfg.node_m


def test_a_checkpoint_keeps_the_ground_it_stood_on_and_a_bad_one_is_refused() -> None:
    """A Cliff-bot restarted from its checkpoint still knows the ground under the poses it held:
    the next map gets it back as before the restart."""
    import pytest

    from fsw.tasks.cliffbot.checkpoint import CheckpointError, restore, snapshot

    z0 = _unknown_below(-1.9)
    m = _mission()
    under = standing_cells(GRID, START, m.ccfg, m.anchors)
    z0[under] = np.nan
    m.on_estimate(np.array([*START, -np.pi / 2]), P)
    m.set_map(z0, GRID)
    m.on_estimate(np.array([2.5, -1.5, -np.pi / 2]), P)
    back = _mission()
    restore(back, snapshot(m, 1.0), m.z, GRID)
    back.on_estimate(np.array([2.5, -1.5, -np.pi / 2]), P)
    back.set_map(z0, GRID)
    m.set_map(z0, GRID)
    assert np.isfinite(back.z[under]).all() and np.array_equal(back.z, m.z, equal_nan=True)
    for bad, why in (([[z0.size, 0.0, 1]], "outside the map"), ([[3, float("nan"), 1]], "non-finite"),
                     ("nope", "stood")):
        with pytest.raises(CheckpointError, match=why):
            restore(_mission(), snapshot(m, 1.0) | {"stood": bad}, m.z, GRID)


def test_with_nothing_nearer_it_looks_again_from_elsewhere_along_the_known_ground() -> None:
    """Its known ground ends level with where it stands (no node nearer the target by a lattice
    spacing) and it looked from there: it drives along that edge, no farther from the target than
    where it stands by more than ``LOOK_APART_M``, to the known node whose scan would show the
    most of the unknown ground the next step needs that no look it took showed (event
    ``EXPLORE``), looks there, and
    reaches the target when that look shows its ground; when the looks show nothing new, it
    gives the target up with its looks once no such place is left. Never onto unknown ground."""
    for shows in (True, False):
        m, dev = _mission(), FreshDevices()
        z0 = _unknown_below(-0.75)
        t = _start(m, dev, z0)
        assert m.step(t + 0.1, dev).request_fix
        m.on_no_fix(m.fix_seq, "busy")
        t += 0.2
        for _ in range(10):  # the approach's short steps, each looking at nothing new
            if "EXPLORE" in _names(m) or m.state != "DRIVE":
                break
            t, _ = _drive(m, dev, t, ground_layers(m.z, GRID, m.ccfg, m.carried, m.anchors).known)
            t = _look(m, dev, t, z0)
        leg = m.legs[0]
        assert m.state == "DRIVE" and leg.via is not None and "EXPLORE" in _names(m), m.events[-3:]
        looked, here = list(m.looked_from), m.est.xy
        assert max(m._look_rating(TARGET)(leg.via)) > 0 and not any(np.allclose(leg.via, p) for p in looked)
        assert float(np.hypot(*(leg.via - TARGET))) <= float(np.hypot(*(here - TARGET))) + LOOK_APART_M
        t, _ = _drive(m, dev, t, ground_layers(m.z, GRID, m.ccfg, m.carried, m.anchors).known)
        assert m.state == "WAIT_FIX" and m.look_now, m.events[-2:]
        t = _look(m, dev, t, _ground() if shows else z0)
        if shows:
            assert m.state == "DRIVE" and m.reasons[0] == "", m.events[-2:]
            _drive(m, dev, t, ground_layers(m.z, GRID, m.ccfg, m.carried, m.anchors).known)
            assert m.reached == [True]
            continue
        for _ in range(20):
            if m.state == "DONE":
                break
            t, _ = _drive(m, dev, t, ground_layers(m.z, GRID, m.ccfg, m.carried, m.anchors).known)
            t = _look(m, dev, t, z0)
        n = m.legs[0].looks
        assert m.state == "DONE" and m.reached == [False] and m.reasons[0] == f"unknown ground ({n} looks)"
