"""The RECON-bot's fixer task: answers the Cliff-bot's fix requests (docs/team.md, "Relative localization").

A FIX_REQUEST the radio received (``radio.fix_request``; it carries the Cliff-bot's own
estimate ``x, y``) is answered once the RECON-bot's mission has ended (``mission.state`` is
``DONE``; before that the answer is NO_FIX ``busy``): the task points the mast at the
estimate through the motion task (a ``mast`` request; a pose outside the mast's limits is
NO_FIX ``out of the mast's reach``), asks the camera task for a pair (view id
``FIX_VIEW_BASE + seq``, which perception leaves out of the map), runs
:class:`~fsw.core.localization.fiducials.CliffbotLocalizer` (docs/algorithm.md §5) on it in a
slack job with the camera pose estimate and its covariance, and hands the FIX (position,
rotation, 6x6 covariance) or NO_FIX ``no markers seen`` to the radio, which sends it ahead of
map bytes (``radio.fix_out``). A request that arrives while one is being answered is told
``busy``; a step that does not finish within ``TIMEOUT_S`` ends in NO_FIX ``busy``.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Generator
from typing import ClassVar

import numpy as np

from fsw.comm.team import fix_packets
from fsw.core.geometry import MapGrid, point_mast
from fsw.core.localization.fiducials import BodyEstimate, CliffbotLocalizer
from fsw.core.localization.localization import PoseEstimate, so3_log
from fsw.core.map.elevation_map import ElevationMap
from fsw.core.stereo.rectify import Rectifier
from fsw.framework.jobs import JobHandle
from fsw.framework.telemetry import Channel, EventDef, Severity
from fsw.settings import load_stereo_calibration
from fsw.tasks.base import FlightTask
from fsw.tasks.messages import (
    CAMERA_FRAME,
    CAMERA_REQUEST,
    FIX_VIEW_BASE,
    MAP_UPDATED,
    MOTION_REQUEST,
    MOTION_STATUS,
    NAV_POSE,
    RADIO_FIX_OUT,
    RADIO_FIX_REQUEST,
    VIEW_FAILED,
    CameraFrame,
    CaptureRequest,
    MapUpdate,
    MotionRequest,
    MoveOutcome,
    NavPose,
)

NO_MARKERS, OUT_OF_REACH, BUSY = 0, 1, 2  # fix_packets.NO_FIX_REASONS
REQUEST_BASE = 1 << 30  # motion request ids of the fixer (the mission's count from 1)
TIMEOUT_S = 30.0
BODY_CENTRE_M = 0.25  # aim this far above the ground under the estimate (the marker band)
LIFT_M = 0.3


class CliffbotFixerTask(FlightTask):
    KIND: ClassVar[str] = "cliffbot_fixer"
    RATE_HZ: ClassVar[tuple[float, float]] = (5.0, 50.0)  # answers within the Cliff-bot's fix timeout
    REQUIRES: ClassVar[tuple[str, ...]] = ("radio", "motion", "camera")
    DOC: ClassVar[str] = "Relative localization: aims the mast at the Cliff-bot, locates its markers, answers FIX."
    CHANNELS = (
        Channel("phase", doc="idle, aim, capture, locate"),
        Channel("fixes", "count", doc="FIX answers sent"),
        Channel("no_fixes", "count", doc="NO_FIX answers sent"),
    )
    EVENTS = (
        EventDef("FIX_SENT", Severity.ACTIVITY_HI, "request {seq}: Cliff-bot at {x:.2f}, {y:.2f} m, heading "
                 "{yaw_deg:.1f} deg, sigma {sigma_cm:.1f} cm"),
        EventDef("NO_FIX_SENT", Severity.ACTIVITY_LO, "request {seq}: no fix ({reason})", throttle=10),
    )

    def setup(self) -> None:
        cfg = self.ctx.cfg
        self.loc = CliffbotLocalizer(cfg.localization, cfg.cliffbot, cfg.camera.K, cfg.camera.baseline_m)
        cal = load_stereo_calibration(cfg)  # the pairs are raw: rectified onto the configured camera first
        self.rectifier = Rectifier(cal, cfg.camera.K) if cal is not None else None
        self.grid = MapGrid.from_config(cfg.map)
        self.requests = self.subscribe(RADIO_FIX_REQUEST, depth=4)
        self.motion = self.subscribe(MOTION_STATUS, depth=8)
        self.frames = self.subscribe(CAMERA_FRAME, depth=2)
        self.failed = self.subscribe(VIEW_FAILED, depth=4)
        self.nav_box = self.subscribe(NAV_POSE, depth=1)
        self.map_box = self.subscribe(MAP_UPDATED, depth=1)
        self.pose: NavPose | None = None
        self.snapshot: ElevationMap | None = None
        self.current: fix_packets.FixRequest | None = None
        self.phase = "idle"
        self.deadline = 0.0
        self.request_id = REQUEST_BASE
        self.counts = {"fixes": 0, "no_fixes": 0}

    def run(self, frame: int) -> None:
        now = self.ctx.clock.now()
        pose = self.nav_box.latest()
        self.pose = pose if pose is not None else self.pose
        upd: MapUpdate | None = self.map_box.latest()
        self.snapshot = upd.snapshot if upd is not None else self.snapshot
        for req in self.requests.drain():
            if self.current is not None:
                if req.seq != self.current.seq:
                    self._no_fix(req.seq, BUSY)
            elif self._mission_state() != "DONE" or self.pose is None:
                self._no_fix(req.seq, BUSY)
            else:
                self._aim(req, now)
        if self.current is not None and now > self.deadline:
            self._no_fix(self.current.seq, BUSY)
        elif self.phase == "aim":
            self._aimed()
        elif self.phase == "capture":
            self._captured()
        self.tlm_record({"phase": self.phase, **self.counts})

    def _mission_state(self) -> str:
        try:
            return str(self.ctx.telemetry.get("mission.state"))
        except KeyError:
            return ""

    def _aim(self, req: fix_packets.FixRequest, now: float) -> None:
        assert self.pose is not None
        if not (math.isfinite(req.x) and math.isfinite(req.y)):
            self._no_fix(req.seq, OUT_OF_REACH)
            return
        p = self.pose
        ground = self._height(req.x, req.y)
        target = (req.x, req.y, (ground if math.isfinite(ground) else p.z_m) + BODY_CENTRE_M)
        joints, reachable = point_mast((p.x, p.y, p.yaw), target, self.ctx.cfg.mast, LIFT_M, ground_z_m=p.z_m)
        if not reachable:
            self._no_fix(req.seq, OUT_OF_REACH)
            return
        self.current, self.phase, self.deadline = req, "aim", now + TIMEOUT_S
        self.request_id += 1
        self.publish(MOTION_REQUEST, MotionRequest(self.request_id, "mast", joints=joints))

    def _height(self, x: float, y: float) -> float:
        if self.snapshot is None:
            return math.nan
        iy, ix, inside = self.grid.cell_index(np.array([x]), np.array([y]))
        return float(self.snapshot.z[iy[0], ix[0]]) if inside[0] else math.nan

    def _aimed(self) -> None:
        assert self.current is not None
        for st in self.motion.drain():
            if st.request_id != self.request_id:
                continue
            if st.state is not MoveOutcome.DONE:
                self._no_fix(self.current.seq, OUT_OF_REACH)
                return
            self.failed.drain()
            self.frames.drain()
            self.phase = "capture"
            self.publish(CAMERA_REQUEST, CaptureRequest(FIX_VIEW_BASE + self.current.seq))

    def _captured(self) -> None:
        assert self.current is not None
        view = FIX_VIEW_BASE + self.current.seq
        if any(f.view_id == view for f in self.failed.drain()):
            self._no_fix(self.current.seq, NO_MARKERS)
            return
        fr = next((f for f in self.frames.drain() if f.view_id == view), None)
        if fr is None:
            return
        self.phase = "locate"
        self.submit_job(self._locate(fr), f"fix{self.current.seq}",
                        on_done=functools.partial(self._located, self.current.seq, int(fr.time_s * 1000)))

    def _locate(self, fr: CameraFrame) -> Generator[None, None, BodyEstimate | None]:
        """The slack job: rectify the pair (when the camera has a calibration), find the markers, PnP."""
        yield
        left, right = fr.left, fr.right
        if self.rectifier is not None:
            left, right = self.rectifier.rectify(left, right)
            yield
        return self.loc.locate(left, PoseEstimate(fr.pose, np.asarray(fr.pose_cov, float)), right)

    def _located(self, seq: int, t_ms: int, handle: JobHandle) -> None:
        if self.current is None or self.current.seq != seq:
            return  # timed out meanwhile: already answered
        est: BodyEstimate | None = handle.result if handle.error is None else None
        if est is None or not np.isfinite(est.cov).all():
            self._no_fix(seq, NO_MARKERS)
            return
        fix = fix_packets.Fix(seq, t_ms, np.asarray(est.t, float), so3_log(est.R), np.asarray(est.cov, float))
        try:
            pkt = fix_packets.encode(fix)
        except ValueError:
            self._no_fix(seq, NO_MARKERS)
            return
        self.publish(RADIO_FIX_OUT, pkt)
        self.counts["fixes"] += 1
        sigma = math.sqrt(max(float(np.trace(est.cov[3:5, 3:5])), 0.0))
        self.event("FIX_SENT", seq=seq, x=float(est.t[0]), y=float(est.t[1]), yaw_deg=math.degrees(est.yaw),
                   sigma_cm=100 * sigma)
        self._idle()

    def _no_fix(self, seq: int, reason: int) -> None:
        self.publish(RADIO_FIX_OUT, fix_packets.encode(fix_packets.NoFix(seq, reason)))
        self.counts["no_fixes"] += 1
        self.event("NO_FIX_SENT", seq=seq, reason=fix_packets.NO_FIX_REASONS[reason])
        if self.current is not None and self.current.seq == seq:
            self._idle()

    def _idle(self) -> None:
        self.current, self.phase = None, "idle"
