"""The Cliff-bot's navigation task: its EKF on the executive (docs/team.md, "The Cliff-bot's flight code").

Thin: every activation it takes the resets the mission asked for (a recovery from a refused
fix, a checkpoint's estimate), the map the mission plans on, the devices' latest statuses and
the RECON-bot's fixes into the sans-I/O :class:`~fsw.core.team.cliffbot_nav.Navigator`
(wheel odometry along the IMU's heading, the IMU heading, the tether lengths on the map, each
fix gated by its NIS), and publishes the estimate with its covariance and its verdict on each
fix (``cliffbot.nav``). It runs before the mission in the same frame. Started where a
checkpoint is, it goes on from the checkpoint's estimate.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from fsw.comm.team.fix_packets import Fix
from fsw.core.geometry import MapGrid
from fsw.core.team.cliffbot_nav import Navigator
from fsw.framework.telemetry import Channel, EventDef, Severity
from fsw.tasks.base import FlightTask
from fsw.tasks.cliffbot import checkpoint
from fsw.tasks.cliffbot.messages import (
    CB_FIX,
    CB_NAV,
    CB_NAV_RESET,
    CB_PLAN_MAP,
    CB_STATUS,
    DeviceStatus,
    FixVerdict,
    NavEstimate,
)
from fsw.tasks.cliffbot_mission import fix_xyyaw, navigate


class CliffbotNavTask(FlightTask):
    KIND: ClassVar[str] = "cliffbot_nav"
    RATE_HZ: ClassVar[tuple[float, float]] = (5.0, 50.0)  # odometry between status frames at ~10 Hz
    REQUIRES: ClassVar[tuple[str, ...]] = ("cliffbot_devices", "cliffbot_radio")
    DOC: ClassVar[str] = "Cliff-bot navigation: EKF on tether lengths, odometry, IMU heading and the RECON-bot's fixes."
    CHANNELS = (
        Channel("x_m", "m", doc="estimate"),
        Channel("y_m", "m"),
        Channel("yaw_deg", "deg"),
        Channel("sigma_m", "m", doc="position 1-sigma (largest axis)"),
        Channel("fixes_fused", "count"),
        Channel("fixes_refused", "count"),
    )
    EVENTS = (
        EventDef("NAV_RESET", Severity.ACTIVITY_LO, "estimate set to {x:.2f}, {y:.2f} m, {yaw_deg:.1f} deg"),
    )

    def setup(self) -> None:
        cfg = self.ctx.cfg
        site = cfg.cliffbot_site
        anchors = np.array([site.anchor_a_xyz, site.anchor_b_xyz], float)
        self.nav = Navigator(np.asarray(site.start_xy, float), math.radians(site.start_yaw_deg), cfg.cliffbot_nav,
                             anchors, cfg.tether, cfg.climber.footprint_m)
        self.grid = MapGrid.from_config(cfg.map)
        self.status = self.subscribe(CB_STATUS, depth=1)
        self.fixes = self.subscribe(CB_FIX, depth=4)
        self.maps = self.subscribe(CB_PLAN_MAP, depth=2)
        self.resets_in = self.subscribe(CB_NAV_RESET, depth=2)
        self.resets = 0
        self.counts = {"fixes_fused": 0, "fixes_refused": 0}
        self._last_t: float | None = None
        self._restore()

    def _restore(self) -> None:
        """A Cliff-bot restarted where a checkpoint is goes on from its estimate (the mission
        task reads the rest of it; a checkpoint it refuses leaves the start's estimate)."""
        store = checkpoint.CheckpointFile(self.ctx.cfg.checkpoint.directory)
        if not store.enabled:
            return
        try:
            got = store.load()
            if got is None:
                return
            s, p = checkpoint.nav_estimate(got[0])
        except checkpoint.CheckpointError:
            return  # (the mission says so: CHECKPOINT_REFUSED)
        self.nav.reset(s, p)
        self.event("NAV_RESET", x=float(s[0]), y=float(s[1]), yaw_deg=math.degrees(float(s[2])))

    def run(self, frame: int) -> None:
        now = self.ctx.clock.now()
        for r in self.resets_in.drain():
            self.nav.reset(r.s, r.P)
            self.resets = max(self.resets, r.seq)
            self.event("NAV_RESET", x=float(r.s[0]), y=float(r.s[1]), yaw_deg=math.degrees(float(r.s[2])))
        for m in self.maps.drain():
            self.nav.set_map(m.z, self.grid)
        st: DeviceStatus | None = self.status.latest()
        if st is not None:
            dt = self.ctx.frame_period_s if self._last_t is None else max(now - self._last_t, 1e-3)
            self._last_t = now
            navigate(self.nav, st.devices, dt, self.ctx.cfg.cliffbot_mission.wheel_radius_m)
        verdicts = []
        for ans in self.fixes.drain():
            if isinstance(ans.answer, Fix):
                ok, nis = self.nav.fix(*fix_xyyaw(ans.answer))
                self.counts["fixes_fused" if ok else "fixes_refused"] += 1
                verdicts.append(FixVerdict(ans.answer, ok, nis))
        n = self.nav.nav
        self.publish(CB_NAV, NavEstimate(now, n.s.copy(), n.P.copy(), self.resets, tuple(verdicts)))
        self.tlm_record({
            "x_m": float(n.s[0]), "y_m": float(n.s[1]), "yaw_deg": math.degrees(float(n.s[2])),
            "sigma_m": math.sqrt(max(float(np.linalg.eigvalsh(n.P[:2, :2]).max()), 0.0)), **self.counts,
        })
