"""The Cliff-bot's mission looks before it plans, after its first fix (fsw.tasks.cliffbot_mission,
``SENSE``; docs/team.md, "Both agents sense")."""

from __future__ import annotations

import numpy as np

from fsw.comm.team.fix_packets import Fix
from fsw.core.geometry import MapGrid, MapGridConfig
from fsw.core.team.cliffbot_nav import NavConfig
from fsw.core.team.climber_ground import ClimberConfig
from fsw.core.team.tether import TetherConfig
from fsw.drivers.cliffbot_devices import CliffbotDevices
from fsw.sections import CliffbotMissionConfig, CliffbotSensingConfig
from fsw.tasks.cliffbot_mission import CliffbotMission

GRID = MapGrid.from_config(MapGridConfig(origin_x_m=0.0, origin_y_m=-3.0, cell_m=0.1, nx=60, ny=40))


class FreshDevices(CliffbotDevices):
    """Statuses that never go stale (the mission's device supervision is not under test here)."""

    def stale(self, now: float) -> list[str]:
        return []


def _mission(sensing: CliffbotSensingConfig | None) -> CliffbotMission:
    anchors = np.array([[1.0, 0.6, 0.3], [4.0, 0.6, 0.3]])
    return CliffbotMission(CliffbotMissionConfig(), TetherConfig(), ClimberConfig(), NavConfig(), anchors,
                           np.array([2.5, -0.5]), -np.pi / 2, np.array([[2.0, -1.5]]), sensing=sensing)


def _names(m: CliffbotMission) -> list[str]:
    return [name for _, name, _ in m.events]


def _first_fix_answered(m: CliffbotMission, dev: CliffbotDevices) -> None:
    """The first map asks for a fix before the first look; answered NO_FIX."""
    assert m.state == "WAIT_FIX" and m.step(0.05, dev).request_fix
    m.on_no_fix(m.fix_seq, "busy")


def test_with_sensing_the_first_map_asks_for_views_once_and_their_map_is_planned_on() -> None:
    m = _mission(CliffbotSensingConfig(enabled=True))
    dev = FreshDevices()
    m.set_map(np.zeros(GRID.shape), GRID)
    _first_fix_answered(m, dev)
    assert m.state == "SENSE"
    first, second = m.step(0.1, dev), m.step(0.2, dev)
    assert first.sense and not second.sense and m.sense_seq == 1
    assert first.rates_mps == (0.0, 0.0) and m.state == "SENSE"  # it holds still while it looks
    m.sensed(0)  # a map without this request's views (say, a newer RECON-bot map) does not end it
    assert m.state == "SENSE"
    m.set_map(np.zeros(GRID.shape), GRID)
    m.sensed(1)
    assert m.state == "PLAN" and "SENSED" in _names(m)
    m.step(0.3, dev)
    assert m.state in ("WAIT_FIX", "DONE") and "PLAN" in _names(m)


def test_views_that_never_come_end_in_a_plan_on_the_map_it_has() -> None:
    m = _mission(CliffbotSensingConfig(enabled=True, sense_timeout_s=5.0))
    dev = FreshDevices()
    m.set_map(np.zeros(GRID.shape), GRID)
    _first_fix_answered(m, dev)
    assert m.step(0.1, dev).sense
    m.step(4.0, dev)
    assert m.state == "SENSE"
    m.step(5.2, dev)
    assert m.state == "PLAN" and "SENSE_TIMEOUT" in _names(m)


def test_a_leg_looks_again_only_after_the_cliffbot_moved() -> None:
    cfg = CliffbotSensingConfig(enabled=True, move_m=0.5)
    m = _mission(cfg)
    m.set_map(np.zeros(GRID.shape), GRID)
    _first_fix_answered(m, FreshDevices())
    m.step(0.1, CliffbotDevices())
    m.sensed(1)
    m.sensed_xy = m.est.xy
    assert not m._wants_views()
    m.est.s[:2] += np.array([0.3, 0.0])
    assert not m._wants_views()
    m.est.s[:2] += np.array([0.3, 0.0])
    assert m._wants_views()


def test_the_first_look_comes_after_the_first_fix_and_the_first_leg_needs_no_other() -> None:
    m = _mission(CliffbotSensingConfig(enabled=True))
    dev = FreshDevices()
    m.set_map(np.zeros(GRID.shape), GRID)
    assert m.state == "WAIT_FIX" and not m.step(0.1, dev).sense  # no look before the fix
    assert m.sense_seq == 0 and m.fix_seq == 1
    sharp = np.diag([1e-4, 1e-4, 1e-4])
    m.on_estimate(m.est.s, sharp)  # the navigation fused it
    fix = Fix(1, 100, np.array([2.5, -0.5, 0.0]), np.array([0.0, 0.0, -np.pi / 2]), np.eye(6) * 1e-4)
    m.on_fix(fix, True, 0.1)
    assert m.state == "SENSE" and m.step(0.2, dev).sense and m.look_sigma < 0.05  # looked with the fix's pose
    m.set_map(np.zeros(GRID.shape), GRID)
    m.sensed(1)
    m.step(0.3, dev)  # PLAN
    cmd = m.step(0.4, dev)  # leg 1 from where the fix was fused: no second request
    assert not cmd.request_fix and m.fix_seq == 1 and m.state == "DRIVE"
    m.est.s[:2] += np.array([0.3, 0.0])  # moved: the next leg asks again
    m.state, m.fix_asked_at = "WAIT_FIX", None
    assert m.step(0.5, dev).request_fix and m.fix_seq == 2


def test_without_sensing_the_mission_plans_at_once() -> None:
    for sensing in (None, CliffbotSensingConfig(enabled=False)):
        m = _mission(sensing)
        m.set_map(np.zeros(GRID.shape), GRID)
        assert m.state == "PLAN" and not m.step(0.1, CliffbotDevices()).sense


def test_the_heads_scan_has_a_tilt_per_pan_or_one_for_all() -> None:
    import pytest

    sc = CliffbotSensingConfig(pan_deg=(0.0, 90.0), tilts_deg=(-40.0, -75.0), places=())
    assert [sc.tilt_of(k) for k in range(3)] == [-40.0, -75.0, -40.0]  # the k-th capture's, round the scan
    assert CliffbotSensingConfig(pan_deg=(0.0,), tilts_deg=(), tilt_deg=-30.0, places=()).tilt_of(5) == -30.0
    with pytest.raises(ValueError, match="tilts_deg"):
        CliffbotSensingConfig(pan_deg=(0.0, 90.0), tilts_deg=(-40.0,), places=())


def test_the_heads_scan_names_where_each_pointing_is_taken_from_or_none() -> None:
    import pytest

    sc = CliffbotSensingConfig(pan_deg=(0.0, 90.0), tilts_deg=(), places=("rear", "front"))
    assert [sc.place_of(k) for k in range(3)] == ["rear", "front", "rear"]
    assert CliffbotSensingConfig(pan_deg=(0.0,), tilts_deg=(), places=()).place_of(4) == ""  # by the pan
    for bad in (("rear",), ("rear", "middle")):
        with pytest.raises(ValueError, match="places"):
            CliffbotSensingConfig(pan_deg=(0.0, 90.0), tilts_deg=(), places=bad)
