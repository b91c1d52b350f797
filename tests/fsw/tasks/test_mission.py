"""The mission sequencer (fsw/tasks/mission.py) alone on a stepped clock: the test plays the
motion, camera, perception and next-view tasks on the bus (issue 11, item 5).

Unit tests walk the sequence (panorama, select, move, point, acquire, end) and its faults; a
stateful property test (hypothesis ``RuleBasedStateMachine``) sends START/ABORT/RESUME and
the other tasks' replies in random order and checks the invariants after every rule.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, event, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, precondition, rule
from task_rig import TaskRig, task_config

from fsw.core.geometry import MapGrid
from fsw.core.localization.nav_fix import NavFix
from fsw.core.map.elevation_map import ElevationMap
from fsw.core.planning.view_candidates import CandidateView
from fsw.tasks import messages
from fsw.tasks.messages import (
    CAMERA_REQUEST,
    MAP_UPDATED,
    MOTION_REQUEST,
    MOTION_STATUS,
    NAV_POSE,
    NBV_REQUEST,
    NBV_RESULT,
    VIEW_FAILED,
    MapUpdate,
    MotionStatus,
    NavPose,
    ViewFailed,
)
from fsw.tasks.mission import FIX_WAIT_S

STEP_TIMEOUT_S = 2.0  # 20 frames
OUTCOME: Any = getattr(messages, "MoveOutcome", str)  # a motion outcome from its name


def _cfg() -> Any:
    base = task_config(("mission", "mission"))
    mission = dataclasses.replace(
        base.mission, auto_start=False, transmit=False, panorama_pans_deg=(0.0, 90.0), step_timeout_s=STEP_TIMEOUT_S,
        safe_recover_s=0.0, capture_retries=1, near_pans_deg=(),  # the step-0 near views: tests/integration
    )
    return dataclasses.replace(base, mission=mission)


CFG = _cfg()
GRID = MapGrid(-1.0, -1.0, 0.1, 20, 20)


def phase(rig: TaskRig) -> str:
    """The mission's phase by name (a string today, an Enum's name once phases are typed)."""
    state = rig.task("mission").state
    return str(getattr(state, "name", state))


class Mission:
    """The rig plus the other tasks' side of the bus."""

    def __init__(self) -> None:
        self.rig = TaskRig(CFG)
        self.moves = self.rig.tap(MOTION_REQUEST)
        self.captures = self.rig.tap(CAMERA_REQUEST)
        self.plans = self.rig.tap(NBV_REQUEST)
        self.pose = (0.0, 0.0, 0.0)

    def nav(self) -> None:
        self.rig.publish(NAV_POSE, NavPose(self.rig.clock.now(), *self.pose, np.diag([1e-4, 1e-4, 1e-4]),
                                           (0.0, math.radians(-30.0), 0.0)))

    def motion_reply(self, request_id: int, kind: str, state: str = "done") -> None:
        reason = "" if state == "done" else "test"
        self.rig.publish(MOTION_STATUS, MotionStatus(request_id, kind, OUTCOME(state), reason))

    def view(self) -> list[Any]:
        """Answer the mast move of the view in progress; the capture requests it led to."""
        self.rig.run(1)
        (req,) = self.moves.drain()
        self.motion_reply(req.request_id, "mast")
        self.rig.run(1)
        return self.captures.drain()

    def map_update(self, view_id: int) -> None:
        emap = ElevationMap(GRID)
        self.rig.publish(MAP_UPDATED, MapUpdate(view_id, self.rig.clock.now(), 100 + view_id, 10, 1000, 0, 5.0, emap))


def test_start_waits_for_a_pose_then_points_the_mast_for_the_panorama() -> None:
    m = Mission()
    assert m.rig.command("mission.START").status.name == "OK" and phase(m.rig) == "INIT"
    m.rig.run(3)
    assert phase(m.rig) == "INIT" and not m.moves.drain()  # no pose estimate yet
    m.nav()
    m.rig.run(1)
    reqs = m.moves.drain()
    pano = (0.0, math.radians(CFG.mission.panorama_tilt_deg), CFG.mission.panorama_lift_m)
    assert [(r.kind, r.joints) for r in reqs] == [("mast", pano)]
    assert phase(m.rig) == "POINT" and reqs[0].request_id > 0


def test_panorama_then_planner_then_done() -> None:
    """Each view: mast done -> capture request -> map update; after the panorama the planner
    is asked; no view worth taking ends mapping (no radio: DONE)."""
    m = Mission()
    m.rig.command("mission.START")
    m.nav()
    for _ in range(2):
        captures = m.view()
        assert phase(m.rig) == "ACQUIRE"
        assert [c.view_id for c in captures] == [0]  # both panorama views are step 0
        m.map_update(0)
    m.rig.run(1)
    assert phase(m.rig) == "SELECT" and len(m.plans.drain()) == 1
    assert len(m.rig.events("mission.STEP")) == 1
    m.rig.publish(NBV_RESULT, None)
    m.rig.run(1)
    assert phase(m.rig) == "DONE"
    assert [e.text for e in m.rig.events("mission.END")] == ["mapping ends: no reachable view worth taking"]


def _to_select(m: Mission) -> None:
    m.rig.command("mission.START")
    m.nav()
    for _ in range(2):
        m.view()
        m.map_update(0)
    m.rig.run(1)
    assert phase(m.rig) == "SELECT"


def test_a_wheel_move_without_an_edge_is_refused_by_the_geofence() -> None:
    """No edge mapped yet: the geofence refuses any wheel move; an event, no wheel move sent, and
    the step's view is taken from where the rover stands, the reason kept (issue 13: never a
    crossing, never a stall)."""
    m = Mission()
    _to_select(m)
    m.moves.drain()
    m.rig.publish(NBV_RESULT, CandidateView((0.5, 0.0, 0.0), (0.0, -0.5, 0.5), 100.0, 10.0, 1.0, 0.0, 99.0, "5"))
    m.rig.run(2)
    # the part-way search: one geofence check a slack slice (not the foreground), no wheel move
    assert m.rig.task("mission").ground.fence_job is not None and not m.moves.drain()
    frames = 2 + m.rig.run_until(lambda: phase(m.rig) == "POINT", 60)
    assert frames > 5
    assert phase(m.rig) == "POINT" and m.rig.task("mission").ground.edge_violations == 1
    assert len(m.rig.events("mission.GEOFENCE")) == 1
    assert [r.kind for r in m.moves.drain()] == ["mast"]
    assert len(m.rig.task("mission").ground.stays) == 1


@pytest.mark.parametrize("outcome", ["aborted", "refused"])
def test_a_failed_mast_move_enters_safe(outcome: str) -> None:
    m = Mission()
    m.rig.command("mission.START")
    m.nav()
    m.rig.run(1)
    (req,) = m.moves.drain()
    m.motion_reply(req.request_id + 7, "mast", outcome)  # not ours: ignored
    m.rig.run(1)
    assert phase(m.rig) == "POINT"
    m.motion_reply(req.request_id, "mast", outcome)
    m.rig.run(1)
    assert phase(m.rig) == "SAFE"
    assert m.rig.task("mission").safe.reason == f"mast move {outcome}: test"


def test_a_missing_pair_is_retried_then_safe() -> None:
    m = Mission()
    m.rig.command("mission.START")
    m.nav()
    m.rig.run(1)
    (req,) = m.moves.drain()
    m.motion_reply(req.request_id, "mast")
    m.rig.run(1)
    assert len(m.captures.drain()) == 1
    m.rig.run_until(lambda: len(m.captures) == 1, 30)  # the retry after the step timeout
    assert phase(m.rig) == "ACQUIRE" and len(m.rig.events("mission.RETRY")) == 1
    m.rig.run_until(lambda: phase(m.rig) == "SAFE", 30)
    assert m.rig.task("mission").safe.reason == "no stereo pair after retries (no merged pair)"


def test_a_failed_view_is_retried_at_once_then_safe() -> None:
    """A camera timeout (or a failed stereo job) is published as ``ViewFailed``: the mission
    retries in the next frame instead of waiting out the step timeout, and enters SAFE with
    the reason once ``capture_retries`` retries failed too. A failure of another view is not
    taken for this one."""
    m = Mission()
    m.rig.command("mission.START")
    m.nav()
    m.rig.run(1)
    (req,) = m.moves.drain()
    m.motion_reply(req.request_id, "mast")
    m.rig.run(1)
    assert len(m.captures.drain()) == 1 and phase(m.rig) == "ACQUIRE"
    m.rig.publish(VIEW_FAILED, ViewFailed(99, "camera: timeout"))  # not this step's view
    m.rig.run(2)
    assert not m.captures.drain() and not m.rig.events("mission.RETRY")
    for n in range(1, CFG.mission.capture_retries + 1):
        m.rig.publish(VIEW_FAILED, ViewFailed(0, "camera: timeout"))
        m.rig.run(1)
        assert len(m.captures.drain()) == 1 and len(m.rig.events("mission.RETRY")) == n
    m.rig.publish(VIEW_FAILED, ViewFailed(0, "camera: dropout"))
    m.rig.run(1)
    assert phase(m.rig) == "SAFE"
    assert m.rig.task("mission").safe.reason == "no stereo pair after retries (camera: dropout)"


class MissionMachine(RuleBasedStateMachine):
    """Commands and the other tasks' replies in any order. Invariants: every command answered
    exactly once with the status its phase allows; a failed motion the mission waits on puts
    it in SAFE; in SAFE no move is requested; the sequencer never raises; requests match the
    phase they are made in."""

    @initialize(start=st.sampled_from([True, True, True, False]))
    def setup(self, start: bool) -> None:
        self.m = Mission()
        self.m.nav()
        self.waiting: tuple[int, str] | None = None  # the move the mission waits on
        self.pending_views: list[int] = []
        if start:
            self.command("START")

    def _after(self, before: str) -> None:
        """Collect what the mission published; check it against the phase."""
        now = phase(self.m.rig)
        event(f"phase {now}")
        for req in self.m.moves.drain():
            if req.request_id == 0:  # stop and park: only on entering SAFE
                assert req.kind in ("stop", "mast") and now == "SAFE"
                continue
            assert before != "SAFE" or now != "SAFE", f"move {req.kind} requested in SAFE"
            assert {"goto": "MOVE", "mast": "POINT"}[req.kind] == now, (req, before, now)
            self.waiting = (req.request_id, req.kind)
        self.pending_views += [c.view_id for c in self.m.captures.drain()]
        self.m.plans.drain()
        if now not in ("MOVE", "POINT"):
            self.waiting = None

    def _frames(self, n: int) -> None:
        for _ in range(n):
            before = phase(self.m.rig)
            self.m.rig.run(1)
            self._after(before)

    @rule(name=st.sampled_from(["START", "ABORT", "RESUME"]))
    def command(self, name: str) -> None:
        before = phase(self.m.rig)
        answered = self.m.rig.exe.commands.dispatched
        r = self.m.rig.command(f"mission.{name}")
        assert self.m.rig.exe.commands.dispatched == answered + 1
        allowed = {
            "START": before in ("IDLE", "DONE"),
            "ABORT": before not in ("IDLE", "DONE", "SAFE"),
            "RESUME": before == "SAFE",
        }[name]
        assert r.status.name == ("OK" if allowed else "EXECUTION_ERROR"), (name, before, r)
        if not allowed:
            assert phase(self.m.rig) == before
        elif name == "ABORT":
            assert phase(self.m.rig) == "SAFE"
        self._after(before)

    @rule(frames=st.integers(1, 3))
    def run(self, frames: int) -> None:
        self._frames(frames)

    @rule()
    def wait_past_the_step_timeout(self) -> None:
        self._frames(int(STEP_TIMEOUT_S / CFG.executive.frame_period_s) + 2)

    def _reply(self, outcome: str) -> None:
        assert self.waiting is not None
        rid, kind = self.waiting
        self.m.motion_reply(rid, kind, outcome)
        before = phase(self.m.rig)
        self._frames(1)
        if outcome != "done" and before in ("MOVE", "POINT"):
            assert phase(self.m.rig) == "SAFE"

    @precondition(lambda self: self.waiting is not None)
    @rule()
    def motion_done(self) -> None:
        self._reply("done")

    @precondition(lambda self: self.waiting is not None)
    @rule(outcome=st.sampled_from(["aborted", "refused"]))
    def motion_failed(self, outcome: str) -> None:
        self._reply(outcome)

    @rule(data=st.data(), outcome=st.sampled_from(["done", "aborted"]))
    def late_motion_reply(self, data: st.DataObject, outcome: str) -> None:
        """A late answer to an earlier request (the motion task answers a move that SAFE's stop
        aborted): never taken for the one awaited."""
        rid = data.draw(st.integers(0, self.m.rig.task("mission").request_id))
        if self.waiting is not None and rid == self.waiting[0]:
            return
        before = phase(self.m.rig)
        self.m.motion_reply(rid, "goto", outcome)
        self._frames(1)
        if before in ("MOVE", "POINT") and phase(self.m.rig) != before:
            # not the awaited request: ignored. The only way out of the phase in this frame is
            # the step timeout of the move still awaited (it may fall in this very frame).
            mission = self.m.rig.task("mission")
            assert phase(self.m.rig) == "SAFE" and mission.safe.reason.endswith("move timed out"), \
                (before, mission.safe.reason)

    @rule(data=st.data())
    def map_update(self, data: st.DataObject) -> None:
        view = data.draw(st.sampled_from(self.pending_views or [0, 1, 2]))
        self.m.map_update(view)
        self._frames(1)

    @rule(kind=st.sampled_from(["none", "here", "away"]))
    def nbv_reply(self, kind: str) -> None:
        here = self.m.pose
        view = {
            "none": None,
            "here": CandidateView(here, (0.3, -0.5, 0.4), 50.0, 5.0, 0.5, 0.0, 45.0, "5"),
            "away": CandidateView((here[0] + 0.4, here[1], 0.0), (0.0, -0.5, 0.4), 50.0, 5.0, 2.0, 0.0, 40.0, "5"),
        }[kind]
        self.m.rig.publish(NBV_RESULT, view)
        self._frames(1)

    @invariant()
    def sane(self) -> None:
        mission = self.m.rig.task("mission")
        assert mission.exceptions == 0, self.m.rig.events("mission.EXCEPTION")
        assert phase(self.m.rig) in ("IDLE", "INIT", "SELECT", "MOVE", "POINT", "ACQUIRE", "TRANSMIT", "DONE", "SAFE")
        assert mission.safe.entries == len(self.m.rig.events("mission.SAFE"))


def test_a_late_reply_is_ignored_and_the_awaited_move_still_times_out() -> None:
    """The case a random run once found: in POINT, a late answer to an earlier request
    arrives in the frame in which the awaited mast move's step timeout passes. The late
    answer is ignored (the phase stays POINT up to the deadline) and the timeout, not the
    late answer, puts the mission in SAFE."""
    m = Mission()
    m.nav()
    m.rig.command("mission.START")
    m.rig.run_until(lambda: phase(m.rig) == "POINT", 30)
    (req,) = m.moves.drain()
    mission = m.rig.task("mission")
    m.rig.run_until(lambda: m.rig.exe.clock.now() > mission.deadline - 0.15, 40)
    m.motion_reply(req.request_id - 1, "goto", "aborted")  # a stale reply to a request not awaited
    m.rig.run(1)
    assert phase(m.rig) == "POINT"
    m.motion_reply(req.request_id - 1, "goto", "aborted")
    m.rig.run(2)
    assert phase(m.rig) == "SAFE" and mission.safe.reason == "mast move timed out"


MissionMachine.TestCase.settings = settings(
    max_examples=60, stateful_step_count=40, deadline=None, suppress_health_check=[HealthCheck.too_slow],
    derandomize=True,  # the same programs every run (CI is deterministic, as the lockstep bench is)
)
TestMissionSequencer = MissionMachine.TestCase


def test_a_map_update_with_a_pose_fix_waits_for_the_pose_to_hold_it() -> None:
    """The last panorama view brought a navigation fix: the mission plans the next step only
    once nav.pose says the motion task took it (fix_seen), so it plans from the corrected pose;
    if the pose never shows it, it goes on after FIX_WAIT_S."""
    for pose_takes_it in (True, False):
        m = Mission()
        m.rig.command("mission.START")
        m.nav()
        for k in range(2):
            m.view()
            if k == 0:
                m.map_update(0)
        fix = NavFix.from_correction(1, 0.0, np.zeros(3), np.r_[0.0, 0.0, 0.01, 0.05, 0.0, 0.0], np.eye(6) * 1e-6)
        up = MapUpdate(0, m.rig.clock.now(), 101, 10, 1000, 0, 5.0, ElevationMap(GRID), nav_fix=fix)
        m.rig.publish(MAP_UPDATED, up)
        m.rig.run(3)
        assert phase(m.rig) == "ACQUIRE" and not m.plans.drain()  # held: the pose has not taken it
        if pose_takes_it:
            m.rig.publish(NAV_POSE, NavPose(m.rig.clock.now(), 0.05, 0.0, 0.01, np.eye(3) * 1e-6,
                                            (0.0, 0.0, 0.0), fix_id=1, fix_seen=1))
            m.rig.run(1)
        else:
            m.rig.run(int(FIX_WAIT_S / CFG.executive.frame_period_s) + 1)
        plans = m.plans.drain()
        assert phase(m.rig) == "SELECT" and len(plans) == 1
        assert plans[0].rover[0] == pytest.approx(0.05 if pose_takes_it else 0.0)
