"""The leg home retraces the way the Cliff-bot came when its map shows no way home: the winches go
back through the tether lengths it held on the way out, last first, to its start
(fsw.tasks.cliffbot_mission; docs/team.md, "The Cliff-bot's flight code")."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fsw.comm.team.team_can import WINCHES, WinchStatus
from fsw.core.team.cliffbot_nav import NavConfig
from fsw.core.team.climber_ground import ClimberConfig, ground_layers
from fsw.core.team.tether import TetherConfig, tether_state
from fsw.sections import CliffbotMissionConfig
from fsw.tasks.cliffbot.checkpoint import CheckpointError, restore, snapshot
from fsw.tasks.cliffbot_mission import CliffbotMission
from tests.fsw.tasks.test_cliffbot_mission_approach import GRID, START, FreshDevices, P, _drive

TARGET = np.array([2.5, -1.8])
ANCHORS = np.array([[1.0, 0.6, 0.3], [4.0, 0.6, 0.3]])


def _mission() -> CliffbotMission:
    return CliffbotMission(CliffbotMissionConfig(return_home=True), TetherConfig(), ClimberConfig(), NavConfig(),
                           ANCHORS, START, -np.pi / 2, TARGET[None, :])


def _band(z: np.ndarray) -> np.ndarray:
    """Rocks across the whole map between the target and the start (a look's false rocks)."""
    out = z.copy()
    _, y = GRID.centers()
    out[(y > -1.25) & (y < -1.05)] += 0.4
    return out


def _lengths(dev: FreshDevices) -> tuple[float, float]:
    return dev.winch[WINCHES[0]].paid_out_m, dev.winch[WINCHES[1]].paid_out_m


def _set(m: CliffbotMission, dev: FreshDevices, lengths: tuple[float, float], xy: np.ndarray) -> None:
    dev.winch = {w: WinchStatus(w, v, 50.0, True, frozenset(), 0) for w, v in zip(WINCHES, lengths, strict=True)}
    m.on_estimate(np.array([xy[0], xy[1], -np.pi / 2]), P)


def _out_to_the_target_and_rocks_behind(m: CliffbotMission, dev: FreshDevices) -> float:
    """Drive out to the target on flat ground, then, before the leg home, a map with a band of
    rocks across the way it came."""
    flat = np.zeros(GRID.shape)
    st0 = tether_state(flat, GRID, m.anchors, START, m.tcfg, m.ccfg.footprint_m)
    assert st0 is not None
    _set(m, dev, st0.lengths_m, START)
    m.set_map(flat, GRID)
    t = 0.0
    for _ in range(4000):
        t += 0.1
        if m.state == "DRIVE":
            t, _ = _drive(m, dev, t, ground_layers(m.z, GRID, m.ccfg, anchors=m.anchors).known)
            continue
        if m.legs and m.leg_i < len(m.legs) and m.legs[m.leg_i].target is None and m.state == "WAIT_FIX":
            break
        cmd = m.step(t, dev)
        if cmd.request_fix:
            m.on_no_fix(m.fix_seq, "busy")
    assert m.reached == [True], m.events
    m.set_map(_band(flat), GRID)
    return t


def test_with_no_way_home_on_its_map_it_retraces_the_lengths_it_came_by() -> None:
    m, dev = _mission(), FreshDevices()
    t = _out_to_the_target_and_rocks_behind(m, dev)
    start_lengths = m.trail[0][:2]
    came = [(a, b) for a, b, _, _ in m.trail]
    assert len(came) >= 3
    assert m.step(t + 0.1, dev).request_fix
    m.on_no_fix(m.fix_seq, "busy")
    assert m.state == "DRIVE" and "RETRACE" in [name for _, name, _ in m.events], m.events[-3:]
    leg = m.legs[m.leg_i]
    assert leg.target is None and leg.lengths == came[::-1]  # the lengths it held, last first
    driven = []
    while m.state == "DRIVE":
        k = m.wp_i
        _set(m, dev, leg.lengths[k], leg.waypoints[k])  # a perfect body: the winches at the set-point
        driven.append(_lengths(dev))
        t += 0.1
        m.step(t, dev)
        assert len(driven) < 500
    assert m.state == "DONE" and [name for _, name, _ in m.events][-2:] == ["HOME", "DONE"]
    assert driven[-1] == pytest.approx(start_lengths) and m.trail == []
    # without the trail (at its start, or never gone), no retrace: the leg home is refused as before
    m2, dev2 = _mission(), FreshDevices()
    _out_to_the_target_and_rocks_behind(m2, dev2)
    m2.trail.clear()
    assert m2.step(t + 0.1, dev2).request_fix
    m2.on_no_fix(m2.fix_seq, "busy")
    assert "RETRACE" not in [name for _, name, _ in m2.events] and m2.state in ("DONE", "SAFE")


def test_a_restart_mid_retrace_goes_back_from_where_it_is_and_a_bad_trail_is_refused() -> None:
    m, dev = _mission(), FreshDevices()
    t = _out_to_the_target_and_rocks_behind(m, dev)
    assert m.step(t + 0.1, dev).request_fix
    m.on_no_fix(m.fix_seq, "busy")
    leg = m.legs[m.leg_i]
    assert leg.lengths is not None
    for _ in range(2):  # two set-points reached, then the restart
        _set(m, dev, leg.lengths[m.wp_i], leg.waypoints[m.wp_i])
        t += 0.1
        m.step(t, dev)
    left = list(m.trail)
    st = json.loads(json.dumps(snapshot(m, t)))
    m2 = _mission()
    restore(m2, st, m.z, GRID)
    assert m2.trail == left and len(left) < len(leg.lengths)
    _set(m2, dev, _lengths(dev), m.est.xy)
    assert m2.state == "WAIT_FIX" and m2.step(t + 0.1, dev).request_fix
    m2.on_no_fix(m2.fix_seq, "busy")
    assert m2.legs[m2.leg_i].lengths == [(a, b) for a, b, _, _ in left][::-1]
    for bad in ([[1.0, 2.0, 3.0]], [[1.0, float("nan"), 0.0, 0.0]], [[-1.0, 2.0, 0.0, 0.0]], "x"):
        with pytest.raises(CheckpointError, match="trail"):
            restore(_mission(), {**st, "trail": bad}, m.z, GRID)


def test_a_leg_home_whose_lengths_keep_holding_it_elsewhere_retraces() -> None:
    """On the way home, the waypoints' lengths hold the body 0.3 m off the way, again and again
    (the map's ground is not the ground's there): the leg home is not given up with the body left
    on the face; it goes back the way it came."""
    m, dev = _mission(), FreshDevices()
    t = _out_to_the_target_and_rocks_behind(m, dev)
    m.set_map(np.zeros(GRID.shape), GRID)  # a way home on the map
    came = [(a, b) for a, b, _, _ in m.trail]
    assert m.step(t + 0.1, dev).request_fix
    m.on_no_fix(m.fix_seq, "busy")
    assert m.state == "DRIVE" and m.legs[m.leg_i].lengths is None  # planned home, not retraced
    for _ in range(20):
        if m.state != "DRIVE" or m.legs[m.leg_i].lengths is not None:
            break
        leg = m.legs[m.leg_i]
        wp = leg.waypoints[m.wp_i]
        st = tether_state(m.z, GRID, m.anchors, wp, m.tcfg, m.ccfg.footprint_m)
        assert st is not None
        _set(m, dev, st.lengths_m, wp + np.array([0.3, 0.0]))  # at the waypoint's lengths, 0.3 m off it
        t += 0.1
        m.step(t, dev)
    names = [name for _, name, _ in m.events]
    assert names.count("OFF_THE_WAY") >= 2 and "RETRACE" in names, names[-8:]
    leg = m.legs[m.leg_i]
    assert m.state == "DRIVE" and leg.target is None and leg.lengths is not None
    assert leg.lengths[-1] == pytest.approx(came[0])  # back to the lengths it left its start with
