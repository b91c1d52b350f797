"""SAFE and its automatic recovery (fsw/tasks/mission_safe.py) on a stepped clock: the test plays
the motion task on the bus, so it sees every request the sequencer makes and answers it.

The recovery an operator expects: after ``safe_recover_s`` in SAFE the sequencer clears the
latched driver faults (a ``clear_faults`` request, before any move), then resumes; a fault
that is still there brings SAFE back, and after ``safe_max_recoveries`` tries in a row
without a completed step SAFE is final, with the reason; a completed step resets the count;
a refused clear (an engaged E-stop) is a failed try and never resumes the mission.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
from task_rig import TaskRig, task_config

from fsw.core.geometry import MapGrid
from fsw.core.map.elevation_map import ElevationMap
from fsw.tasks.messages import (
    CAMERA_REQUEST,
    MAP_UPDATED,
    MOTION_REQUEST,
    MOTION_STATUS,
    NAV_POSE,
    MapUpdate,
    MotionStatus,
    MoveOutcome,
    NavPose,
)

RECOVER_S = 1.0  # 10 frames
MAX_TRIES = 2
GRID = MapGrid(-1.0, -1.0, 0.1, 20, 20)


def _cfg(**kw: Any) -> Any:
    base = task_config(("mission", "mission"))
    mission = dataclasses.replace(
        base.mission, auto_start=False, transmit=False, panorama_pans_deg=(0.0, 90.0), step_timeout_s=2.0,
        capture_retries=1, near_pans_deg=(), safe_recover_s=RECOVER_S, safe_max_recoveries=MAX_TRIES, **kw,
    )
    return dataclasses.replace(base, mission=mission)


class Bus:
    """The mission on a rig; the test answers its motion requests."""

    def __init__(self, **kw: Any) -> None:
        self.rig = TaskRig(_cfg(**kw))
        self.moves = self.rig.tap(MOTION_REQUEST)
        self.captures = self.rig.tap(CAMERA_REQUEST)
        self.m = self.rig.task("mission")
        self.rig.publish(NAV_POSE, NavPose(0.0, 0.0, 0.0, 0.0, np.diag([1e-4] * 3), (0.0, math.radians(-30.0), 0.0)))

    def requests(self) -> list[Any]:
        return [r for r in self.moves.drain() if r.request_id > 0]  # not SAFE's stop and park

    def until_request(self, kind: str, frames: int = 60) -> Any:
        """Run until the mission asks for ``kind``; every other request seen on the way is returned too."""
        seen: list[Any] = []
        for _ in range(frames):
            self.rig.run(1)
            seen += self.requests()
            if seen and seen[-1].kind == kind:
                return seen
        raise AssertionError(f"no {kind} request in {frames} frames; saw {[r.kind for r in seen]}")

    def reply(self, req: Any, state: str = "done", reason: str = "") -> None:
        self.rig.publish(MOTION_STATUS, MotionStatus(req.request_id, req.kind, MoveOutcome(state), reason))

    def fail_mast(self) -> None:
        """The next mast move is refused (a latched mast fault): SAFE."""
        (req,) = self.until_request("mast")[-1:]
        self.reply(req, "refused", "mast faults: controller (CLEAR_FAULTS)")
        self.rig.run(1)
        assert str(self.m.state) == "SAFE"

    def map_update(self, view_id: int) -> None:
        up = MapUpdate(view_id, self.rig.clock.now(), 100 + view_id, 10, 1000, 0, 5.0, ElevationMap(GRID))
        self.rig.publish(MAP_UPDATED, up)

    def events(self, name: str) -> list[str]:
        return [e.text for e in self.rig.events(f"mission.{name}")]


def test_recovery_clears_faults_before_it_resumes_and_only_after_the_wait() -> None:
    b = Bus()
    b.rig.command("mission.START")
    b.fail_mast()
    t_safe = b.rig.clock.now()
    seen = b.until_request("clear_faults")
    assert [r.kind for r in seen] == ["clear_faults"]  # nothing moves before the faults are cleared
    assert b.rig.clock.now() - t_safe >= RECOVER_S - 1e-9 and str(b.m.state) == "SAFE"
    b.reply(seen[-1])
    seen = b.until_request("mast")  # nothing mapped yet: the panorama again
    assert [r.kind for r in seen] == ["mast"] and str(b.m.state) == "POINT"
    assert len(b.events("RECOVERING")) == 1 and len(b.events("RECOVERED")) == 1
    assert b.m.safe.entries == 1 and b.m.safe.tries == 1 and not b.m.safe.final


def test_a_persistent_fault_ends_the_mission_in_safe_after_the_bounded_tries() -> None:
    b = Bus()
    b.rig.command("mission.START")
    b.fail_mast()
    for _ in range(MAX_TRIES):
        b.reply(b.until_request("clear_faults")[-1])
        b.fail_mast()  # the fault is still there
    b.rig.run(int(5 * RECOVER_S / 0.1))
    assert b.requests() == []  # no more clears, no more moves
    assert b.m.safe.final and str(b.m.state) == "SAFE" and b.m.safe.entries == MAX_TRIES + 1
    assert b.m.safe.reason.startswith("persistent fault: mast move refused: mast faults")
    assert len(b.events("SAFE_FINAL")) == 1 and len(b.events("RECOVERED")) == MAX_TRIES
    # the operator may still resume it: a fresh count
    assert b.rig.command("mission.RESUME").status.name == "OK"
    assert not b.m.safe.final and b.m.safe.tries == 0 and str(b.m.state) != "SAFE"


def test_a_completed_step_after_a_recovery_resets_the_count() -> None:
    b = Bus()
    b.rig.command("mission.START")
    b.fail_mast()
    b.reply(b.until_request("clear_faults")[-1])
    for _ in range(2):  # the recovered panorama completes: step 0 done
        b.reply(b.until_request("mast")[-1])
        b.rig.run(1)
        assert len(b.captures.drain()) == 1
        b.map_update(0)
    b.rig.run(2)
    assert b.m.step == 1 and b.m.safe.tries == 1
    b.m.enter_safe("a new fault")  # e.g. a motor fault on the next move
    assert b.m.safe.tries == 0 and b.m.safe.entries == 2
    b.reply(b.until_request("clear_faults")[-1])
    b.rig.run(1)
    assert b.m.safe.tries == 1 and str(b.m.state) != "SAFE" and not b.m.safe.final


def test_a_refused_clear_is_a_failed_try_and_never_resumes() -> None:
    """An engaged E-stop: the motion task refuses to clear; the mission stays in SAFE, and once the
    tries are spent SAFE is final."""
    b = Bus()
    b.rig.command("mission.START")
    b.fail_mast()
    for n in range(MAX_TRIES):
        (req,) = b.until_request("clear_faults")[-1:]
        b.reply(req, "refused", "emergency stop engaged: only the operator releases it")
        b.rig.run(1)
        assert str(b.m.state) == "SAFE" and b.m.safe.tries == n + 1
    b.rig.run(int(3 * RECOVER_S / 0.1))
    assert b.requests() == [] and b.m.safe.final and b.events("RECOVERED") == []
    assert len(b.events("RECOVERY_FAILED")) == MAX_TRIES


def test_without_clearing_the_recovery_resumes_directly() -> None:
    b = Bus(safe_clear_faults=False)
    b.rig.command("mission.START")
    b.fail_mast()
    seen = b.until_request("mast")
    assert [r.kind for r in seen] == ["mast"] and len(b.events("RECOVERED")) == 1


def test_with_recovery_off_safe_waits_for_the_operator() -> None:
    b = Bus()
    b.m.safe.cfg = dataclasses.replace(b.m.mcfg, safe_recover_s=0.0)
    b.rig.command("mission.START")
    b.fail_mast()
    b.rig.run(50)
    assert b.requests() == [] and str(b.m.state) == "SAFE" and not b.m.safe.final
