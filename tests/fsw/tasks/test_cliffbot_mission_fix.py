"""The Cliff-bot's mission asks for a fix on ground command (fsw.tasks.cliffbot_mission; docs/team.md)."""

from __future__ import annotations

import numpy as np

from fsw.core.team.cliffbot_nav import NavConfig
from fsw.core.team.climber_ground import ClimberConfig
from fsw.core.team.tether import TetherConfig
from fsw.drivers.cliffbot_devices import CliffbotDevices
from fsw.sections import CliffbotMissionConfig
from fsw.tasks.cliffbot_mission import CliffbotMission


def _mission() -> CliffbotMission:
    anchors = np.array([[1.0, 0.6, 0.0], [4.0, 0.6, 0.0]])
    return CliffbotMission(CliffbotMissionConfig(), TetherConfig(), ClimberConfig(), NavConfig(), anchors,
                           np.array([2.5, -0.5]), -np.pi / 2, np.array([[2.0, -1.5]]))


def test_a_fix_asked_for_at_a_target_is_requested_once() -> None:
    m = _mission()
    m.state, m.dwell_until = "DWELL", 100.0
    m.request_fix()
    dev = CliffbotDevices()
    first, second = m.step(0.5, dev), m.step(0.6, dev)
    assert first.request_fix and not second.request_fix and m.fix_seq == 1
    assert m.events[-1][1] == "FIX_REQUEST" and "on command" in m.events[-1][2]


def test_a_fix_asked_for_before_the_map_is_not_requested() -> None:
    m = _mission()
    m.request_fix()
    assert not m.step(0.5, CliffbotDevices()).request_fix and m.fix_seq == 0
    assert m.events[-1][1] == "FIX_REQUEST" and "not now" in m.events[-1][2]
