"""A target given up for a reason a look can change is tried again once, after the other targets,
on the map their looks have grown meanwhile; its reason is the final one, and a mission resumed
from its checkpoint retries the same way (fsw.tasks.cliffbot_mission; docs/team.md, "Approach:
making the unknown known")."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from fsw.core.team.cliffbot_nav import NavConfig
from fsw.core.team.climber_ground import ClimberConfig, ground_layers
from fsw.core.team.tether import TetherConfig
from fsw.drivers.cliffbot_devices import CliffbotDevices
from fsw.sections import CliffbotMissionConfig, CliffbotSensingConfig
from fsw.tasks.cliffbot.checkpoint import restore, snapshot
from fsw.tasks.cliffbot_mission import CliffbotMission
from tests.fsw.tasks.test_cliffbot_mission_approach import (
    GRID,
    START,
    TARGET,
    FreshDevices,
    _drive,
    _ground,
    _names,
    _start,
    _unknown_below,
)

KNOWN_TARGET = np.array([3.5, -0.9])  # a target on the ground known from the start
Map = Callable[[CliffbotMission], np.ndarray]


def _mission(targets: np.ndarray, return_home: bool = False, retry: bool = True) -> CliffbotMission:
    anchors = np.array([[1.0, 0.6, 0.3], [4.0, 0.6, 0.3]])
    return CliffbotMission(CliffbotMissionConfig(approach_looks=1, return_home=return_home,
                                                 retry_given_up=retry), TetherConfig(),
                           ClimberConfig(), NavConfig(), anchors, START, -np.pi / 2, targets,
                           sensing=CliffbotSensingConfig(enabled=True))


def _run(m: CliffbotMission, dev: CliffbotDevices, t: float, views: Map, until: str = "DONE") -> float:
    """Run the mission as a perfect body would until ``until`` (state) or DONE: every fix request
    answered with NO_FIX, every view request with the map ``views`` gives for the mission then."""
    for _ in range(2000):
        if m.state in (until, "DONE", "SAFE"):
            return t
        if m.state == "DRIVE":
            t, _ = _drive(m, dev, t, ground_layers(m.z, GRID, m.ccfg, anchors=m.anchors).known)
            continue
        t += 0.5
        cmd = m.step(t, dev)
        if cmd.request_fix:
            m.on_no_fix(m.fix_seq, "busy")
        if cmd.sense:
            m.set_map(views(m), GRID)
            m.sensed(m.sense_seq)
    raise AssertionError(f"the mission did not end: {m.state}, {m.events[-3:]}")


def _targets() -> np.ndarray:
    return np.array([TARGET, KNOWN_TARGET])


def test_a_target_given_up_on_unknown_ground_is_reached_when_tried_again_on_the_grown_map() -> None:
    m, dev = _mission(_targets()), FreshDevices()
    z0 = _unknown_below(-1.9)
    # the looks on the first target's own leg show nothing new; a look after the other target's
    # leg (the map has grown meanwhile) shows its ground
    t = _start(m, dev, z0)
    t = _run(m, dev, t, lambda mm: z0 if mm.leg_i == 0 else _ground())
    assert m.state == "DONE" and m.reached == [True, True], m.events
    assert [leg.target for leg in m.legs] == [0, 1, 0]
    given_up = [text for _, name, text in m.events if name == "TARGET_UNREACHABLE"]
    assert len(given_up) == 1 and "tried again after the other targets" in given_up[0]
    assert m.reasons == ["", ""] and m.looks[0] >= 1


def test_a_target_is_tried_again_once_and_keeps_its_final_reason_with_all_its_looks() -> None:
    m, dev = _mission(_targets(), return_home=True), FreshDevices()
    z0 = _unknown_below(-1.9)
    _run(m, dev, _start(m, dev, z0), lambda mm: z0)  # no look ever shows the target's ground
    assert m.state == "DONE" and m.reached == [False, True]
    # the retry comes after the other target and before the leg home, once
    assert [leg.target for leg in m.legs] == [0, 1, 0, None]
    n = m.looks[0]
    assert n == m.legs[2].looks and n > m.legs[0].looks >= 1  # the retry's looks carry on the first's
    assert m.reasons[0] == f"unknown ground ({n} looks)"
    assert _names(m).count("TARGET_UNREACHABLE") == 2 and "HOME" in _names(m)


def test_a_target_with_no_other_target_after_it_is_not_tried_again() -> None:
    m, dev = _mission(np.array([KNOWN_TARGET, TARGET]), return_home=True), FreshDevices()
    z0 = _unknown_below(-1.9)
    _run(m, dev, _start(m, dev, z0), lambda mm: z0)
    # the map would be the same: the target is given up once, its reason kept
    assert m.state == "DONE" and [leg.target for leg in m.legs] == [0, 1, None]
    assert m.reasons[1].startswith("unknown ground (") and _names(m).count("TARGET_UNREACHABLE") == 1


def test_without_retry_given_up_a_target_given_up_stays_given_up() -> None:
    m, dev = _mission(_targets(), retry=False), FreshDevices()
    z0 = _unknown_below(-1.9)
    t = _start(m, dev, z0)
    _run(m, dev, t, lambda mm: z0 if mm.leg_i == 0 else _ground())  # the default: the grown map is not used
    assert m.state == "DONE" and [leg.target for leg in m.legs] == [0, 1] and m.reached == [False, True]
    assert m.reasons[0].startswith("unknown ground (")


def test_a_mission_resumed_from_its_checkpoint_retries_the_same_way() -> None:
    m, dev = _mission(_targets()), FreshDevices()
    z0 = _unknown_below(-1.9)
    t = _start(m, dev, z0)
    t = _run(m, dev, t, lambda mm: z0, until="DWELL")  # at the other target, the first given up once
    assert m.leg_i == 1 and [leg.target for leg in m.legs] == [0, 1, 0]
    back = _mission(_targets())
    restore(back, snapshot(m, t), m.z, GRID)
    assert [leg.target for leg in back.legs] == [0, 1, 0]
    back.on_estimate(m.est.s, m.est.P)
    _run(back, FreshDevices(), t, lambda mm: z0)
    # the resumed retry is the target's last: given up again, no third leg
    assert back.state == "DONE" and [leg.target for leg in back.legs] == [0, 1, 0]
    assert back.reasons[0].startswith("unknown ground (") and back.reached == [False, True]
