"""The perception task: owns the elevation map; fuses each stereo pair and re-fits the edge.

A ``CameraFrame`` from the camera task becomes a slack job (ALGORITHM.md §4): the view's
P_V on the map before the merge (§3.1, for the misses), stereo matching, triangulation
with covariance and propagation of the camera pose covariance (§1.2), fusion into the map
with misses (§1.1, §3.4), the non-convex polygon fit of the edge (§2; the geofence and the
edge path use it for every method, Method 3 straightens the path in its planner) and the
mapped fraction of the region of interest (§3.6).
Each step is one slice of a few to ~20 ms, so the 10 Hz foreground keeps its deadlines. The result is
published on ``map.updated`` with a snapshot of the map for the planner. Checkpoints are
written through the map store at ``checkpoint.period_s`` and on command.
"""

from __future__ import annotations

from collections.abc import Generator
from typing import Any, ClassVar

import numpy as np

from fsw.core.edge import EdgeModel, edge_cells_steps, fit_polygon
from fsw.core.elevation_map import ElevationMap
from fsw.core.geometry import MapGrid
from fsw.core.localization import point_covariance_parts
from fsw.core.nbv import predicted_visibility_steps
from fsw.core.stereo import StereoMatcher
from fsw.executive.commands import CommandDef, CommandError
from fsw.executive.jobs import JobHandle
from fsw.executive.task import Task
from fsw.executive.telemetry import Channel, EventDef, Severity
from fsw.tasks.messages import CAMERA_FRAME, MAP_UPDATED, CameraFrame, MapUpdate

ROI_STRIDE = 4  # the region-of-interest fraction is estimated on every 4th cell each way


def roi_mapped_fraction(emap: ElevationMap, edge: EdgeModel) -> float:
    """Mapped fraction of the region of interest: the cells beyond the edge (§2, §3.6)."""
    if edge.empty:
        return 0.0
    X, Y = emap.grid.centers()
    s = (slice(None, None, ROI_STRIDE), slice(None, None, ROI_STRIDE))
    below = edge.signed_distance(np.column_stack([X[s].ravel(), Y[s].ravel()])) < 0
    if not below.any():
        return 0.0
    return float(emap.mapped[s].ravel()[below].mean())


PROPAGATE_CHUNK = 10000  # points per slice of the covariance propagation (~5 ms here)
MERGE_STEP_POINTS = 50000  # points per slice of each pass of the map merge (a few ms)


class PerceptionTask(Task):
    KIND: ClassVar[str] = "perception"
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
    )
    EVENTS = (
        EventDef(
            "VIEW_MERGED",
            Severity.ACTIVITY_LO,
            "view {view}: {points} points, {new} new cells, {misses} misses, {mapped} mapped",
        ),
        EventDef("VIEW_FAILED", Severity.WARNING_HI, "view {view} could not be merged: {error}", throttle=5),
        EventDef("CHECKPOINT_SAVED", Severity.ACTIVITY_LO, "map checkpoint {seq} saved ({kib:.0f} KiB)"),
        EventDef("CHECKPOINT_FAILED", Severity.WARNING_HI, "map checkpoint failed: {error}", throttle=3),
        EventDef("CHECKPOINT_LOADED", Severity.ACTIVITY_HI, "map restored from checkpoint {seq}"),
    )
    COMMANDS = (
        CommandDef("CHECKPOINT", doc="save a map checkpoint now"),
        CommandDef("CLEAR_MAP", doc="forget the map (start a new survey)"),
    )

    def setup(self) -> None:
        cfg = self.ctx.cfg
        self.matcher = StereoMatcher(cfg.stereo, cfg.camera)
        self.map = ElevationMap(MapGrid.from_config(cfg.map), cfg.fusion)
        self.frames = self.subscribe(CAMERA_FRAME, depth=2, policy="drop_oldest")
        self.job: JobHandle | None = None
        self.views = 0
        self.store: Any = self.ctx.resources.get("map_store")
        self._last_checkpoint_s = self.ctx.clock.now()
        self._ckpt_seq = 0
        if self.store is not None:
            self._restore()

    def run(self, frame: int) -> None:
        if self.job is not None and self.job.done:
            self._finish(self.job)
            self.job = None
        if self.job is None:
            msg = self.frames.get()
            if msg is not None:
                self.job = self.submit_job(self._merge_view(msg), f"view{msg.view_id}")
        now = self.ctx.clock.now()
        if self.store is not None and now - self._last_checkpoint_s >= self.ctx.cfg.checkpoint.period_s:
            self._checkpoint()

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
        dm = yield from self.matcher.match_steps(fr.left, fr.right)
        yield
        pts = yield from self.matcher.triangulate_steps(dm.disparity_px, sigma_px=dm.sigma_px)
        parts = []
        for a in range(0, len(pts), PROPAGATE_CHUNK):  # world covariance (§1.2) in bounded slices
            b = a + PROPAGATE_CHUNK
            xyz, cov_s, cov_p = point_covariance_parts(fr.pose, fr.pose_cov, pts.xyz_c[a:b], pts.cov_c[a:b])
            # The pose term is common to every point of the view: it must not average down in a cell.
            parts.append((xyz, cov_s if cov_p is None else cov_s + cov_p, cov_p))
            yield
        stats = yield from self.map.merge_parts_steps(parts, p_visible=p_visible, step_points=MERGE_STEP_POINTS)
        yield
        ecfg = self.ctx.cfg.edge
        here = (float(fr.pose.t[0]), float(fr.pose.t[1]))  # the camera stands over the plateau
        cells = yield from edge_cells_steps(self.map, 0.0, here, ecfg)  # ground: the plateau at the start
        yield
        poly = fit_polygon(self.map, cells, ecfg)
        yield
        roi_fraction = roi_mapped_fraction(self.map, poly)
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
            extra={"outliers": stats.outliers, "edge_points": int(cells.points_xy.shape[0]),
                   "roi_mapped_fraction": roi_fraction},
        )

    def _finish(self, h: JobHandle) -> None:
        if h.error is not None:
            self.event("VIEW_FAILED", view=h.name, error=f"{type(h.error).__name__}: {h.error}")
            return
        up: MapUpdate = h.result
        self.publish(MAP_UPDATED, up)
        self.tlm("mapped_cells", up.mapped_cells)
        self.tlm("views", self.views)
        self.tlm("last_points", up.points)
        self.tlm("last_new_cells", up.new_cells)
        self.tlm("last_misses", up.misses)
        self.tlm("last_outliers", up.extra["outliers"])
        self.tlm("edge_points", up.extra["edge_points"])
        self.tlm("job_ms", h.busy_s * 1e3)
        self.event(
            "VIEW_MERGED", view=up.view_id, points=up.points, new=up.new_cells, misses=up.misses, mapped=up.mapped_cells
        )

    # -- checkpoints ---------------------------------------------------------------------
    def _checkpoint(self) -> None:
        self._last_checkpoint_s = self.ctx.clock.now()
        self._ckpt_seq += 1
        try:
            path = self.store.save(self.map, self._ckpt_seq, self._last_checkpoint_s)
        except OSError as exc:
            self.event("CHECKPOINT_FAILED", error=str(exc))
            raise CommandError(f"checkpoint failed: {exc}") from None
        self.event("CHECKPOINT_SAVED", seq=self._ckpt_seq, kib=path.stat().st_size / 1024)

    def _restore(self) -> None:
        loaded: Any = self.store.load_latest()
        for path, reason in loaded.skipped:
            self.event("CHECKPOINT_FAILED", error=f"{path}: {reason}")
        if loaded.emap is not None and loaded.emap.grid == self.map.grid:
            self.map = loaded.emap
            self._ckpt_seq = loaded.meta.seq
            self.event("CHECKPOINT_LOADED", seq=loaded.meta.seq)

    def cmd_CHECKPOINT(self) -> None:
        if self.store is None:
            raise CommandError("no map store configured")
        self._checkpoint()

    def cmd_CLEAR_MAP(self) -> None:
        if self.job is not None and not self.job.done:
            raise CommandError("a view is being merged; try again")
        self.map = ElevationMap(self.map.grid, self.ctx.cfg.fusion)
