"""The Cliff-bot's mission task: the sans-I/O mission on the executive.

Thin (docs/architecture.md, tasks): every activation it hands the sans-I/O
:class:`~fsw.tasks.cliffbot_mission.CliffbotMission` the map the radio received, the
navigation's estimate and its verdicts on the RECON-bot's fixes (``cb_nav``,
:mod:`fsw.tasks.cliffbot.navigation`), the RECON-bot's NO_FIX answers and the devices'
statuses, steps it, publishes its device commands, its fix requests, the map it plans on
(for the navigation) and the estimate the navigation is to take after a recovery or a
checkpoint, and turns what it recorded into events (``TARGET_UNREACHABLE`` with the
planner's reason, ``SAFE`` with the reason, ...) and telemetry (state, leg, targets reached;
the estimate and its sigma are the navigation's channels, ``cb_nav``).

SAFE is the mission's (winches braked, wheels stopped; docs/team.md): the task reports it
(``SAFE``, ``safe_reason``), checkpoints, and leaves it on the ground's ``RECOVER`` (or by
itself after ``[cliffbot_mission] safe_recover_s`` when that is not 0).

Checkpoints (:mod:`fsw.tasks.cliffbot.checkpoint`): the mission state, the navigation
estimate and the received map, written in ``[checkpoint] directory`` at every change of state;
on start-up the task continues from a checkpoint there (``RESUMED``), its leg asking for a fix
first.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from fsw.comm.team.fix_packets import Fix
from fsw.core.geometry import MapGrid
from fsw.framework.commands import Arg, CommandDef
from fsw.framework.telemetry import Channel, EventDef, Severity
from fsw.tasks.base import FlightTask
from fsw.tasks.cliffbot import checkpoint
from fsw.tasks.cliffbot.messages import (
    CB_COMMANDS,
    CB_FIX,
    CB_FIX_REQUEST,
    CB_MAP,
    CB_NAV,
    CB_NAV_RESET,
    CB_PLAN_MAP,
    CB_SENSE,
    CB_SENSED_MAP,
    CB_STATUS,
    DeviceStatus,
    NavEstimate,
    NavReset,
    PlanMap,
    SenseRequest,
)
from fsw.tasks.cliffbot_mission import CliffbotMission, fix_request

A, I, W = Severity.ACTIVITY_HI, Severity.ACTIVITY_LO, Severity.WARNING_HI
# the sans-I/O mission's events, as this task's (name -> severity)
MISSION_EVENTS = {
    "MAP": I, "PLAN": A, "FIX_REQUEST": I, "FIX": I, "FIX_REFUSED": W, "FIX_UNAVAILABLE": Severity.WARNING_LO,
    "TARGET_UNREACHABLE": Severity.WARNING_LO, "TARGET_REACHED": A, "HOME": A, "DONE": A, "WINCH_FAULT": W,
    "LINK_LOST": W, "SAFE": W, "RECOVER": A, "TARGETS_REFUSED": Severity.WARNING_LO,
    "SENSE_REQUEST": I, "SENSED": I, "SENSE_TIMEOUT": Severity.WARNING_LO, "OFF_THE_WAY": Severity.WARNING_LO,
    "APPROACH": A, "LOOK": I, "EXPLORE": A, "RETRACE": Severity.WARNING_LO, "TENSION_GUARD": W,
}
RENAMED = {"COMMAND_REFUSED": "TARGETS_REFUSED"}  # the framework's own COMMAND_REFUSED is another event


class CliffbotMissionTask(FlightTask):
    KIND: ClassVar[str] = "cliffbot_mission"
    RATE_HZ: ClassVar[tuple[float, float]] = (5.0, 50.0)  # winch pacing and timeouts assume ~10 Hz
    REQUIRES: ClassVar[tuple[str, ...]] = ("cliffbot_devices", "cliffbot_radio", "cliffbot_nav", "health")
    DOC: ClassVar[str] = "Cliff-bot mission: plan on the received map, drive the tethers to each target and home."

    @classmethod
    def required_kinds(cls, cfg: object) -> tuple[str, ...]:  # cfg: the FswConfig
        """With ``[cliffbot_sensing] enabled`` its views come from the sensing task."""
        on = bool(getattr(getattr(cfg, "cliffbot_sensing", None), "enabled", False))
        return (*cls.REQUIRES, "cliffbot_sensing") if on else cls.REQUIRES
    CHANNELS = (
        Channel("state", doc="WAIT_MAP, SENSE, PLAN, WAIT_FIX, DRIVE, DWELL, DONE, SAFE"),
        Channel("leg", "count"),
        Channel("targets_reached", "count"),
        Channel("safe_reason"),
    )
    EVENTS = (
        *(EventDef(name, sev, "{text}") for name, sev in MISSION_EVENTS.items()),
        EventDef("STATE", A, "mission {old} -> {new}"),  # each change of mode (the HEARTBEAT's, docs/ground.md)
        EventDef("RESUMED", A, "continued from checkpoint in {state}: {text}"),
        EventDef("CHECKPOINT_REFUSED", Severity.WARNING_LO, "checkpoint not used: {error}"),
        EventDef("CHECKPOINT_FAILED", Severity.WARNING_LO, "checkpoint not written: {error}", throttle=5),
    )
    COMMANDS = (
        CommandDef("RECOVER", doc="leave SAFE: clear the winches' faults, re-plan the leg from the estimate"),
        CommandDef("REQUEST_FIX", doc="ask the RECON-bot for a fiducial fix now (on a leg or at a target)"),
        CommandDef("SET_TARGETS", (Arg("targets", str),),
                   doc="new science targets 'x1,y1;x2,y2;...' (m, map frame), planned from where the Cliff-bot is"),
    )

    def setup(self) -> None:
        cfg = self.ctx.cfg
        site = cfg.cliffbot_site
        anchors = np.array([site.anchor_a_xyz, site.anchor_b_xyz], float)
        targets = np.asarray(site.targets_xy, float).reshape(-1, 2)
        self.mission = CliffbotMission(cfg.cliffbot_mission, cfg.tether, cfg.climber, cfg.cliffbot_nav, anchors,
                                       np.asarray(site.start_xy, float), math.radians(site.start_yaw_deg), targets,
                                       sensing=cfg.cliffbot_sensing)
        self.grid = MapGrid.from_config(cfg.map)
        self.status = self.subscribe(CB_STATUS, depth=1)
        # with its own views, the sensing task hands it the received map with its own cells
        self.sensing = self.mission.sensing is not None
        self.maps = self.subscribe(CB_SENSED_MAP if self.sensing else CB_MAP, depth=2)
        self.fixes = self.subscribe(CB_FIX, depth=4)
        self.nav = self.subscribe(CB_NAV, depth=8)
        self._map_sent = 0
        self.resets = 0  # estimates handed to the navigation; its estimates before the last are stale
        self.store = checkpoint.CheckpointFile(cfg.checkpoint.directory)
        self._emitted = 0
        self._saved_key: tuple[object, ...] | None = None
        self._safe_since: float | None = None
        self._restore()
        self._state = self.mission.state

    # -- commands ------------------------------------------------------------------------------
    def cmd_RECOVER(self) -> None:
        self.mission.recover()

    def cmd_REQUEST_FIX(self) -> None:
        self.mission.request_fix()

    def cmd_SET_TARGETS(self, targets: str) -> None:
        try:
            pairs = [tuple(float(v) for v in p.split(",")) for p in targets.split(";") if p.strip()]
            if any(len(p) != 2 for p in pairs):
                raise ValueError("each target is 'x,y'")
        except ValueError as exc:
            self.mission.event("COMMAND_REFUSED", f"targets {targets!r}: {exc}")
            return
        self.mission.set_targets(np.asarray(pairs, float).reshape(-1, 2))

    # -- the work ------------------------------------------------------------------------------
    def run(self, frame: int) -> None:
        now = self.ctx.clock.now()
        m = self.mission
        m.now = now
        for est in self.nav.drain():
            self._estimate(est)
        for got in self.maps.drain():
            m.set_map(got.z, self.grid, got.error_bound_m)
            if self.sensing:
                m.sensed(got.sense_seq)
        if m.z is not None and m.map_version != self._map_sent:  # a new map, or a checkpoint's
            self._map_sent = m.map_version
            self.publish(CB_PLAN_MAP, PlanMap(m.map_version, m.z, m.carried, m.error_bound_m))
        for ans in self.fixes.drain():
            if not isinstance(ans.answer, Fix):
                m.on_no_fix(ans.answer.seq, ans.reason)
        self._reset_nav()
        st: DeviceStatus | None = self.status.latest()
        if st is not None:
            cmd = m.step(now, st.devices)
            self.publish(CB_COMMANDS, cmd)
            if cmd.sense:
                self.publish(CB_SENSE, SenseRequest(m.sense_seq))
            if cmd.request_fix:
                self.publish(CB_FIX_REQUEST, fix_request(m, st.devices))
        self._auto_recover(now)
        self._reset_nav()
        self._events()
        if m.state != self._state:
            self.event("STATE", old=self._state, new=m.state)
            self._state = m.state
        self._checkpoint(now)
        self._telemetry()

    def _estimate(self, est: NavEstimate) -> None:
        """The navigation's estimate and verdicts; an estimate made before the navigation took the
        last reset, or while one waits to be sent, is stale (its verdicts are not: each fix is
        judged once)."""
        if est.resets >= self.resets and self.mission.nav_reset is None:
            self.mission.on_estimate(est.s, est.P)
        for v in est.verdicts:
            self.mission.on_fix(v.fix, v.ok, v.nis)

    def _reset_nav(self) -> None:
        m = self.mission
        if m.nav_reset is not None:
            self.resets += 1
            self.publish(CB_NAV_RESET, NavReset(self.resets, m.nav_reset.s.copy(), m.nav_reset.P.copy()))
            m.nav_reset = None

    def _auto_recover(self, now: float) -> None:
        after = self.ctx.cfg.cliffbot_mission.safe_recover_s
        if self.mission.state != "SAFE":
            self._safe_since = None
            return
        self._safe_since = now if self._safe_since is None else self._safe_since
        if after > 0 and now - self._safe_since >= after:
            self.mission.recover()
            self._safe_since = None

    def _events(self) -> None:
        evs = self.mission.events
        for _, name, text in evs[self._emitted:]:
            name = RENAMED.get(name, name)
            self.event(name if name in MISSION_EVENTS else "TARGETS_REFUSED", text=text)
        self._emitted = len(evs)

    def _telemetry(self) -> None:
        m = self.mission
        self.tlm_record({"state": m.state, "leg": m.leg_i, "targets_reached": int(sum(m.reached)),
                         "safe_reason": m.safe_reason})

    # -- checkpoints ---------------------------------------------------------------------------
    def _checkpoint(self, now: float) -> None:
        m = self.mission
        key = (m.state, m.leg_i, m.map_version, tuple(m.reached), m.fixes_used)
        if key == self._saved_key or not self.store.enabled:
            return
        self._saved_key = key
        err = self.store.save(checkpoint.snapshot(m, now), m.z)
        if err:
            self.event("CHECKPOINT_FAILED", error=err)

    def _restore(self) -> None:
        if not self.store.enabled:
            return
        try:
            got = self.store.load()
        except checkpoint.CheckpointError as exc:
            self.event("CHECKPOINT_REFUSED", error=str(exc))
            return
        if got is None:
            return
        state, z = got
        try:
            text = checkpoint.restore(self.mission, state, z, self.grid)
        except checkpoint.CheckpointError as exc:
            self.event("CHECKPOINT_REFUSED", error=str(exc))
            return
        self._emitted = len(self.mission.events)
        self.event("RESUMED", state=self.mission.state, text=text)
