"""The mission sequencer (paper Figure 4; docs/algorithm.md §2-§4, §6).

    INIT -> PANORAMA -> [SELECT -> MOVE -> POINT -> ACQUIRE] until the end criterion (§3.6)
         -> TRANSMIT -> DONE;   any state -> SAFE on a driver fault or a geofence refusal;
         TRANSMIT -> SAFE when the map was not delivered (link failed, rejected, timeout).

Each view is a sequence of requests to the other tasks over the software bus: the motion
task drives to the rover pose (``goto``), then points the mast; the camera task takes the
pair; the perception task merges it and re-fits the edge; the next-view task rates the
candidates on the new map. A map update whose view corrected the rover pose (a navigation fix,
``fsw.core.localization.nav_fix``) is acted on once ``nav.pose`` shows the motion task took it (or after
``FIX_WAIT_S``), so the next step is planned from where the map says the rover stands.
Before any wheel move the geofence checks the swept footprint against the polygon edge
(§2): a refusal is an event, never a crossing, and the step's view is taken from where the
rover stands (``fsw.tasks.mission_ground``). A move over ground the map has not measured
(``fsw.core.edge.known_ground``) is not taken blind: the step first looks at that ground from
where the rover stands (``fsw.core.edge.look``, part of the same step; again while a look still
maps some of it, up to ``max_looks_per_move``); a move still refused is driven part of the
way the geofence allows (along the drive, or straight ahead or behind). A fitted edge that
hems the rover in where it stands makes the next step a look at the ground nearest it.
Step 0 is the panorama from the start pose (the same for every method); steps 1..N are the
planner's. Each step is recorded (``records``) for the run summary.

SAFE (``fsw.tasks.mission_safe``): wheels and mast stopped, mast parked, an event; then wait
for ``RESUME``, or with ``safe_recover_s`` > 0 clear the latched driver faults and resume by
itself after that long; a fault still there after ``safe_max_recoveries`` tries in a row
ends the mission in SAFE with its reason.

Checkpoints (``fsw.tasks.mission_checkpoint``): when a step completes, and on entering SAFE
or DONE, the map of the step and the mission state go to the map store as one snapshot; at
start-up a mission found there continues at the next step (or stays SAFE/DONE).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections import deque
from typing import ClassVar

from fsw.comm.mavlink_plan import ground_plan
from fsw.core.edge.edge import EdgeModel
from fsw.core.planning.nbv import end_reason
from fsw.core.planning.view_candidates import CandidateView
from fsw.framework.commands import CommandDef, CommandError
from fsw.framework.storage import describe
from fsw.framework.telemetry import Channel, EventDef, Severity
from fsw.sections import MissionConfig
from fsw.tasks import mission_checkpoint
from fsw.tasks.base import FlightTask
from fsw.tasks.messages import (
    CAMERA_REQUEST,
    MAP_UPDATED,
    MISSION_GROUND,
    MOTION_REQUEST,
    MOTION_STATUS,
    NAV_POSE,
    NBV_REQUEST,
    NBV_RESULT,
    RADIO_STATUS,
    VIEW_FAILED,
    CaptureRequest,
    MapUpdate,
    MotionRequest,
    MotionStatus,
    MoveOutcome,
    NavPose,
)
from fsw.tasks.mission_ground import MIN_MOVE_M, MIN_TURN_RAD, MissionGround, Pose3
from fsw.tasks.mission_safe import SafeMode
from fsw.tasks.mission_state import STATES, LatestSection, MissionPhase, MissionSection, StateError, StepRecord
from fsw.tasks.mission_transmit import MapDelivery

FIX_WAIT_S = 1.0  # longest wait for nav.pose to show a map update's navigation fix


class MissionTask(FlightTask):
    KIND: ClassVar[str] = "mission"
    RATE_HZ: ClassVar[tuple[float, float]] = (5.0, 50.0)  # its timeouts and moves assume ~10 Hz
    REQUIRES: ClassVar[tuple[str, ...]] = ("motion", "camera", "perception", "nbv", "health")

    @classmethod
    def required_kinds(cls, cfg: object) -> tuple[str, ...]:  # cfg: the FswConfig (not imported here)
        # a map sent to the Cliff-bot brings its fix requests: the fixer answers them (docs/team.md)
        return cls.REQUIRES + (("radio", "cliffbot_fixer") if getattr(cfg, "mission").transmit else ())  # noqa: B009
    DOC: ClassVar[str] = "Mission sequencer: panorama, next view, move, acquire, transmit; SAFE on faults."
    CHANNELS = (
        Channel("state", doc=", ".join(STATES)),
        Channel("state_code", "", doc="index of the state in the list above"),
        Channel("step", "count", doc="imaging steps done"),
        Channel("mapped_cells", "cells"),
        Channel("edge_violations", "count", hi=0, doc="moves refused by the geofence"),
        Channel("safe_entries", "count", hi=0),
    )
    EVENTS = (
        EventDef("STATE", Severity.ACTIVITY_HI, "mission {old} -> {new}"),
        EventDef("STEP", Severity.ACTIVITY_HI, "step {step}: {mapped} cells mapped (+{new}, expected {exp:.0f})"),
        EventDef("END", Severity.ACTIVITY_HI, "mapping ends: {reason}"),
        EventDef("GEOFENCE", Severity.WARNING_HI, "move to ({x:.2f}, {y:.2f}) refused: {reason}; view taken from here"),
        EventDef("LOOK", Severity.ACTIVITY_LO, "look at {n} unknown cells toward ({x:.2f}, {y:.2f})"),
        EventDef("SAFE", Severity.WARNING_HI, "SAFE mode: {reason}"),
        EventDef("RECOVERING", Severity.ACTIVITY_HI, "SAFE recovery {n} of {max}: clear faults, resume ({reason})"),
        EventDef("RECOVERED", Severity.ACTIVITY_HI, "left SAFE at step {step} ({reason})"),
        EventDef("RECOVERY_FAILED", Severity.WARNING_HI, "SAFE recovery failed: {reason}"),
        EventDef("SAFE_FINAL", Severity.WARNING_HI, "mission stays in SAFE: {reason}"),
        EventDef("RETRY", Severity.WARNING_LO, "{what} failed ({reason}); retry {n}", throttle=5),
        EventDef("TRANSMITTED", Severity.ACTIVITY_HI, "map transmission ended: {state}"),
        EventDef("UNDELIVERED", Severity.WARNING_HI, "map not delivered ({state}); the mission does not end DONE"),
        EventDef("CHECKPOINT_SAVED", Severity.ACTIVITY_LO, "step {step} checkpoint {seq} saved ({kib:.0f} KiB)"),
        EventDef("CHECKPOINT_FAILED", Severity.WARNING_HI, "mission checkpoint failed: {error}", throttle=3),
        EventDef("RESUMED", Severity.ACTIVITY_HI, "mission resumed from checkpoint {seq}: step {step}, {phase}"),
        EventDef("RESUME_REFUSED", Severity.WARNING_HI, "checkpoint not resumed ({reason}); waiting for START"),
    )
    COMMANDS = (
        CommandDef("START", doc="start the mission (from IDLE or DONE)"),
        CommandDef("ABORT", doc="stop mapping, enter SAFE"),
        CommandDef("RESUME", doc="leave SAFE and continue where the mission stood"),
    )

    def setup(self) -> None:
        cfg = self.ctx.cfg
        self.mcfg: MissionConfig = cfg.mission
        self.nav_box = self.subscribe(NAV_POSE, depth=1)
        self.status_box = self.subscribe(MOTION_STATUS, depth=8)
        self.map_box = self.subscribe(MAP_UPDATED, depth=4)
        self.maps: deque[tuple[float, MapUpdate]] = deque()  # (arrival, update) held for their nav fix
        self.nbv_box = self.subscribe(NBV_RESULT, depth=2)
        self.radio_box = self.subscribe(RADIO_STATUS, depth=4)
        self.failed_box = self.subscribe(VIEW_FAILED, depth=4)  # a view that will not reach the map
        self.nav: NavPose | None = None
        self.state = MissionPhase.IDLE
        self.records: list[StepRecord] = []
        self.step = 0
        self.view: CandidateView | None = None
        self.pending: list[CandidateView] = []
        self.latest: MapUpdate | None = None
        self.edge: EdgeModel | None = None
        self._stations: list[tuple[float, float, float]] = []  # for the ground (MISSION protocol)
        self.request_id = 0
        self.waiting_for: int | None = None
        self.deadline = math.inf
        self.retries = 0
        self.end: str | None = None
        self.t_wall0 = time.perf_counter()
        self._share_ground = False  # a resumed mission: mission.ground goes out again in its first activation
        self.ground = MissionGround(cfg, self)  # geofence, looks, stays (fsw.tasks.mission_ground)
        self.safe = SafeMode(self.mcfg, self)  # SAFE and its recovery (fsw.tasks.mission_safe)
        self.delivery = MapDelivery(self.mcfg, self)  # TRANSMIT (fsw.tasks.mission_transmit)
        self._auto_start = self.mcfg.auto_start
        self._republish: MapUpdate | None = None
        self._resume()

    # -- plumbing (also what SAFE and the ground-awareness use: SafeHost, GroundHost) ------------
    def now(self) -> float:
        return self.ctx.clock.now()

    def goto(self, new: MissionPhase) -> None:
        self.ground.cancel_job()  # geofence work ends with the phase it began in
        if new != self.state:
            self.event("STATE", old=str(self.state), new=str(new))
            self.state = new
            self.publish(MISSION_GROUND, self.ground.shared())  # for another task's wheel move (the fixer's)
        self.tlm("state", str(new))
        self.tlm("state_code", STATES.index(new))

    def request(
        self,
        kind: str,
        target: tuple[float, float, float] | None = None,
        joints: tuple[float, float, float] | None = None,
    ) -> None:
        self.request_id += 1
        self.waiting_for = self.request_id
        self.deadline = self.ctx.clock.now() + self.mcfg.step_timeout_s
        self.publish(MOTION_REQUEST, MotionRequest(self.request_id, kind, target=target, joints=joints))

    def motion_outcome(self) -> MotionStatus | None:
        for st in self.status_box.drain():
            if st.request_id == self.waiting_for:
                self.waiting_for = None
                return st
        return None

    def _nav_took_fix(self, arrived: float, up: MapUpdate, now: float) -> bool:
        fix = up.nav_fix
        return (fix is None or (self.nav is not None and self.nav.fix_seen >= fix.fix_id)
                or now - arrived >= FIX_WAIT_S)

    def timed_out(self) -> bool:
        return self.ctx.clock.now() > self.deadline

    def forget_request(self) -> None:
        self.waiting_for = None

    def set_deadline(self, t: float) -> None:
        self.deadline = t

    # -- checkpoints (fsw.tasks.mission_checkpoint) -----------------------------------------------
    def checkpoint(self, phase: MissionPhase) -> None:
        """Checkpoint the map of the last merged step with the mission state (events either way)."""
        store = self.ctx.res.map_store
        if store is None or self.latest is None:
            return
        try:
            state = mission_checkpoint.full_state(self.ctx, self.name, self.section(phase))
            store.save_next(self.latest.snapshot, self.ctx.clock.now(), state)
        except OSError as exc:  # a full or failing device: the newest good checkpoint stays, the mission goes on
            self.event("CHECKPOINT_FAILED", error=describe(exc))
            return
        except (ValueError, TypeError) as exc:
            self.event("CHECKPOINT_FAILED", error=f"{type(exc).__name__}: {exc}")
            return
        self.event("CHECKPOINT_SAVED", step=self.step, seq=store.seq, kib=store.last_size / 1024)

    def section(self, phase: MissionPhase) -> MissionSection:
        """The mission's checkpoint section in ``phase``."""
        g = self.ground
        return MissionSection(
            phase=phase, step=self.step, records=list(self.records), request_id=self.request_id,
            edge_violations=g.edge_violations, safe_entries=self.safe.entries, end=self.end,
            safe_reason=self.safe.reason, edge=self.edge, nav=self.nav,
            latest=None if self.latest is None else LatestSection.of(self.latest),
            looks=g.looks, stays=list(g.stays), looked=g.looked, looked_from=g.looked_from,
            look_n=g.look_n, look_left=g.look_left, stood_on=g.stood_on_wkb(),
        )

    def _resume(self) -> None:
        """Continue the mission of the start-up checkpoint, if there is one: the phase entered, or
        an event saying why it was not used (the mission then waits for START)."""
        try:
            loaded = mission_checkpoint.load(self.ctx)
        except StateError as exc:
            self._auto_start = False
            self.event("RESUME_REFUSED", reason=str(exc))
            return
        if loaded is None:
            return
        s, g = loaded.section, self.ground
        self.step, self.request_id, self.records, self.edge, self.nav = s.step, s.request_id, s.records, s.edge, s.nav
        self.latest, self.end = loaded.latest, s.end
        g.edge_violations, self.safe.entries, self.safe.reason = s.edge_violations, s.safe_entries, s.safe_reason
        g.looks, g.stays = s.looks, list(s.stays)
        g.looked, g.looked_from, g.look_n, g.look_left = s.looked, s.looked_from, s.look_n, s.look_left
        g.set_stood_on(loaded.stood_on)
        self.event("RESUMED", step=self.step, seq=loaded.seq, phase=str(s.phase))
        self._auto_start = False
        self._republish = self.latest
        self._share_ground = True
        self.goto(s.phase)
        if s.phase is MissionPhase.SELECT:
            self.next_view()  # the next-view request goes out in the frame it did before the stop
        elif s.phase is MissionPhase.SAFE:
            self.safe.since = self.ctx.clock.now()

    def enter_safe(self, reason: str) -> None:
        self.safe.enter(reason)

    def continue_mission(self) -> None:
        """Leave SAFE where the mission stood (or from the panorama if nothing is mapped)."""
        self.pending.clear()
        if self.latest is None:  # nothing mapped yet: start again with the panorama
            self.goto(MissionPhase.INIT)
            return
        self.goto(MissionPhase.SELECT)
        self.next_view()

    def drive(self, target: Pose3, view: CandidateView) -> None:
        self.view = view
        self.goto(MissionPhase.MOVE)
        self.request(kind="goto", target=target)

    def point(self, view: CandidateView) -> None:
        self.view = view
        self._start_point()

    def look_first(self, look: CandidateView) -> None:
        assert self.view is not None
        self.pending.insert(0, self.view)
        self.point(look)

    # -- the cycle ------------------------------------------------------------------------------
    def run(self, frame: int) -> None:
        if self._auto_start:
            self._auto_start = False
            self.goto(MissionPhase.INIT)
        if self._republish is not None:  # a resumed mission's map, for the radio task
            self.publish(MAP_UPDATED, self._republish)
            self._republish = None
        if self._share_ground:  # (published in set-up, before every task had subscribed)
            self._share_ground = False
            self.publish(MISSION_GROUND, self.ground.shared())
        self.nav = self.nav_box.latest() or self.nav
        now = self.ctx.clock.now()
        self.maps.extend((now, up) for up in self.map_box.drain())
        if self.ground.job_pending():  # geofence work runs as a slack job (fsw.tasks.mission_ground)
            return
        while self.maps and self._nav_took_fix(*self.maps[0], now):
            self._on_map(self.maps.popleft()[1])
        handler = getattr(self, f"_state_{self.state.lower()}")
        handler()
        self.tlm("step", self.step)
        self.tlm("edge_violations", self.ground.edge_violations)
        self.tlm("safe_entries", self.safe.entries)
        if self.latest is not None:
            self.tlm("mapped_cells", self.latest.mapped_cells)

    def _state_idle(self) -> None:
        pass

    def _state_done(self) -> None:
        pass

    def _state_init(self) -> None:
        if self.nav is None:
            return  # wait for the first pose estimate
        m = self.mcfg
        rover = (self.nav.x, self.nav.y, self.nav.yaw)
        views = [(p, m.panorama_tilt_deg) for p in m.panorama_pans_deg]
        views += [(p, m.near_tilt_deg) for p in m.near_pans_deg]  # the ground it turns on
        self.pending = [
            CandidateView(rover, (math.radians(p), math.radians(t), m.panorama_lift_m), method="panorama")
            for p, t in views
        ]
        self.step = 0
        self.next_view()

    def _state_safe(self) -> None:
        self.safe.run()

    def next_view(self) -> None:
        """Take the next pending view (panorama), or ask the planner for one."""
        if self.pending:
            self.view = self.pending.pop(0)
            self._start_move()
            return
        reason = self._end_reason()
        if reason is not None:
            self._finish_mapping(reason)
            return
        look = self.ground.look_around()
        if look is not None:  # the fitted edge hems the rover in: look at the ground first
            self.point(look)
            return
        self.goto(MissionPhase.SELECT)
        self.publish(NBV_REQUEST, self.ground.planner_state())
        self.deadline = self.ctx.clock.now() + self.mcfg.step_timeout_s

    def _state_select(self) -> None:
        if len(self.nbv_box) == 0:
            if self.timed_out():
                self.enter_safe("next-view search timed out")
            return
        view: CandidateView | None = self.nbv_box.get()
        if view is None:
            self._finish_mapping("no reachable view worth taking")
            return
        self.view = view
        self._start_move()

    def _start_move(self) -> None:
        assert self.view is not None and self.nav is not None
        here = (self.nav.x, self.nav.y, self.nav.yaw)
        there = self.view.rover
        dyaw = math.remainder(there[2] - here[2], math.tau)
        if math.hypot(there[0] - here[0], there[1] - here[1]) < MIN_MOVE_M and abs(dyaw) < MIN_TURN_RAD:
            # Not worth a move (a goto turns toward its target first: a few cm sideways would
            # be a quarter turn): the view from here, the mast turned to look the same way.
            # It is the rated view within a few cm and degrees: it keeps its rating (§3.5).
            pan, tilt, lift = self.view.joints
            if self.view.note:  # the planner found no move at all: why, in the mission summary
                self.ground.stays.append(f"step {self.step}: {self.view.note}")
            self.view = dataclasses.replace(self.view, rover=here,
                                            joints=self.ctx.cfg.mast.clamp(pan + dyaw, tilt, lift))
            self._start_point()
            return
        self._stations.append((float(there[0]), float(there[1]), float(there[2])))
        self.publish(self.ctx.cfg.mavlink.plan_topic, ground_plan(self._stations, self.edge, self.ctx.cfg.geofence))
        self.ground.start_move(here, there)

    def _state_move(self) -> None:
        st = self.motion_outcome()
        if st is None:
            if self.timed_out():
                self.enter_safe("rover move timed out")
            return
        if st.state != MoveOutcome.DONE:
            self.enter_safe(f"rover move {st.state}: {st.reason}")
            return
        self._start_point()

    def _start_point(self) -> None:
        assert self.view is not None
        self.goto(MissionPhase.POINT)
        self.request(kind="mast", joints=self.view.joints)

    def _state_point(self) -> None:
        st = self.motion_outcome()
        if st is None:
            if self.timed_out():
                self.enter_safe("mast move timed out")
            return
        if st.state != MoveOutcome.DONE:
            self.enter_safe(f"mast move {st.state}: {st.reason}")
            return
        self._capture()

    def _capture(self) -> None:
        assert self.view is not None
        self.goto(MissionPhase.ACQUIRE)
        self.deadline = self.ctx.clock.now() + self.mcfg.step_timeout_s
        self.failed_box.drain()  # failures of earlier attempts are answered by this one
        self.publish(CAMERA_REQUEST, CaptureRequest(self.step, self.view.expected_new_cells))

    def _state_acquire(self) -> None:
        """Wait for the view's map update (``_on_map``); retry a view that failed (camera,
        perception) at once, and one that never arrived after the step timeout."""
        failed = [f for f in self.failed_box.drain() if f.view_id == self.step]
        if failed or self.timed_out():
            reason = failed[-1].reason if failed else "no merged pair"
            if self.retries < self.mcfg.capture_retries:
                self.retries += 1
                self.event("RETRY", what=f"view {self.step}", reason=reason, n=self.retries)
                self._capture()
            else:
                self.enter_safe(f"no stereo pair after retries ({reason})")

    def _on_map(self, up: MapUpdate) -> None:
        self.latest = up
        if up.edge is not None and not up.edge.empty:
            self.edge = up.edge
        if self.state != MissionPhase.ACQUIRE or up.view_id != self.step:
            return
        self.retries = 0
        assert self.view is not None
        # New cells of the step: against the map at the end of the previous step (the panorama
        # views all belong to step 0, which replaces its record as each view lands).
        base = next((r.mapped_cells for r in reversed(self.records) if r.step < self.step), 0)
        rover, joints = self.view.rover, self.view.joints
        rec = StepRecord(
            step=self.step,
            mapped_cells=up.mapped_cells,
            expected_new_cells=float(self.view.expected_new_cells),
            obtained_new_cells=up.mapped_cells - base,
            view=self.view.method,
            # what the view's prediction is about: its own new cells, not a look's before it in the step
            view_new_cells=up.mapped_cells - (self.records[-1].mapped_cells if self.records else 0),
            pose=dict(zip(("x", "y", "yaw", "pan", "tilt", "lift"), (*rover, *joints), strict=True)),
            wall_s=time.perf_counter() - self.t_wall0,
            sim_s=self.ctx.clock.now(),
        )
        if self.records and self.records[-1].step == self.step:
            self.records[-1] = rec
        else:
            self.records.append(rec)
        if not self.pending:  # the step is complete (the panorama's only after its last view)
            self.event(
                "STEP", step=self.step, mapped=up.mapped_cells, new=rec.obtained_new_cells, exp=rec.expected_new_cells
            )
            self.step += 1
            self.checkpoint(MissionPhase.SELECT)  # the step's map and state, one snapshot
        self.next_view()

    def _end_reason(self) -> str | None:
        """§3.6: the step limit, or the region of interest mapped (estimated by perception)."""
        if self.latest is None:
            return "no map"
        fraction = self.latest.roi_mapped_fraction
        return end_reason(self.step - 1, None, fraction, self.ctx.cfg.nbv)

    # -- the end -------------------------------------------------------------------------------
    def _finish_mapping(self, reason: str) -> None:
        self.end = reason
        self.event("END", reason=reason)
        if self.mcfg.transmit and "radio" in self.ctx.runtime.tasks:
            self.delivery.begin()  # fsw.tasks.mission_transmit
        else:
            self.goto(MissionPhase.DONE)
            self.checkpoint(MissionPhase.DONE)

    def _state_transmit(self) -> None:
        self.delivery.run(self.radio_box.drain())

    def cmd_RESUME(self) -> None:
        if self.state != MissionPhase.SAFE:
            raise CommandError("not in SAFE")
        self.safe.operator_resume()

    def cmd_START(self) -> None:
        if self.state not in (MissionPhase.IDLE, MissionPhase.DONE):
            raise CommandError(f"mission already running ({self.state})")
        self.goto(MissionPhase.INIT)

    def cmd_ABORT(self) -> None:
        if self.state in (MissionPhase.IDLE, MissionPhase.DONE, MissionPhase.SAFE):
            raise CommandError(f"nothing to abort ({self.state})")
        self.enter_safe("aborted by command")
