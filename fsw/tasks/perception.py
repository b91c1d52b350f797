"""The perception task: owns the sensing pipeline (the elevation map); merges each stereo pair
and re-fits the edge.

A ``CameraFrame`` from the camera task becomes a slack job (docs/algorithm.md §4) that runs the
sensing pipeline (``fsw.core.pipeline``: rectification, stereo, registration, world points with
covariance, fusion with misses, the edge fit and the mapped fraction of the region of
interest), each step a slice of a few to ~20 ms so the 10 Hz foreground keeps its deadlines.
This task reads the frames, publishes the result on ``map.updated`` with a snapshot of the map
for the planner (and the navigation fix on ``nav.fix``), and reports telemetry and events. The
mission sequencer checkpoints each step's map with its state (``fsw.tasks.mission_checkpoint``);
this task also writes map-only checkpoints through the map store on command and at
``checkpoint.period_s`` when nothing was saved for that long, never while a merge is under
way (the map would be half-merged). At start-up it restores the newest good checkpoint's map.

With ``[cliffbot_site] mask_team`` (a team mission) the pipeline masks the team out of every
view (docs/algorithm.md §8.1, :func:`site_team`): the Cliff-bot standing at its surveyed start, the
two Anchorbots at their surveyed ground points and the two tethers, straight from the Anchorbots'
exits to its attachment, so no robot is mapped as terrain nor the ground just past its outline as
a step; the ground round each robot and under the tethers is kept (each one's ground is known).
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from collections.abc import Generator
from typing import ClassVar

import numpy as np

from fsw.core.map.body_mask import MaskConfig, TeamGeometry, TetherLine, anchorbot_box, standing_box
from fsw.core.map.elevation_map import ElevationMap
from fsw.core.pipeline import SensingPipeline
from fsw.core.registration.registration import RegistrationSummary
from fsw.core.stereo.rig_drift import RigAlignment
from fsw.drivers.map_store import MapStore
from fsw.framework.commands import CommandDef, CommandError
from fsw.framework.jobs import JobHandle
from fsw.framework.storage import describe
from fsw.framework.telemetry import Channel, EventDef, Severity
from fsw.settings import FswConfig, load_stereo_calibration
from fsw.tasks.base import FlightTask
from fsw.tasks.messages import (
    CAMERA_FRAME,
    FIX_VIEW_BASE,
    MAP_UPDATED,
    NAV_FIX,
    VIEW_FAILED,
    CameraFrame,
    MapUpdate,
    ViewFailed,
)
from fsw.tasks.mission_state import JsonDict, restore_into

SITE_SIGMA_M = 0.03  # the surveyed start's position error (the mask grows by sigma times it)
SITE_BELOW_M = 0.15  # the box reaches this far under the start's ground (its height is the anchors')
TETHER_RADIUS_M = 0.01
# the RECON-bot's mask: its views of the team are metres away, a point's 1 sigma is centimetres, so the
# band kept above a robot's ground is that sigma alone (docs/algorithm.md §8.1)
SITE_MASK = MaskConfig(ground_band_m=0.0)


def site_team(cfg: FswConfig) -> TeamGeometry | None:
    """The team's known geometry from ``[cliffbot_site]`` (None unless ``mask_team``): the
    Cliff-bot's box (its marker layout, ``[cliffbot]``) at its start, level at the anchors' mean
    height, the Anchorbots' boxes on their ground points (under the tethers' exits by ``[tether]
    anchor_exit_m``, ``fsw.core.map.body_mask.anchorbot_box``) and the tethers from the anchors'
    exits to its attachment (``[tether] attach_m``). Each robot's ground and the ground under each
    tether (the line between the anchor's ground and the Cliff-bot's) are known: the mask keeps
    the points at or below them (docs/algorithm.md §8.1)."""
    site = cfg.cliffbot_site
    if not site.mask_team:
        return None
    a, b = np.array(site.anchor_a_xyz, float), np.array(site.anchor_b_xyz, float)
    exit_m = cfg.tether.anchor_exit_m
    ground_z = 0.5 * (a[2] + b[2]) - exit_m
    ground = np.array([site.start_xy[0], site.start_xy[1], ground_z])
    pts = np.concatenate(list(cfg.cliffbot.corners_body().values()))
    box = standing_box(ground, math.radians(site.start_yaw_deg), pts, SITE_SIGMA_M, SITE_BELOW_M)
    box = dataclasses.replace(box, ground=ground)
    anchors = tuple(anchorbot_box(p - np.array([0.0, 0.0, exit_m]), SITE_SIGMA_M) for p in (a, b))
    attach = ground + np.array([0.0, 0.0, cfg.tether.attach_m])
    lines = tuple(TetherLine(np.vstack([p, attach]), TETHER_RADIUS_M, SITE_SIGMA_M, np.array([p[2] - exit_m, ground_z]))
                  for p in (a, b))
    return TeamGeometry((box, *anchors), lines)


class PerceptionTask(FlightTask):
    KIND: ClassVar[str] = "perception"
    RATE_HZ: ClassVar[tuple[float, float]] = (5.0, 50.0)  # its timeouts and moves assume ~10 Hz
    REQUIRES: ClassVar[tuple[str, ...]] = ("camera",)
    DOC: ClassVar[str] = "Stereo, fusion into the elevation map, cliff-edge fits (slack jobs)."
    CHANNELS = (
        Channel("mapped_cells", "cells", doc="cells with n >= 1"),
        Channel("views", "count", doc="views merged"),
        Channel("last_points", "points"),
        Channel("last_new_cells", "cells"),
        Channel("last_misses", "cells"),
        Channel("last_outliers", "cells"),
        Channel("edge_points", "points", doc="edge points found in the map"),
        Channel("job_ms", "ms", doc="busy time of the last view's slack job"),
        Channel("reg_status", doc="registration of the last view: registered, reference, unregistered, off"),
        Channel("reg_points", "points", doc="points of the last view aligned to the map"),
        Channel("reg_dz_m", "m", doc="height correction of the last view"),
        Channel("reg_dtilt_deg", "deg", doc="tilt correction of the last view (roll, pitch RSS)"),
        Channel("reg_dyaw_deg", "deg", doc="yaw correction of the last view"),
        Channel("reg_dxy_m", "m", doc="horizontal correction of the last view"),
        Channel("reg_sigma_z_m", "m", doc="height sigma of the last view's correction"),
        Channel("reg_unregistered", "count", hi=0, doc="views merged with an inflated pose covariance"),
        Channel("reg_partial", "count", doc="views registered in height and tilt only (halves disagreed)"),
        Channel("reg_split_chi2", doc="the last view's halves' disagreement (chi-square)"),
        Channel("rig_dv_px", "px", doc="vertical offset of the last pair's right image (rig drift)"),
        Channel("rig_exceeded", "count", hi=0, doc="views whose rig offset was beyond drift_bound_px"),
    )
    EVENTS = (
        EventDef(
            "VIEW_MERGED",
            Severity.ACTIVITY_LO,
            "view {view}: {points} points, {new} new cells, {misses} misses, {mapped} mapped",
        ),
        EventDef(
            "VIEW_REGISTERED",
            Severity.ACTIVITY_LO,
            "view {view} registered on {points} points: dz {dz_cm:+.1f} cm, droll {droll:+.2f}, dpitch "
            "{dpitch:+.2f}, dyaw {dyaw:+.2f} deg, dxy {dxy_cm:.1f} cm (sigma z {sz_cm:.2f} cm)",
        ),
        EventDef("VIEW_PARTLY_REGISTERED", Severity.WARNING_LO, "view {view}: {reason}", throttle=10),
        EventDef(
            "VIEW_NOT_REGISTERED", Severity.WARNING_LO,
            "view {view} not registered ({reason}): merged with its pose covariance inflated", throttle=10,
        ),
        EventDef(
            "RIG_MISALIGNED", Severity.WARNING_HI,
            "view {view}: stereo rows {offset:.1f} px apart (shift {dv:+.2f} px, {matches} matches), beyond "
            "{bound:.1f} px: corrected per pair, recalibrate the stereo head", throttle=5,
        ),
        EventDef(
            "MAP_LEVELLED", Severity.ACTIVITY_HI,
            "view {view}: map frame levelled by roll {rx:+.3f}, pitch {ry:+.3f} deg (sigma {sx:.3f}, {sy:.3f}): "
            "mast tilt offset {tilt:+.3f}, attitude bias roll {roll:+.3f}, pitch {pitch:+.3f} deg",
        ),
        EventDef("VIEW_FAILED", Severity.WARNING_HI, "view {view} could not be merged: {error}", throttle=5),
        EventDef("CHECKPOINT_SAVED", Severity.ACTIVITY_LO, "map checkpoint {seq} saved ({kib:.0f} KiB)"),
        EventDef("CHECKPOINT_FAILED", Severity.WARNING_HI, "map checkpoint failed: {error}", throttle=3),
        EventDef("CHECKPOINT_LOADED", Severity.ACTIVITY_HI, "map restored from checkpoint {seq}"),
        EventDef("STALE_REMOVED", Severity.WARNING_LO, "{n} temporary checkpoint file(s) of interrupted saves removed"),
    )
    COMMANDS = (
        CommandDef("CHECKPOINT", doc="save a map checkpoint now"),
        CommandDef("CLEAR_MAP", doc="forget the map (start a new survey)"),
    )

    def setup(self) -> None:
        cfg = self.ctx.cfg
        # the map, the registration state and the camera model (ConfigError if the calibration
        # file is missing or inconsistent)
        self.pipeline = SensingPipeline(cfg, load_stereo_calibration(cfg))
        self.pipeline.team = site_team(cfg)
        self.pipeline.team_mask_cfg = SITE_MASK
        self.frames = self.subscribe(CAMERA_FRAME, depth=2, policy="drop_oldest")
        self.job: JobHandle | None = None
        self.job_view = -1  # the view the job merges
        self.views = 0
        self.last_update: MapUpdate | None = None
        self.unregistered = 0
        self.partial = 0  # views registered in height and tilt only
        self.rig_exceeded = 0  # views whose rig offset was beyond the bound
        self.registrations: deque[RegistrationSummary] = deque(maxlen=1000)  # per view (mission summary)
        self.store = self.ctx.res.map_store
        self._last_checkpoint_s = self.ctx.clock.now()
        if self.store is not None:
            self._restore(self.store)

    @property
    def map(self) -> ElevationMap:
        """The elevation map (the pipeline's)."""
        return self.pipeline.map

    def run(self, frame: int) -> None:
        if self.job is not None and self.job.done:
            self._finish(self.job)
            self.job = None
        if self.job is None:
            msg = self.frames.get()
            if msg is not None and msg.view_id >= FIX_VIEW_BASE:
                msg = None  # a pair of the Cliff-bot for the fixer (fsw.tasks.fixer.task), not a view
            if msg is not None:
                self.job = self.submit_job(self.merge_view(msg), f"view{msg.view_id}")
                self.job_view = msg.view_id
        now = self.ctx.clock.now()
        if self.store is not None and (err := self.store.take_error()) is not None:
            self.event("CHECKPOINT_FAILED", error=err)  # a write on the store's writer thread
        if self.store is not None and self.job is None:
            last_s = max(self._last_checkpoint_s, self.store.last_save_s)
            if now - last_s >= self.ctx.cfg.checkpoint.period_s:
                self._checkpoint(self.store)

    def merge_view(self, fr: CameraFrame) -> Generator[None, None, MapUpdate]:
        """The slack job of one view: the sensing pipeline (``fsw.core.pipeline``, one bounded
        step per slice), then the update to publish with a snapshot of the map."""
        sv = yield from self.pipeline.view_steps(fr)
        self.views += 1
        pose = sv.placed.pose
        update = MapUpdate(
            view_id=fr.view_id,
            time_s=fr.time_s,
            mapped_cells=int(self.map.mapped.sum()),
            new_cells=sv.merge.cells_new,
            points=sv.merge.points_used,
            misses=sv.merge.misses,
            expected_new_cells=fr.expected_new_cells,
            snapshot=self.map.copy(),
            edge=sv.edge,
            outliers=sv.merge.outliers,
            edge_points=int(sv.edge_cells.points_xy.shape[0]),
            roi_mapped_fraction=sv.roi_mapped_fraction,
            registration=sv.placed.registration.summary(fr.view_id),
            view_cells=sv.view_cells,
            camera_xyz=(float(pose.t[0]), float(pose.t[1]), float(pose.t[2])),
            drop=sv.edge_cells.drop,
            nav_fix=sv.placed.nav_fix,
            rig=sv.alignment,
        )
        if sv.levelling is not None:  # the map's frame corrected by the mount biases (§5.1)
            lv = sv.levelling
            om, sg, est = np.degrees(lv.omega), np.degrees(lv.sigma), np.degrees(lv.estimate)
            self.event("MAP_LEVELLED", view=fr.view_id, rx=om[0], ry=om[1], sx=sg[0], sy=sg[1], tilt=est[0],
                       roll=est[1], pitch=est[2])
        return update

    def _finish(self, h: JobHandle) -> None:
        if h.error is not None:
            self.event("VIEW_FAILED", view=h.name, error=f"{type(h.error).__name__}: {h.error}")
            self.publish(VIEW_FAILED, ViewFailed(self.job_view, f"perception: {type(h.error).__name__}: {h.error}"))
            return
        up: MapUpdate = h.result
        self.last_update = up
        if up.nav_fix is not None:  # the motion task corrects the rover's pose (fsw.core.localization.nav_fix)
            self.publish(NAV_FIX, up.nav_fix)
        self.publish(MAP_UPDATED, up)
        self.tlm("mapped_cells", up.mapped_cells)
        self.tlm("views", self.views)
        self.tlm("last_points", up.points)
        self.tlm("last_new_cells", up.new_cells)
        self.tlm("last_misses", up.misses)
        self.tlm("last_outliers", up.outliers)
        self.tlm("edge_points", up.edge_points)
        self.tlm("job_ms", h.busy_s * 1e3)
        if up.registration is not None:
            self._report_registration(up.registration)
        if up.rig is not None:
            self._report_rig(up.view_id, up.rig)
        self.event(
            "VIEW_MERGED", view=up.view_id, points=up.points, new=up.new_cells, misses=up.misses, mapped=up.mapped_cells
        )

    def _report_rig(self, view: int, rig: RigAlignment) -> None:
        """The rig-drift measurement of a view: telemetry, and an event when the offset is beyond
        ``[stereo] drift_bound_px`` (the correction goes on; the calibration should be redone)."""
        if not math.isfinite(rig.dv_px):
            return
        half_w = self.ctx.cfg.camera.width_px / 2.0
        offset = abs(rig.dv_px) + abs(rig.roll_px_per_px) * half_w
        self.tlm("rig_dv_px", rig.dv_px)
        if rig.exceeds:
            self.rig_exceeded += 1
            self.tlm("rig_exceeded", self.rig_exceeded)
            self.event("RIG_MISALIGNED", view=view, dv=rig.dv_px, offset=offset, matches=rig.matches,
                       bound=self.ctx.cfg.stereo.drift_bound_px)

    def _report_registration(self, r: RegistrationSummary) -> None:
        self.registrations.append(r)
        self.tlm("reg_status", r["status"])
        self.tlm("reg_points", r["points"])
        if r["status"] == "registered":
            sig = r["sigma"]
            self.tlm("reg_dz_m", r["dz_m"])
            self.tlm("reg_dtilt_deg", float(np.hypot(r["droll_deg"], r["dpitch_deg"])))
            self.tlm("reg_dyaw_deg", r["dyaw_deg"])
            self.tlm("reg_dxy_m", float(np.hypot(r["dx_m"], r["dy_m"])))
            self.tlm("reg_sigma_z_m", sig[5])
            if np.isfinite(r["split_chi2"]):
                self.tlm("reg_split_chi2", r["split_chi2"])
            self.event("VIEW_REGISTERED", view=r["view"], points=r["points"], dz_cm=100 * r["dz_m"],
                       droll=r["droll_deg"], dpitch=r["dpitch_deg"], dyaw=r["dyaw_deg"],
                       dxy_cm=100 * float(np.hypot(r["dx_m"], r["dy_m"])), sz_cm=100 * sig[5])
            if r["reason"]:  # height and tilt only: yaw, x, y kept at the prior
                self.partial += 1
                self.tlm("reg_partial", self.partial)
                self.event("VIEW_PARTLY_REGISTERED", view=r["view"], reason=r["reason"])
        elif r["status"] == "unregistered":
            self.unregistered += 1
            self.tlm("reg_unregistered", self.unregistered)
            self.event("VIEW_NOT_REGISTERED", view=r["view"], reason=r["reason"])

    # -- checkpoints ---------------------------------------------------------------------
    def _checkpoint(self, store: MapStore) -> None:
        self._last_checkpoint_s = self.ctx.clock.now()
        try:
            store.save_next(self.map, self._last_checkpoint_s)
        except OSError as exc:
            self.event("CHECKPOINT_FAILED", error=describe(exc))
            raise CommandError(f"checkpoint failed: {describe(exc)}") from None
        self.event("CHECKPOINT_SAVED", seq=store.seq, kib=store.last_size / 1024)

    def _restore(self, store: MapStore) -> None:
        loaded = store.restore()
        if loaded.stale_removed:
            self.event("STALE_REMOVED", n=loaded.stale_removed)
        for path, reason in loaded.skipped:
            self.event("CHECKPOINT_FAILED", error=f"{path}: {reason}")
        if loaded.emap is None:
            return
        if loaded.emap.grid != self.map.grid:
            self.event("CHECKPOINT_FAILED", error=f"{loaded.path}: map grid differs from the configuration; not used")
            return
        self.pipeline.map = loaded.emap.copy()
        self.event("CHECKPOINT_LOADED", seq=loaded.meta.seq if loaded.meta is not None else -1)
        restore_into(self)  # a resumed mission (fsw.tasks.mission_state)

    def checkpoint_state(self) -> JsonDict:
        """What a resumed mission needs besides the map (``fsw.tasks.mission_state``): the view
        count, the registration state (the station chain, the per-view reports) and the lips the
        views found (``fsw.core.map.known_lips``)."""
        return {"views": self.views, "unregistered": self.unregistered, "partial": self.partial,
                **self.pipeline.chain.state(), "sources": self.pipeline.sources.state(),
                "mount_bias": self.pipeline.bias.state(), "lips": self.pipeline.lips.state(),
                "registrations": list(self.registrations)}

    def restore_state(self, state: JsonDict) -> None:
        self.views = int(state["views"])
        self.unregistered = int(state.get("unregistered", 0))
        self.partial = int(state.get("partial", 0))
        self.pipeline.chain.restore(state)
        self.pipeline.sources.restore(state.get("sources", {}))
        self.pipeline.bias.restore(state.get("mount_bias", {}))
        self.pipeline.lips.restore(state.get("lips", {}))
        self.registrations.extend(state.get("registrations", []))
        self.tlm("views", self.views)

    def cmd_CHECKPOINT(self) -> None:
        if self.store is None:
            raise CommandError("no map store configured")
        if self.job is not None and not self.job.done:
            raise CommandError("a view is being merged; try again")
        self._checkpoint(self.store)

    def cmd_CLEAR_MAP(self) -> None:
        if self.job is not None and not self.job.done:
            raise CommandError("a view is being merged; try again")
        self.pipeline.clear()
