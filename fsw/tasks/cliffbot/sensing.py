"""The Cliff-bot's sensing task: its own stereo views into its own map (docs/team.md, "Both
agents sense"; docs/algorithm.md §8.1).

On the mission's request (:class:`~fsw.tasks.cliffbot.messages.SenseRequest`, the mission
holding still in ``SENSE``) the task takes one pair per pointing of the head's scan
(``[cliffbot_sensing] pan_deg`` and ``tilts_deg``, in order: the k-th capture of the camera
driver, sequence number ``k + 1``, looks along the scan's ``k mod n``-th pan and tilt, so the
camera head and the flight side agree without a head command), each tagged with the head's pose from the navigation
estimate, the attitude sensor and the ground height on the map the mission plans on, and that
pose's covariance (:mod:`fsw.core.team.cliffbot_head`). Each pair goes through THE sensing
pipeline (:class:`fsw.core.pipeline.SensingPipeline`, the Cliff-bot's camera, registration off:
the pose covariance carries the navigation's error into every point, §1.2) as a slack job,
with the team masked out at its known poses: its own body box and the two tethers (anchor
exits, their contacts on the map, its attachment) at its estimate, the Anchorbots at their
surveyed ground points (``fsw.core.map.body_mask``), each with the ground it stands on (its body's
plane, the Anchorbots' ground points): the ground round them, which the tethers run over, stays
in the views.

The map the mission plans on (:class:`~fsw.tasks.cliffbot.messages.SensedMap`, published when
a map arrives over the link and when a request's views are all in): the received map as it
came (the RECON-bot's, within the codec's bound), and, on the cells it does not know, the
Cliff-bot's own map, and under each Anchorbot (its footprint round its surveyed ground point,
which no camera sees) that ground point's height: known by contact. A request without a
camera, or whose captures all fail, is answered with the map as it stands (events say why):
the mission never waits on a broken camera.
"""

from __future__ import annotations

import math
from collections.abc import Generator
from dataclasses import dataclass, field, replace
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from fsw.comm.team.team_can import WINCHES
from fsw.core.edge.edge import EdgeConfig
from fsw.core.geometry import CameraConfig, CameraPose, MapGrid, MapGridConfig, normal_from_attitude
from fsw.core.map.body_mask import BodyBox, MaskConfig, TeamGeometry, TetherLine, anchorbot_box
from fsw.core.map.elevation_map import FusionConfig
from fsw.core.pipeline import MergedView, SensingPipeline
from fsw.core.planning.nbv import NbvConfig
from fsw.core.registration.registration import RegistrationConfig
from fsw.core.stereo.stereo import StereoConfig
from fsw.core.team.cliffbot_head import head_end, head_pose_covariance
from fsw.core.team.contact_ground import body_height
from fsw.core.team.tether import tether_state
from fsw.framework.jobs import JobHandle
from fsw.framework.telemetry import Channel, EventDef, Severity
from fsw.sections import CliffbotSensingConfig
from fsw.settings import FswConfig
from fsw.tasks.base import FlightTask
from fsw.tasks.cliffbot.messages import (
    CB_MAP,
    CB_NAV,
    CB_PLAN_MAP,
    CB_SENSE,
    CB_SENSED_MAP,
    CB_STATUS,
    DeviceStatus,
    NavEstimate,
    ReceivedMap,
    SensedMap,
    SenseRequest,
)
from fsw.tasks.cliffbot_mission import BODY_MARGIN_M

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]
# An Anchorbot as the mask knows it: fsw.core.map.body_mask.anchorbot_box; the ground it stands on is known
# by contact (ANCHOR_FOOT_M round its surveyed ground point).
ANCHOR_FOOT_M = 0.4
TETHER_RADIUS_M = 0.006
BODY_SIGMA_M = 0.01  # its own box as its camera knows it (one rigid body)
BODY_LIFT_M = 0.05  # the mask's box of its body starts this far above its ground
MARGIN_M = 0.015  # the mask's margin (5 px windows at 1 m: 1.8 cm; fsw.core.map.body_mask.MaskConfig)
BEHIND_TETHER = 1.25  # the tether mask's sight-line reach, times a point's range (fsw.core.map.body_mask.MaskConfig)
# Its views look along the face from a head on it: a point's error across the sight line may carry it
# off the steep surface it came from; its variance takes that surface's slope within this many sigma
# (fsw.core.map.elevation_map.FusionConfig.source_reach_sigma, docs/algorithm.md §1.2)
SOURCE_REACH_SIGMA = 2.0


@dataclass(frozen=True)
class CliffbotPipelineSettings:
    """The sensing pipeline's settings for the Cliff-bot's camera (``fsw.core.pipeline.PipelineSettings``):
    its stereo pair, the team's map grid, the stereo search sized for its nearest range, no
    registration (its views are placed by the navigation with their covariance)."""

    camera: CameraConfig
    map: MapGridConfig
    stereo: StereoConfig = field(default_factory=StereoConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    registration: RegistrationConfig = field(default_factory=lambda: RegistrationConfig(enabled=False))
    nbv: NbvConfig = field(default_factory=NbvConfig)
    edge: EdgeConfig = field(default_factory=EdgeConfig)

    @staticmethod
    def of(cfg: FswConfig) -> CliffbotPipelineSettings:
        sc = cfg.cliffbot_sensing
        cam = CameraConfig(width_px=sc.width_px, height_px=sc.height_px, hfov_deg=sc.hfov_deg,
                           baseline_m=sc.baseline_m, min_range_m=sc.min_range_m, max_range_m=sc.max_range_m)
        # the disparity search reaches the nearest usable range (a multiple of 16)
        need = cam.baseline_m * cam.focal_px / cam.min_range_m
        ndisp = int(min(max(16 * math.ceil(need / 16.0), 16), 16 * ((cam.width_px // 2) // 16)))
        # a head over the lip looks down the face past the lips it finds there (its steps and ledges): a
        # lip withholds only the points it can hide from the head (FusionConfig.lip_sight_line, §4); the
        # rest of the fusion and stereo settings are the configuration's own ([fusion], [stereo])
        fusion = replace(cfg.fusion, source_reach_sigma=SOURCE_REACH_SIGMA, lip_sight_line=True)
        return CliffbotPipelineSettings(cam, cfg.map, stereo=replace(cfg.stereo, num_disparities_px=ndisp),
                                        fusion=fusion)


@dataclass(frozen=True)
class HeadView:
    """One of the Cliff-bot's pairs as the pipeline takes it (``fsw.core.pipeline.StereoView``)."""

    view_id: int
    time_s: float
    left: U8
    right: U8
    pose: CameraPose
    pose_cov: F64
    ground_z_m: float
    nav_fix_id: int = -1
    body_yaw_rad: float = math.nan  # not estimated for the Cliff-bot's head (no mount-bias estimate)


@dataclass
class Capture:
    seq: int
    pan: float
    pose: CameraPose
    cov: F64
    body_z: float
    t: float


class CliffbotSensingTask(FlightTask):
    KIND: ClassVar[str] = "cliffbot_sensing"
    RATE_HZ: ClassVar[tuple[float, float]] = (5.0, 50.0)  # capture timeouts assume ~10 Hz
    REQUIRES: ClassVar[tuple[str, ...]] = ("cliffbot_devices", "cliffbot_radio", "cliffbot_nav", "cliffbot_mission")
    DOC: ClassVar[str] = "Cliff-bot sensing: its head's stereo views through the sensing pipeline into its own map."
    CHANNELS = (
        Channel("views", "count", doc="views merged into its own map"),
        Channel("own_cells", "cells", doc="cells of its own map the received map does not know"),
        Channel("last_points", "points"),
        Channel("last_new_cells", "cells"),
        Channel("pending", "count", doc="captures left of the request under way"),
    )
    EVENTS = (
        EventDef("VIEW_MERGED", Severity.ACTIVITY_LO,
                 "view {view} (pan {pan:.0f} deg): {points} points, {new} new cells, {mapped} mapped"),
        EventDef("VIEW_FAILED", Severity.WARNING_LO, "view {view}: {error}", throttle=5),
        EventDef("SENSED", Severity.ACTIVITY_HI, "views {seq}: {views} of {asked} merged, {own} cells of its own"),
        EventDef("BODY_HEIGHT", Severity.ACTIVITY_LO,
                 "views {seq}: the ground under the body from {how}: {z:.2f} m (the map does not know it)"),
        EventDef("NO_CAMERA", Severity.WARNING_HI, "views {seq}: no camera; planning on the received map"),
    )

    def setup(self) -> None:
        cfg = self.ctx.cfg
        self.sc: CliffbotSensingConfig = cfg.cliffbot_sensing
        self.grid = MapGrid.from_config(cfg.map)
        self.pipe = SensingPipeline(CliffbotPipelineSettings.of(cfg), None)
        self.pipe.team_with_camera = True  # its body and tethers are placed from its own estimate
        # its views are short (at most max_range_m): a point's depth is good to a few centimetres,
        # so the sight lines past a robot end at the point (beyond it they dive under the ground
        # round an Anchorbot and take the ground the tethers start over) and past a tether a
        # quarter beyond it; a robot's or tether's outline smears over a window of a centimetre or so
        self.pipe.team_mask_cfg = MaskConfig(margin_m=MARGIN_M, behind=1.0, behind_tether=BEHIND_TETHER)
        site = cfg.cliffbot_site
        self.anchors = np.array([site.anchor_a_xyz, site.anchor_b_xyz], float)  # the tethers' exits
        self.anchor_ground = self.anchors - np.array([0.0, 0.0, cfg.tether.anchor_exit_m])
        self.camera = self.ctx.res.camera
        self.maps = self.subscribe(CB_MAP, depth=2)
        self.plan_maps = self.subscribe(CB_PLAN_MAP, depth=2)
        self.nav = self.subscribe(CB_NAV, depth=8)
        self.status = self.subscribe(CB_STATUS, depth=1)
        self.requests = self.subscribe(CB_SENSE, depth=4)
        self.received: ReceivedMap | None = None
        self.plan_z: F64 | None = None
        self.est: NavEstimate | None = None
        self.last_status: DeviceStatus | None = None
        self.seq = 0  # the request under way (or last answered)
        self.left = 0  # captures left of it
        self.asked = self.merged = 0  # its captures and the views merged
        self.capture: Capture | None = None
        self.job: JobHandle | None = None
        self.job_capture: Capture | None = None
        self.views = 0
        self.answered = 0  # the last request answered with a map
        self.body_z_at: tuple[tuple[int, float, float], float] | None = None  # (request, place), height

    # -- the map the mission plans on -----------------------------------------------------------
    def own_map(self) -> F64:
        """The Cliff-bot's own map (heights, NaN unknown), team frame."""
        m = self.pipe.map
        return np.where(m.mapped, m.z, np.nan).astype(np.float64)

    def _publish(self) -> None:
        if self.received is None:
            return
        z = np.asarray(self.received.z, np.float64).copy()
        own = self.own_map()
        fill = ~np.isfinite(z) & np.isfinite(own)
        z[fill] = own[fill]
        n = int(fill.sum())
        X, Y = self.grid.centers()
        for a in self.anchor_ground:  # the ground under each Anchorbot, known by contact
            foot = (np.abs(X - a[0]) <= ANCHOR_FOOT_M) & (np.abs(Y - a[1]) <= ANCHOR_FOOT_M) & ~np.isfinite(z)
            z[foot] = a[2]
        self.tlm("own_cells", n)
        self.publish(CB_SENSED_MAP, SensedMap(self.received.map_id, z, self.received.error_bound_m, self.answered, n,
                                              own))

    # -- the work ------------------------------------------------------------------------------
    def run(self, frame: int) -> None:
        now = self.ctx.clock.now()
        for got in self.maps.drain():
            self.received = got
            self._publish()
        for pm in self.plan_maps.drain():
            self.plan_z = np.asarray(pm.z, np.float64)
            if self.received is None:  # started from a checkpoint: its map, less the plane carried on
                z = self.plan_z.copy()
                if pm.carried is not None and pm.carried.shape == z.shape:
                    z[pm.carried] = np.nan
                self.received = ReceivedMap(0, z, pm.error_bound_m)
        for est in self.nav.drain():
            self.est = est
        st: DeviceStatus | None = self.status.latest()
        self.last_status = st if st is not None else self.last_status
        for req in self.requests.drain():
            self._request(req)
        if self.camera is not None:
            self.camera.poll(now)
        if self.job is not None and self.job.done:
            self._finish(self.job)
            self.job = None
        self._collect(now)
        if self.job is None and self.capture is None and self.left > 0:
            self._trigger(now)
        if self.left == 0 and self.capture is None and self.job is None and self.answered < self.seq:
            self.answered = self.seq
            self.event("SENSED", seq=self.seq, views=self.merged, asked=self.asked,
                       own=int(np.isfinite(self.own_map()).sum()))
            self._publish()
        self.tlm("pending", self.left)

    def _request(self, req: SenseRequest) -> None:
        self.seq = req.seq
        self.asked = self.merged = 0
        if self.camera is None:
            self.event("NO_CAMERA", seq=req.seq)
            self.left = 0
            return
        self.left = len(self.sc.pan_deg)

    def _trigger(self, now: float) -> None:
        assert self.camera is not None
        self.left -= 1
        seq = self.camera.trigger(now)
        if seq is None:  # busy or no source: that pointing is skipped (the driver said why)
            return
        self.asked += 1
        pan = math.radians(self.sc.pan_deg[(seq - 1) % len(self.sc.pan_deg)])
        placed = self._head_pose(pan, math.radians(self.sc.tilt_of(seq - 1)), self.sc.place_of(seq - 1))
        if placed is None:
            self.event("VIEW_FAILED", view=seq, error="no navigation estimate or attitude yet")
            return
        pose, cov, body_z = placed
        self.capture = Capture(seq, pan, pose, cov, body_z, now)

    def _head_pose(self, pan: float, tilt: float, place: str) -> tuple[CameraPose, F64, float] | None:
        att = None if self.last_status is None else self.last_status.devices.attitude
        if self.est is None or att is None:
            return None
        s, P = self.est.s, self.est.P
        z = self._body_z(s[:2])
        sc = self.sc
        pose, cov = head_pose_covariance(
            s[:2], z, float(s[2]), math.radians(att.roll_deg), math.radians(att.pitch_deg), pan,
            tilt, sc.head_m, head_end(pan, sc.head_end_m, place), P, sc.height_sigma_m,
            math.radians(sc.tilt_sigma_deg))
        return pose, cov, z

    def _body_z(self, xy: F64) -> float:
        """The ground under the body on the map the mission plans on (filled there by contact;
        else the received map), or where that map does not know it, from the known cells round
        it or its tethers' paid-out lengths (:func:`fsw.core.team.contact_ground.body_height`;
        event ``BODY_HEIGHT`` when not from the map); worked out once per request and place."""
        z = self.plan_z if self.plan_z is not None else (None if self.received is None else self.received.z)
        if z is None:
            return float(np.mean(self.anchor_ground[:, 2]))
        key = (self.seq, round(float(xy[0]), 3), round(float(xy[1]), 3))
        if self.body_z_at is not None and self.body_z_at[0] == key:
            return self.body_z_at[1]
        dev = None if self.last_status is None else self.last_status.devices
        a, b = (None, None) if dev is None else (dev.winch.get(WINCHES[0]), dev.winch.get(WINCHES[1]))
        lengths = None if a is None or b is None else (a.paid_out_m, b.paid_out_m)
        att = None if dev is None else dev.attitude
        normal = None if att is None or self.est is None else normal_from_attitude(
            float(self.est.s[2]), math.radians(att.roll_deg), math.radians(att.pitch_deg))
        cfg = self.ctx.cfg
        h, how = body_height(z, self.grid, xy, self.anchors, cfg.tether, lengths=lengths, normal=normal,
                             hide_m=cfg.climber.footprint_m + BODY_MARGIN_M)
        if how != "map":
            self.event("BODY_HEIGHT", seq=self.seq, how=how, z=h)
        self.body_z_at = (key, h)
        return h

    def _collect(self, now: float) -> None:
        c = self.capture
        if c is None or self.camera is None:
            return
        r = self.camera.take()
        if r is not None and r.seq == c.seq and r.left is not None and r.right is not None:
            self.capture = None
            view = HeadView(c.seq, c.t, np.asarray(r.left, np.uint8), np.asarray(r.right, np.uint8), c.pose, c.cov,
                            c.body_z)
            self.pipe.team = self._team(c)
            self.job_capture = c
            self.job = self.submit_job(self._merge(view), f"cbview{c.seq}")
        elif not self.camera.busy:  # timed out, dropped or a broken link (the driver's events)
            self.capture = None
            self.event("VIEW_FAILED", view=c.seq, error="no pair from the camera")

    def _merge(self, view: HeadView) -> Generator[None, None, MergedView]:
        merged = yield from self.pipe.merge_view_steps(view)
        return merged

    def _finish(self, h: JobHandle) -> None:
        c = self.job_capture
        if h.error is not None:
            self.event("VIEW_FAILED", view=h.name, error=f"{type(h.error).__name__}: {h.error}")
            return
        mv: MergedView = h.result
        self.views += 1
        self.merged += 1
        self.event("VIEW_MERGED", view=h.name, pan=math.degrees(c.pan) if c is not None else 0.0,
                   points=mv.merge.points_used, new=mv.merge.cells_new, mapped=int(self.pipe.map.mapped.sum()))
        self.tlm("views", self.views)
        self.tlm("last_points", mv.merge.points_used)
        self.tlm("last_new_cells", mv.merge.cells_new)

    # -- the team, masked out of its views (docs/algorithm.md §8.1) -----------------------------
    def _team(self, c: Capture) -> TeamGeometry:
        """Its body, the Anchorbots and the tethers as the mask knows them (:func:`cliffbot_team`)."""
        assert self.est is not None
        att = None if self.last_status is None else self.last_status.devices.attitude
        roll = math.radians(att.roll_deg) if att is not None else 0.0
        pitch = math.radians(att.pitch_deg) if att is not None else 0.0
        return cliffbot_team(self.ctx.cfg, self.est.s, self.est.P, roll, pitch, c.body_z, self.anchors,
                             self.plan_z, self.grid)


def cliffbot_team(cfg: FswConfig, s: F64, P: F64, roll: float, pitch: float, body_z: float, anchors: F64,
                  plan_z: F64 | None, grid: MapGrid) -> TeamGeometry:
    """The team as the Cliff-bot's mask knows it: its body box and the tethers at its estimate
    ``s`` (x, y, yaw; covariance ``P``) on the ground ``body_z`` tilted by ``roll`` and ``pitch``,
    the Anchorbots at their ground points under the tether exits ``anchors`` (``(2, 3)``), the
    tethers over their contacts on ``plan_z`` (None: straight). The body and the camera are one
    rigid whole: its box is known to the camera within ``BODY_SIGMA_M`` (the head stands outside
    it). The tethers run from the body (rigid with the camera) to the anchors: they carry
    ``mask_sigma_m`` (a tube of the estimate's error round the whole tether would hold the
    camera, next to the attachment); the Anchorbots, placed from the anchors, carry
    ``mask_sigma_m`` and the estimate's error."""
    sc = cfg.cliffbot_sensing
    sig = sc.mask_sigma_m + math.sqrt(max(float(np.linalg.eigvalsh(P[:2, :2]).max()), 0.0))
    n = normal_from_attitude(float(s[2]), roll, pitch)
    fwd = np.array([math.cos(s[2]), math.sin(s[2]), 0.0])
    fwd = fwd - float(fwd @ n) * n
    fwd /= max(float(np.linalg.norm(fwd)), 1e-9)
    R = np.column_stack([fwd, np.cross(n, fwd), n])
    half = np.asarray(sc.body_half_m, float)
    ground = np.array([float(s[0]), float(s[1]), body_z])
    # the box from BODY_LIFT_M above its ground up (the ground round its wheels stays in the
    # views; the box's lowest edge mapped as ground is replaced by contact: fill_under_body)
    lift = np.array([half[0], half[1], 0.5 * (2 * half[2] - BODY_LIFT_M)])
    boxes = [BodyBox(ground + (BODY_LIFT_M + lift[2]) * n, R, lift, BODY_SIGMA_M, ground)]
    for a in np.asarray(anchors, float) - np.array([0.0, 0.0, cfg.tether.anchor_exit_m]):
        boxes.append(anchorbot_box(a, sig))
    attach = ground + np.array([0.0, 0.0, cfg.tether.attach_m])
    ts = None
    if plan_z is not None:
        ts = tether_state(plan_z, grid, anchors, s[:2], cfg.tether, cfg.climber.footprint_m)
    lines = []
    for k in range(2):
        mid = np.zeros((0, 3)) if ts is None else np.asarray(ts.paths[k].contacts, float).reshape(-1, 3)
        lines.append(TetherLine(np.vstack([anchors[k], mid, attach]), TETHER_RADIUS_M, sc.mask_sigma_m))
    return TeamGeometry(tuple(boxes), tuple(lines))
