"""Every event the sans-I/O Cliff-bot mission raises is one of its flight task's events, under its
own name (fsw.tasks.cliffbot.mission.MISSION_EVENTS): an event the task does not know would be
published as another."""

from __future__ import annotations

import inspect
import re

from fsw.tasks import cliffbot_mission
from fsw.tasks.cliffbot.mission import MISSION_EVENTS, RENAMED


def test_every_mission_event_is_a_task_event() -> None:
    raised = set(re.findall(r'self\.event\(\s*"([A-Z_]+)"', inspect.getsource(cliffbot_mission)))
    assert {"APPROACH", "LOOK", "EXPLORE", "TARGET_UNREACHABLE"} <= raised
    missing = {name for name in raised if RENAMED.get(name, name) not in MISSION_EVENTS}
    assert not missing
