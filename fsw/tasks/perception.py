"""The perception task: owns the elevation map; fuses each stereo pair and re-fits the edge.

A ``CameraFrame`` from the camera task becomes a slack job (docs/algorithm.md §4): the view's
P_V on the map before the merge (§3.1, for the misses), rectification of the raw pair when
the camera has a calibration file (``fsw.core.stereo.rectify``: maps built once here at start-up,
the pair remapped in row bands), stereo matching, triangulation with covariance,
registration of the view against the map (§5.1: its pose corrected, or its pose covariance
inflated when it cannot be registered), propagation of the camera pose covariance (§1.2),
fusion into the map
with misses (§1.1, §3.4), the non-convex polygon fit of the edge (§2; the geofence and the
edge path use it for every method, Method 3 straightens the path in its planner) and the
mapped fraction of the region of interest (§3.6).
Each step is one slice of a few to ~20 ms, so the 10 Hz foreground keeps its deadlines. The result is
published on ``map.updated`` with a snapshot of the map for the planner. The mission
sequencer checkpoints each step's map with its state (``fsw.tasks.mission_checkpoint``); this
task also writes map-only checkpoints through the map store on command and at
``checkpoint.period_s`` when nothing was saved for that long, never while a merge is under
way (the map would be half-merged). At start-up it restores the newest good checkpoint's map.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Generator
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from fsw.core.edge.edge import EdgeModel, edge_cells_steps, fit_polygon_steps
from fsw.core.geometry import CameraPose, MapGrid
from fsw.core.localization.localization import point_covariance_parts
from fsw.core.localization.nav_fix import NavFix
from fsw.core.map.elevation_map import ElevationMap
from fsw.core.map.reference_frames import ReferenceFrames
from fsw.core.planning.nbv import predicted_visibility_steps
from fsw.core.registration.registration import (
    Registration,
    RegistrationSummary,
    apply_correction,
    reference_cells,
    register_steps,
)
from fsw.core.registration.station_chain import StationChain
from fsw.core.steps import run_to_end
from fsw.core.stereo.occlusion import LipGuard
from fsw.core.stereo.rectify import Rectifier
from fsw.core.stereo.stereo import StereoMatcher, StereoPoints
from fsw.core.stereo.stereo_calibration import offset_covariance
from fsw.drivers.map_store import MapStore
from fsw.framework.commands import CommandDef, CommandError
from fsw.framework.jobs import JobHandle
from fsw.framework.storage import describe
from fsw.framework.telemetry import Channel, EventDef, Severity
from fsw.settings import load_stereo_calibration
from fsw.tasks.base import FlightTask
from fsw.tasks.messages import CAMERA_FRAME, MAP_UPDATED, NAV_FIX, VIEW_FAILED, CameraFrame, MapUpdate, ViewFailed
from fsw.tasks.mission_state import JsonDict, restore_into

ROI_STRIDE = 4  # the region-of-interest fraction is estimated on every 4th cell each way
ROI_STEP_POINTS = 2048  # cells per slice of that estimate (~10 ms here on the lab's edge)


def roi_mapped_fraction(emap: ElevationMap, edge: EdgeModel) -> float:
    """Mapped fraction of the region of interest: the cells beyond the edge (§2, §3.6)."""
    return run_to_end(roi_mapped_fraction_steps(emap, edge))


def roi_mapped_fraction_steps(emap: ElevationMap, edge: EdgeModel) -> Generator[None, None, float]:
    """:func:`roi_mapped_fraction`, yielding after each ``ROI_STEP_POINTS`` cells (the signed
    distance of a cell is its own: the same values as one call)."""
    if edge.empty:
        return 0.0
    X, Y = emap.grid.centers()
    s = (slice(None, None, ROI_STRIDE), slice(None, None, ROI_STRIDE))
    pts = np.column_stack([X[s].ravel(), Y[s].ravel()])
    below = np.empty(pts.shape[0], bool)
    for a in range(0, pts.shape[0], ROI_STEP_POINTS):
        below[a:a + ROI_STEP_POINTS] = edge.signed_distance(pts[a:a + ROI_STEP_POINTS]) < 0
        yield
    if not below.any():
        return 0.0
    return float(emap.mapped[s].ravel()[below].mean())


PROPAGATE_CHUNK = 10000  # points per slice of the covariance propagation (~5 ms here)
MERGE_STEP_POINTS = 50000  # points per slice of each pass of the map merge (a few ms)


ViewPart = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64] | None]  # xyz, cov, common cov


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
        cal = load_stereo_calibration(cfg)  # ConfigError if missing or inconsistent
        # rectified onto the configured pinhole camera, so P_V and the planner see the same one
        self.rectifier = None if cal is None else Rectifier(cal, cfg.camera.K)
        self.matcher = StereoMatcher(cfg.stereo, cfg.camera, None if self.rectifier is None else self.rectifier.camera)
        self.map = ElevationMap(MapGrid.from_config(cfg.map), cfg.fusion)
        self.frames = self.subscribe(CAMERA_FRAME, depth=2, policy="drop_oldest")
        self.job: JobHandle | None = None
        self.job_view = -1  # the view the job merges
        self.views = 0
        self.last_update: MapUpdate | None = None
        self.unregistered = 0
        self.partial = 0  # views registered in height and tilt only
        self.chain = StationChain()  # the registered stations (fsw.core.registration.station_chain)
        self.sources = ReferenceFrames(self.map.grid.shape)  # each cell's view (fsw.core.map.reference_frames)
        self.registrations: deque[RegistrationSummary] = deque(maxlen=1000)  # per view (mission summary)
        self.store = self.ctx.res.map_store
        self._last_checkpoint_s = self.ctx.clock.now()
        if self.store is not None:
            self._restore(self.store)

    def run(self, frame: int) -> None:
        if self.job is not None and self.job.done:
            self._finish(self.job)
            self.job = None
        if self.job is None:
            msg = self.frames.get()
            if msg is not None:
                self.job = self.submit_job(self._merge_view(msg), f"view{msg.view_id}")
                self.job_view = msg.view_id
        now = self.ctx.clock.now()
        if self.store is not None and (err := self.store.take_error()) is not None:
            self.event("CHECKPOINT_FAILED", error=err)  # a write on the store's writer thread
        if self.store is not None and self.job is None:
            last_s = max(self._last_checkpoint_s, self.store.last_save_s)
            if now - last_s >= self.ctx.cfg.checkpoint.period_s:
                self._checkpoint(self.store)

    def _merge_view(self, fr: CameraFrame) -> Generator[None, None, MapUpdate]:
        """The slack job of one view: one bounded step per slice (a few to ~20 ms here).

        Every long stage is itself a step generator: P_V in ray chunks, SGBM in row bands,
        triangulation per band, the covariance propagation and both passes of the merge in
        point chunks, the edge search in halves; nothing runs a whole stage in one slice.
        """
        # Which cells this view was expected to see (P_V on the map before the merge, §3.1):
        # those that get no point count a miss and lose interest (§3.4, §4).
        cfg = self.ctx.cfg
        p_visible = None
        if self.map.mapped.any():
            p_visible = yield from predicted_visibility_steps(self.map, fr.pose, cfg.camera, cfg.nbv.visibility)
            yield
        left, right = fr.left, fr.right
        if self.rectifier is not None:
            left, right = yield from self.rectifier.rectify_steps(left, right, cfg.stereo.band_rows_px)
        dm = yield from self.matcher.match_steps(left, right)
        yield
        pts = yield from self.matcher.triangulate_steps(dm.disparity_px, sigma_px=dm.sigma_px)
        del dm, left, right  # not needed past here: a smaller resident peak (issue 15)
        reg, pose, pose_cov, nav_fix = yield from self._register(fr, pts)
        parts, off_sigma = [], 0.0 if self.rectifier is None else self.rectifier.camera.offset_sigma_px
        lips = LipGuard.of_view(self.map.grid, pose, pts.lip_near_c, pts.lip_far_c, cfg.fusion.lip_min_drop_m)
        for a in range(0, len(pts), PROPAGATE_CHUNK):  # world covariance (§1.2) in bounded slices
            b = a + PROPAGATE_CHUNK
            xyz, cov_s, cov_p = point_covariance_parts(pose, pose_cov, pts.xyz_c[a:b], pts.cov_c[a:b])
            if off_sigma > 0.0:  # the calibration's disparity offset: common too (§1.2)
                cal = offset_covariance(xyz, pose.t, pts.disparity_px[a:b], off_sigma)
                cov_p = cal if cov_p is None else cov_p + cal
            # The pose term is common to every point of the view: it must not average down in a cell.
            parts.append(lips.part(xyz, cov_s, cov_p, cfg.fusion.lip_guard_sigma))  # too near a lip: withheld
            yield
        del pts  # the camera-frame points: every use is above
        view_cells = self.map.grid.cell_means(np.concatenate([p[0] for p in parts]) if parts else np.zeros((0, 3)))
        X, Y = (c.reshape(-1)[view_cells[0]] for c in self.map.grid.centers())
        self.sources.add(view_cells[0], np.column_stack([X, Y, view_cells[1]]), pose.t, pose_cov)
        yield
        stats = yield from self.map.merge_parts_steps(parts, p_visible=p_visible, step_points=MERGE_STEP_POINTS)
        yield
        ecfg = self.ctx.cfg.edge
        here = (float(fr.pose.t[0]), float(fr.pose.t[1]))  # the camera stands over the plateau
        # The ground under the rover now (not at the start: on a slope the rover has climbed or
        # descended since), with the registration's height correction (§2, §5.1).
        ground_z = fr.ground_z_m + float(pose.t[2] - fr.pose.t[2])
        cells = yield from edge_cells_steps(self.map, ground_z, here, ecfg)
        yield
        poly = yield from fit_polygon_steps(self.map, cells, ecfg)
        yield
        roi_fraction = yield from roi_mapped_fraction_steps(self.map, poly)
        yield
        self.views += 1
        return MapUpdate(
            view_id=fr.view_id,
            time_s=fr.time_s,
            mapped_cells=int(self.map.mapped.sum()),
            new_cells=stats.cells_new,
            points=stats.points_used,
            misses=stats.misses,
            expected_new_cells=fr.expected_new_cells,
            snapshot=self.map.copy(),
            edge=poly,
            outliers=stats.outliers,
            edge_points=int(cells.points_xy.shape[0]),
            roi_mapped_fraction=roi_fraction,
            registration=reg.summary(fr.view_id),
            view_cells=view_cells,
            camera_xyz=(float(pose.t[0]), float(pose.t[1]), float(pose.t[2])),
            drop=cells.drop,
            nav_fix=nav_fix,
        )

    def _register(
        self, fr: CameraFrame, pts: StereoPoints
    ) -> Generator[None, None, tuple[Registration, CameraPose, NDArray[np.float64], NavFix | None]]:
        """Align the view to the map (§5.1): the corrected pose, the covariance to merge with
        and the navigation fix to feed back (``fsw.core.registration.station_chain``: where the fit starts,
        the frame error, the feedback)."""
        rcfg = self.ctx.cfg.registration
        if not rcfg.enabled:
            return Registration("off", "disabled in config"), fr.pose, fr.pose_cov, None
        vp = self.chain.prior(fr.pose, fr.pose_cov, fr.nav_fix_id, rcfg)
        prior = apply_correction(fr.pose, vp.d0)
        n = len(pts)
        sel = np.linspace(0, n - 1, min(n, 4 * rcfg.max_points)).astype(np.intp) if n else np.zeros(0, np.intp)
        xyz_w, cov_w, _ = point_covariance_parts(prior, None, pts.xyz_c[sel], pts.cov_c[sel])
        ref = reference_cells(self.map.z, self.map.var, self.map.n, rcfg)
        yield
        reg = yield from register_steps(xyz_w, cov_w, prior, vp.cov, self.map.grid, self.map.z,
                                        self.map.var, ref, rcfg, self.sources if rcfg.reference_error else None)
        if reg.status == "reference":
            self.chain.reference(fr.pose_cov)
            return reg, fr.pose, fr.pose_cov, None
        if reg.status != "registered":
            pose, cov = self.chain.unregistered(fr.pose, vp, reg, rcfg)
            return reg, pose, cov, None
        pose, cov, nav = self.chain.registered(fr.pose, fr.pose_cov, fr.nav_fix_id, fr.time_s, vp, reg, rcfg)
        return reg, pose, cov, nav

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
        self.event(
            "VIEW_MERGED", view=up.view_id, points=up.points, new=up.new_cells, misses=up.misses, mapped=up.mapped_cells
        )

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
        self.map = loaded.emap.copy()
        self.event("CHECKPOINT_LOADED", seq=loaded.meta.seq if loaded.meta is not None else -1)
        restore_into(self)  # a resumed mission (fsw.tasks.mission_state)

    def checkpoint_state(self) -> JsonDict:
        """What a resumed mission needs besides the map (``fsw.tasks.mission_state``): the view
        count and the registration state (the station chain, the per-view reports)."""
        return {"views": self.views, "unregistered": self.unregistered, "partial": self.partial, **self.chain.state(),
                "sources": self.sources.state(),
                "registrations": list(self.registrations)}

    def restore_state(self, state: JsonDict) -> None:
        self.views = int(state["views"])
        self.unregistered = int(state.get("unregistered", 0))
        self.partial = int(state.get("partial", 0))
        self.chain.restore(state)
        self.sources.restore(state.get("sources", {}))
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
        self.map = ElevationMap(self.map.grid, self.ctx.cfg.fusion)
        self.chain.clear()
        self.sources.clear()
