"""The typed checkpoint sections (fsw/tasks/mission_state.py, motion_state.py, state_json.py).

``data/checkpoint_v1_state.json`` is the state of a checkpoint written by the build before the
sections were typed (``make demo``, step 21 of seed 0; the perception section and the bench's
hooks left out): the typed sections read it back and write it out again unchanged, and the
flight software resumes from it.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from fsw.app import build_executive
from fsw.core.geometry import MapGrid
from fsw.core.map.elevation_map import ElevationMap
from fsw.drivers.factory import close_devices
from fsw.drivers.map_store import MapStore
from fsw.drivers.radio import open_radio
from fsw.drivers.resources import Resources
from fsw.executive.executive import Executive
from fsw.framework.clock import SteppedClock
from fsw.settings import load_settings
from fsw.tasks.mission import MissionTask
from fsw.tasks.mission_state import MissionPhase, MissionSection, fingerprint
from fsw.tasks.motion import MotionTask
from fsw.tasks.motion_state import MotionSection, section
from fsw.tasks.state_json import JsonObject, StateError

OLD = Path(__file__).parent / "data" / "checkpoint_v1_state.json"
SHAPE = (256, 256)  # the demo's map grid (config/fsw.toml [map])


def old_state() -> JsonObject:
    state: JsonObject = json.loads(OLD.read_text(encoding="utf-8"))
    return state


def _mission(state: JsonObject) -> JsonObject:
    m = state["mission"]
    assert isinstance(m, dict)
    return m


def _without_wall_time(mission: JsonObject) -> JsonObject:
    """The older mission section as this build writes it: the same, less each record's host
    wall-clock time (``wall_s``), which a checkpoint no longer holds (a lockstep run writes the
    same checkpoints every time)."""
    out = copy.deepcopy(mission)
    records = out["records"]
    assert isinstance(records, list) and records and all("wall_s" in r for r in records)
    for r in records:
        del r["wall_s"]
    return out


def _motion(state: JsonObject) -> JsonObject:
    tasks = state["tasks"]
    assert isinstance(tasks, dict)
    return tasks["motion"]  # type: ignore[no-any-return]


def test_an_older_mission_section_reads_back_and_writes_out_unchanged() -> None:
    old = _mission(old_state())
    s = MissionSection.from_json(old, SHAPE)
    assert s.phase is MissionPhase.SELECT and s.step == 21 and len(s.records) == 21
    assert s.latest is not None and s.latest.drop is not None and s.latest.drop.shape == SHAPE
    assert s.nav is not None and s.nav.cov.shape == (3, 3) and s.edge is not None
    assert json.dumps(s.to_json(), sort_keys=True) == json.dumps(_without_wall_time(old), sort_keys=True)
    assert all(r.wall_s is None for r in s.records)


def test_an_older_motion_section_reads_back_and_writes_out_unchanged() -> None:
    old = _motion(old_state())
    s = section(old)
    assert s.attitude is not None and s.setpoints is not None and s.fix_terms() is not None
    assert s.done == old["done"] and s.pose() == tuple(old["pose"])
    assert json.dumps(s.to_json(), sort_keys=True) == json.dumps(old, sort_keys=True)


def test_sections_from_before_the_later_fields_still_load() -> None:
    """Fields added after version 1 was first written (looks, stays, stood ground, attitude,
    navigation fix) are optional: absent, the section is what that older mission had."""
    m = _mission(old_state())
    for key in ("looks", "stays", "looked", "looked_from", "look_n", "look_left", "stood_on"):
        del m[key]
    s = MissionSection.from_json(m, SHAPE)
    assert s.looks == 0 and s.stays == [] and s.looked is None and s.stood_on == []
    mo = _motion(old_state())
    for key in ("attitude", "fix_id", "fix_seen", "base_cov", "path0", "turned0", "lever"):
        del mo[key]
    ms = MotionSection.from_json(mo)
    assert ms.attitude is None and ms.fix_id == 0 and ms.fix_terms() is None


@pytest.mark.parametrize(("where", "key", "value", "named"), [
    ("mission", "step", "x", "step"),
    ("mission", "step", math.nan, "step"),
    ("mission", "looked", [1.0, 2.0], "looked"),
    ("mission", "stays", "not a list", "stays"),
    ("mission", "phase", "FLYING", "phase"),
    ("mission", "records", [{"step": 1}], "mapped_cells"),
    ("motion", "steer_hold", [0.0, 0.0], "steer_hold"),
    ("motion", "done", None, "done"),
    ("motion", "setpoints", {"DRIVE_FL": "fast"}, "setpoints.DRIVE_FL"),
    ("motion", "pose", "nonsense", "pose"),
])
def test_a_bad_field_is_a_state_error_naming_it(where: str, key: str, value: object, named: str) -> None:
    state = old_state()
    sec = _mission(state) if where == "mission" else _motion(state)
    sec[key] = value
    with pytest.raises(StateError, match=named):
        if where == "mission":
            MissionSection.from_json(sec, SHAPE)
        else:
            section(sec)


def test_the_flight_software_resumes_from_an_older_checkpoint(tmp_path: Path) -> None:
    """The state of the older build, on a map of the configured grid: the mission continues after
    step 21 with the records, counters and odometry it had."""
    cfg = load_settings()  # its [map] grid is the one the state was written on
    cfg = dataclasses.replace(cfg, checkpoint=dataclasses.replace(cfg.checkpoint, directory=str(tmp_path / "c")))
    state = copy.deepcopy(old_state())
    state["fingerprint"] = fingerprint(cfg)  # the method of the test's configuration
    emap = ElevationMap(MapGrid.from_config(cfg.map), cfg.fusion)
    MapStore(cfg.checkpoint, cfg.fusion).save_next(emap, float(state["time_s"]), state)  # type: ignore[arg-type]
    radio = open_radio(f"inproc://sections-test-{id(tmp_path)}")
    exe = build_executive(cfg, SteppedClock(12.0), Resources(map_store=MapStore(cfg.checkpoint, cfg.fusion),
                                                             radio_port=radio))
    try:
        check_resumed(exe)
    finally:
        close_devices(exe.ctx.res)
        radio.close()


def check_resumed(exe: Executive) -> None:
    mission, motion = exe.tasks["mission"], exe.tasks["motion"]
    assert isinstance(mission, MissionTask) and isinstance(motion, MotionTask)
    names = [e.name for e in exe.events.history]
    assert "mission.RESUMED" in names and "mission.RESUME_REFUSED" not in names
    old = _mission(old_state())
    # step 21 of a 20-step mission: it goes on as the uninterrupted run did, to the map's transmission
    assert mission.step == 21 and len(mission.records) == 21 and mission.end == "step limit reached (20)"
    assert mission.state == MissionPhase.TRANSMIT
    assert mission.ground.looks == old["looks"] and mission.ground.stays == old["stays"]
    assert mission.safe.entries == old["safe_entries"]
    assert motion.odo.pose == tuple(_motion(old_state())["pose"]) and motion.done == _motion(old_state())["done"]
    want = MissionSection.from_json(old, SHAPE).latest
    assert mission.latest is not None and want is not None and np.array_equal(mission.latest.drop, want.drop)
    # and it writes the same mission section again (with the end it has reached since)
    again = mission.section(MissionPhase.SELECT).to_json()
    assert json.dumps(again, sort_keys=True) == json.dumps({**_without_wall_time(old), "end": mission.end},
                                                           sort_keys=True)
