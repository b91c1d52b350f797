"""The tension guard: the winches' measured tensions, not only the map's statics, stop a way. A
tension that nears its limit while the Cliff-bot drives on steep ground stops it; it backs off to
where it last stood, refuses the place and plans the leg round it (fsw.tasks.cliffbot_mission;
docs/team.md, "The Cliff-bot's flight code")."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fsw.comm.team.team_can import WINCHES, Attitude, WinchStatus
from fsw.core.team.cliffbot_nav import NavConfig
from fsw.core.team.climber_ground import ClimberConfig
from fsw.core.team.tether import TetherConfig, tether_state
from fsw.sections import CliffbotMissionConfig
from fsw.tasks.cliffbot.checkpoint import CheckpointError, restore, snapshot
from fsw.tasks.cliffbot_mission import MAX_GUARDS, CliffbotMission
from tests.fsw.tasks.test_cliffbot_mission_approach import GRID, START, FreshDevices, P

TARGET = np.array([2.5, -2.0])
ANCHORS = np.array([[1.0, 0.6, 0.3], [4.0, 0.6, 0.3]])
FLAT = np.zeros(GRID.shape)
OK_N, NEAR_N = 50.0, TetherConfig().t_min_n + 1.0  # a healthy tension; one within the guard of T_min


def _mission(guard_n: float = 5.0) -> CliffbotMission:
    cfg = CliffbotMissionConfig(return_home=False, tension_guard_n=guard_n)
    return CliffbotMission(cfg, TetherConfig(), ClimberConfig(), NavConfig(), ANCHORS, START, -np.pi / 2,
                           TARGET[None, :])


def _stand(m: CliffbotMission, dev: FreshDevices, xy: np.ndarray, tension_b: float = OK_N) -> None:
    """A perfect body at ``xy``: the winches at its lengths on the map, the estimate on it."""
    st = tether_state(FLAT, GRID, m.anchors, xy, m.tcfg, m.ccfg.footprint_m)
    assert st is not None
    dev.winch = {w: WinchStatus(w, length, t, True, frozenset(), 0)
                 for w, length, t in zip(WINCHES, st.lengths_m, (OK_N, tension_b), strict=True)}
    m.on_estimate(np.array([xy[0], xy[1], -np.pi / 2]), P)


def _on_the_leg(m: CliffbotMission, dev: FreshDevices) -> float:
    """The map, a plan, and the first leg under way (two waypoints reached)."""
    _stand(m, dev, START)
    m.set_map(FLAT, GRID)
    t = 0.0
    while m.state != "DRIVE":
        t += 0.1
        if m.step(t, dev).request_fix:
            m.on_no_fix(m.fix_seq, "busy")
        assert t < 5.0, m.events
    for _ in range(2):
        _stand(m, dev, m.legs[0].waypoints[m.wp_i])
        t += 0.1
        m.step(t, dev)
    assert m.state == "DRIVE" and m.wp_i == 2 and len(m.trail) >= 2
    return t


def _names(m: CliffbotMission) -> list[str]:
    return [name for _, name, _ in m.events]


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    ab = b - a
    t = 0.0 if float(ab @ ab) == 0.0 else min(1.0, max(0.0, float((p - a) @ ab) / float(ab @ ab)))
    return float(np.hypot(*(a + t * ab - p)))


def test_a_tension_near_its_limit_stops_the_way_backs_off_and_the_leg_goes_round_the_place() -> None:
    m, dev = _mission(), FreshDevices()
    t = _on_the_leg(m, dev)
    leg = m.legs[0]
    # half way to the next waypoint, tether B's load cell reads 1 N over T_min (the map said it holds)
    here = 0.5 * (leg.waypoints[1] + leg.waypoints[2])
    _stand(m, dev, here, tension_b=NEAR_N)
    stood = [tuple(x) for x in m.trail]
    t += 0.1
    cmd = m.step(t, dev)
    assert _names(m)[-1] == "TENSION_GUARD" and cmd.rates_mps == (0.0, 0.0)
    assert f"tensions {OK_N:.1f} / {NEAR_N:.1f} N" in m.events[-1][2]  # what the load cells measured
    assert len(m.refused) == 1 and m.refused[0][1] == "slack" and np.allclose(m.refused[0][0], here)
    # it backs off to the last place it stood at, by the lengths it held there
    assert leg.back_to == len(stood) - 1 and leg.lengths == [stood[-1][:2]]
    m.set_map(FLAT, GRID)  # a newer map while it backs off: the back-off ends first (its end plans the leg)
    t += 0.1
    cmd = m.step(t, dev)
    assert leg.back_to == len(stood) - 1 and leg.lengths == [stood[-1][:2]]
    back = np.sign(np.asarray(stood[-1][:2]) - np.array([w.paid_out_m for w in dev.winch.values()]))
    assert np.array_equal(np.sign(cmd.rates_mps), back)  # the winches drive toward those lengths
    near = {w: s._replace(paid_out_m=stood[-1][k] + 0.01) for k, (w, s) in enumerate(dev.winch.items())}
    dev.winch = near  # 1 cm short of the place (within length_tol_m): not back yet
    t += 0.1
    assert m.step(t, dev).rates_mps != (0.0, 0.0) and leg.back_to is not None
    _stand(m, dev, np.array(stood[-1][2:]))  # back there: the leg is planned again, round the place
    t += 0.1
    m.step(t, dev)
    assert m.state == "DRIVE" and leg.back_to is None and leg.lengths is None and m.trail == [
        tuple(x) for x in stood]
    way = [np.array(stood[-1][2:]), *leg.waypoints]
    clear = min(_segment_distance(here, a, b) for a, b in zip(way[:-1], way[1:], strict=True))
    assert clear > m.cfg.guard_radius_m  # no way between its waypoints passes the refused place
    while m.state == "DRIVE":  # the way round holds: it reaches the target
        _stand(m, dev, leg.waypoints[m.wp_i])
        t += 0.1
        m.step(t, dev)
    assert m.reached == [True] and m.reasons == [""], m.events[-3:]


def test_the_guard_watches_the_lower_limit_on_steep_ground_only_and_the_upper_everywhere() -> None:
    for guard_n, attitude, tension_b, trips in (
            (5.0, Attitude(0.0, 0.0, -90.0, 0), NEAR_N, False),  # level: the wheels hold it, a slack tether is no fault
            (5.0, Attitude(0.0, 60.0, -90.0, 0), NEAR_N, True),  # on a 60 deg face: the tethers hold it
            (5.0, Attitude(0.0, 0.0, -90.0, 0), TetherConfig().t_max_n - 1.0, True),  # over-tension anywhere
            (0.0, Attitude(0.0, 60.0, -90.0, 0), NEAR_N, False)):  # the guard off
        m, dev = _mission(guard_n), FreshDevices()
        t = _on_the_leg(m, dev)
        dev.attitude = attitude
        _stand(m, dev, 0.5 * (m.legs[0].waypoints[1] + m.legs[0].waypoints[2]), tension_b=tension_b)
        m.step(t + 0.1, dev)
        assert ("TENSION_GUARD" in _names(m)) == trips, (guard_n, attitude, tension_b, m.events[-2:])
        if trips:
            assert m.refused[0][1] == ("slack" if tension_b < 100.0 else "over-tension")


def test_a_leg_the_guard_keeps_stopping_is_given_up_with_the_limit_as_its_reason() -> None:
    m, dev = _mission(), FreshDevices()
    t = _on_the_leg(m, dev)
    for k in range(MAX_GUARDS + 1):
        assert m.state == "DRIVE" and m.legs[0].lengths is None, (k, m.events[-3:])
        leg = m.legs[0]
        # every way out reads the tension near its limit a little past its first waypoint
        ahead = leg.waypoints[m.wp_i]
        _stand(m, dev, ahead, tension_b=NEAR_N)
        t += 0.1
        m.step(t, dev)
        if leg.back_to is not None:
            _stand(m, dev, np.array(m.trail[leg.back_to][2:]))
            t += 0.1
            m.step(t, dev)
    assert _names(m).count("TENSION_GUARD") == MAX_GUARDS + 1
    assert m.reasons == ["slack"] and m.reached == [False] and "TARGET_UNREACHABLE" in _names(m)
    assert m.state == "DONE"


def test_the_refused_places_survive_a_restart_and_a_bad_record_is_refused() -> None:
    m, dev = _mission(), FreshDevices()
    t = _on_the_leg(m, dev)
    here = 0.5 * (m.legs[0].waypoints[1] + m.legs[0].waypoints[2])
    _stand(m, dev, here, tension_b=NEAR_N)
    m.step(t + 0.1, dev)
    st = json.loads(json.dumps(snapshot(m, t)))
    m2 = _mission()
    restore(m2, st, m.z, GRID)
    assert len(m2.refused) == 1 and np.allclose(m2.refused[0][0], here) and m2.refused[0][1] == "slack"
    assert m2.route().refused and any(v == "slack" for v in m2.route().nodes.values())
    for bad in ([[1.0, 2.0]], [[1.0, float("nan"), "slack"]], [[1.0, 2.0, "loose"]], "x", [["a", 2.0, "slack"]]):
        with pytest.raises(CheckpointError, match="refused"):
            restore(_mission(), {**st, "refused": bad}, m.z, GRID)
