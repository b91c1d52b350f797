"""The RECON-bot's fixer task: answers the Cliff-bot's fix requests (docs/team.md, "Relative localization").

A FIX_REQUEST the radio received (``radio.fix_request``; it carries the Cliff-bot's own
estimate ``x, y``) is answered once the RECON-bot's mission has ended (``mission.state`` is
``DONE``; before that the answer is NO_FIX ``busy``): the task points the mast at the
estimate through the motion task (a ``mast`` request; a pose outside the mast's limits is
NO_FIX ``out of the mast's reach``; when only the pan's range misses it, the RECON-bot
also turns its body in place toward it, a small turn, and answers the next request from there),
asks the camera task for a pair (view id
``FIX_VIEW_BASE + seq``, which perception leaves out of the map), runs
:class:`~fsw.core.localization.fiducials.CliffbotLocalizer` (docs/algorithm.md §5) on it in a
slack job with the camera pose estimate and its covariance, and hands the FIX (position,
rotation, 6x6 covariance) or NO_FIX ``no markers seen`` to the radio, which sends it ahead of
map bytes (``radio.fix_out``). A request that arrives while one is being answered is told
``busy``; a step that does not finish within ``TIMEOUT_S`` ends in NO_FIX ``busy``.

The camera pose comes from the RECON-bot's own estimate, which drifts over its mission; a fix
carries that error over its range. Before the first fix from where it stands, the task views the
Anchorbots' marker plates (``[localization] anchor_marker_ids``, placed from the tether exits of
``[cliffbot_site]``) and resects its camera in the team's frame on each plate it sees
(docs/algorithm.md §5.2, :mod:`fsw.core.localization.landmarks`); the fix's camera pose is then
the resected one carried through the mast's joints, with its covariance. The request waits for
those views (its answer's deadline starts when they are done); while the rover does not move,
later fixes reuse them; with no plate seen the fix uses the rover's estimate.

Every turn in place (toward the Cliff-bot or a plate) is first checked by the geofence as the
mission checks its own moves, on the mission's ground (``mission.ground``:
:func:`fsw.tasks.mission_ground.check_move`, a slack job): a turn sweeps the wheels over arcs
that can reach past the lip or onto unmapped ground. A refused turn is event ``TURN_REFUSED``
with the geofence's reason, never a move: the Cliff-bot stays ``out of the mast's reach``, and
a fix waiting for a turn toward a plate is made without it (on the rover's estimate).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Generator
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from fsw.comm.team import fix_packets
from fsw.core.edge.geofence import Verdict
from fsw.core.geometry import MapGrid, mast_angles, point_mast, wrap_angle
from fsw.core.localization.fiducials import BodyEstimate, CliffbotLocalizer
from fsw.core.localization.landmarks import Landmark, anchor_marker_corners
from fsw.core.localization.localization import PoseEstimate, so3_log
from fsw.core.map.elevation_map import ElevationMap
from fsw.core.stereo.rectify import Rectifier
from fsw.framework.jobs import JobHandle
from fsw.framework.telemetry import Channel, EventDef, Severity
from fsw.settings import load_stereo_calibration
from fsw.tasks.base import FlightTask
from fsw.tasks.fixer.fix_pose import fix_camera, frame_extra, joints_covariance
from fsw.tasks.messages import (
    CAMERA_FRAME,
    CAMERA_REQUEST,
    FIX_VIEW_BASE,
    MAP_UPDATED,
    MISSION_GROUND,
    MOTION_REQUEST,
    MOTION_STATUS,
    NAV_POSE,
    RADIO_FIX_OUT,
    RADIO_FIX_REQUEST,
    VIEW_FAILED,
    CameraFrame,
    CaptureRequest,
    MapUpdate,
    MissionGroundState,
    MotionRequest,
    MoveOutcome,
    NavPose,
)
from fsw.tasks.mission_ground import check_move

NO_MARKERS, OUT_OF_REACH, BUSY = 0, 1, 2  # fix_packets.NO_FIX_REASONS
REQUEST_BASE = 1 << 30  # motion request ids of the fixer (the mission's count from 1)
TIMEOUT_S = 30.0
BODY_CENTRE_M = 0.25  # aim this far above the ground under the estimate (the marker band)
LIFT_M = 0.3
TURN_MARGIN_DEG = 10.0  # a turn toward the Cliff-bot leaves its pan this far inside the mast's range
MAX_TURN_DEG = 45.0  # a larger turn is not made (the answer stays "out of the mast's reach")
SURVEY_VIEW = FIX_VIEW_BASE + (1 << 24)  # view ids of the views of the Anchorbots' plates


@dataclasses.dataclass(frozen=True)
class Shot:
    """One view of a fix: of an Anchorbot's plate (``kind`` ``"anchor"``) or of the Cliff-bot."""

    kind: str
    view_id: int
    target: tuple[float, float, float]  # what the mast points at (team frame)
    plate: int = -1  # the plate's marker id (a view of a plate)


class CliffbotFixerTask(FlightTask):
    KIND: ClassVar[str] = "cliffbot_fixer"
    RATE_HZ: ClassVar[tuple[float, float]] = (5.0, 50.0)  # answers within the Cliff-bot's fix timeout
    REQUIRES: ClassVar[tuple[str, ...]] = ("radio", "motion", "camera")
    DOC: ClassVar[str] = "Relative localization: aims the mast at the Cliff-bot, locates its markers, answers FIX."
    CHANNELS = (
        Channel("phase", doc="idle, aim, capture, locate, turn"),
        Channel("fixes", "count", doc="FIX answers sent"),
        Channel("no_fixes", "count", doc="NO_FIX answers sent"),
        Channel("landmarks", "count", doc="views of the Anchorbots' plates the current standing's fixes use"),
    )
    EVENTS = (
        EventDef("FIX_SENT", Severity.ACTIVITY_HI, "request {seq}: Cliff-bot at {x:.2f}, {y:.2f} m, heading "
                 "{yaw_deg:.1f} deg, sigma {sigma_cm:.1f} cm, {basis}"),
        EventDef("NO_FIX_SENT", Severity.ACTIVITY_LO, "request {seq}: no fix ({reason})", throttle=10),
        EventDef("TURN_TO_CLIFFBOT", Severity.ACTIVITY_HI, "request {seq}: the Cliff-bot is {pan_deg:.0f} deg "
                 "off the body, out of the mast's pan: turning {turn_deg:+.1f} deg in place"),
        EventDef("TURNED", Severity.ACTIVITY_LO, "turn {outcome}{why}"),
        EventDef("TURN_REFUSED", Severity.WARNING_LO, "turn {turn_deg:+.1f} deg in place not made: {reason}",
                 throttle=10),
        EventDef("TURN_TO_PLATE", Severity.ACTIVITY_HI, "no plate resected; plate {plate} is out of the mast's "
                 "pan: turning {turn_deg:+.1f} deg in place, then viewing the plates again"),
        EventDef("LANDMARKS", Severity.ACTIVITY_LO, "camera resected on plates {ids} ({n} of {views} views): yaw "
                 "{dyaw_deg:+.2f} deg, {dxy_cm:.1f} cm from the rover's estimate{missed}"),
        EventDef("NO_LANDMARKS", Severity.WARNING_LO, "no Anchorbot plate resected ({missed}): this standing's "
                 "fixes rest on the rover's estimate"),
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
        self.ground_box = self.subscribe(MISSION_GROUND, depth=1)
        self.ground: MissionGroundState | None = None  # what the mission's geofence stands on
        self.pose: NavPose | None = None
        self.snapshot: ElevationMap | None = None
        self.current: fix_packets.FixRequest | None = None
        self.phase = "idle"
        self.deadline = 0.0
        self.request_id = REQUEST_BASE
        self.counts = {"fixes": 0, "no_fixes": 0}
        site = cfg.cliffbot_site
        self.plates = anchor_marker_corners(site.anchor_a_xyz, site.anchor_b_xyz, cfg.localization)
        self.shots: list[Shot] = []
        self.shot: Shot | None = None
        self.landmarks: list[Landmark] = []
        self.standing: tuple[float, ...] | None = None  # the rover's pose the landmarks were seen from
        self.surveyed = 0
        self.surveying = False
        self.missed: dict[int, str] = {}  # the plates of the last survey not resected, and why
        self.plate_turned = -1  # the request a turn toward a plate was made for (one per request)
        self.resurveyed = -1  # the request whose plates were viewed again (the estimate moved meanwhile)
        self.pending: fix_packets.FixRequest | None = None  # a request held while the plates are viewed
        self.turn_id: int | None = None  # the motion request of a turn toward the Cliff-bot

    def run(self, frame: int) -> None:
        now = self.ctx.clock.now()
        pose = self.nav_box.latest()
        self.pose = pose if pose is not None else self.pose
        upd: MapUpdate | None = self.map_box.latest()
        self.snapshot = upd.snapshot if upd is not None else self.snapshot
        self.ground = self.ground_box.latest() or self.ground
        ready = self._mission_state() == "DONE" and self.pose is not None
        for req in self.requests.drain():
            if self.turn_id is not None:
                if self.pending is None or self.pending.seq != req.seq:  # (a turn toward a plate: it waits)
                    self._no_fix(req.seq, BUSY)  # turning toward it: the next request is answered from there
            elif self.current is not None:
                if req.seq != self.current.seq:
                    self._no_fix(req.seq, BUSY)
            elif not ready:
                self._no_fix(req.seq, BUSY)
            elif self.surveying:
                if self.pending is not None and self.pending.seq != req.seq:
                    self._no_fix(req.seq, BUSY)
                else:
                    self.pending = req  # answered once the plates are seen
            elif self.plates and self._standing() != self.standing:
                self.pending = req  # the first fix from here: see the plates first, then answer it
                self._survey(now)
            else:
                self._aim(req, now)
        if (self.current is not None or self.surveying) and now > self.deadline:
            if self.current is not None:
                self._no_fix(self.current.seq, BUSY)
            else:
                self._survey_done()
        elif self.turn_id is not None:
            self._turned(now)
        elif self.phase == "aim":
            self._aimed()
        elif self.phase == "capture":
            self._captured()
        self.tlm_record({"phase": self.phase, **self.counts, "landmarks": len(self.landmarks)})

    def _mission_state(self) -> str:
        try:
            return str(self.ctx.telemetry.get("mission.state"))
        except KeyError:
            return ""

    def _survey(self, now: float) -> None:
        """View each Anchorbot's plate from where the rover stands (§5.2)."""
        self.landmarks, self.standing, self.missed = [], self._standing(), {}
        self.shots = [Shot("anchor", SURVEY_VIEW + (self.surveyed + k) % (1 << 20),
                           (float(c[:, 0].mean()), float(c[:, 1].mean()), float(c[:, 2].mean())), mid)
                      for k, (mid, c) in enumerate(self.plates.items())]
        self.surveyed += len(self.shots)
        self.surveying, self.deadline = True, now + TIMEOUT_S
        self._next_shot()

    def _survey_done(self) -> None:
        self.surveying, self.shot, self.shots, self.phase = False, None, [], "idle"
        if self.pending is not None and self._standing() != self.standing and self.resurveyed != self.pending.seq:
            # the rover's estimate changed while its plates were viewed (a turn's last odometry came
            # after the survey began): the views are of no one standing; view them again, once
            self.resurveyed = self.pending.seq
            self._survey(self.ctx.clock.now())
            return
        self._report_landmarks()
        req, self.pending = self.pending, None
        if req is not None and not self.landmarks and self._turn_to_plate(req):
            self.pending = req  # answered from the new standing, once its plates are viewed
        elif req is not None:
            self._aim(req, self.ctx.clock.now())

    def _turn_to_plate(self, req: fix_packets.FixRequest) -> bool:
        """With no plate resected and a plate beyond the mast's pan only: turn the body in place
        the least that brings it ``TURN_MARGIN_DEG`` inside the pan's range (at most
        ``MAX_TURN_DEG``), when the Cliff-bot stays within the pan's range after it; once per
        request (``plate_turned``). True when the turn was asked for."""
        if self.plate_turned == req.seq or self.pose is None:
            return False
        cb = self._target(req)
        if cb is None:
            return False
        mast = self.ctx.cfg.mast
        lo, hi = math.radians(mast.pan_min_deg), math.radians(mast.pan_max_deg)
        cb_pan = self._angles(cb)[0]
        best: tuple[float, int] | None = None
        for mid, c in self.plates.items():
            if self.missed.get(mid) != "out of the mast's reach":
                continue
            turn = self._least_turn((float(c[:, 0].mean()), float(c[:, 1].mean()), float(c[:, 2].mean())))
            if turn is None or not lo <= wrap_angle(cb_pan - turn) <= hi:
                continue
            if best is None or abs(turn) < abs(best[0]):
                best = (turn, mid)
        if best is None:
            return False
        self.plate_turned = req.seq
        self._start_turn(best[0], self.ctx.clock.now())
        self.event("TURN_TO_PLATE", plate=best[1], turn_deg=math.degrees(best[0]))
        return True

    def _aim(self, req: fix_packets.FixRequest, now: float) -> None:
        assert self.pose is not None
        target = self._target(req)
        if target is None:
            self._no_fix(req.seq, OUT_OF_REACH)
            return
        if self._joints(target) is None:
            self._no_fix(req.seq, OUT_OF_REACH)
            self._turn_toward(req.seq, target, now)
            return
        if self._standing() != self.standing:
            self.landmarks = []  # seen from elsewhere: this fix rests on the rover's estimate
        self.current, self.deadline = req, now + TIMEOUT_S
        self.shots = [Shot("cliffbot", FIX_VIEW_BASE + req.seq, target)]
        self._next_shot()

    def _target(self, req: fix_packets.FixRequest) -> tuple[float, float, float] | None:
        """Where the mast aims for a request: its estimate, ``BODY_CENTRE_M`` above the map's ground
        there (the rover's height off the map); None for a non-finite estimate."""
        assert self.pose is not None
        if not (math.isfinite(req.x) and math.isfinite(req.y)):
            return None
        ground = self._height(req.x, req.y)
        return req.x, req.y, (ground if math.isfinite(ground) else self.pose.z_m) + BODY_CENTRE_M

    def _angles(self, target: tuple[float, float, float]) -> tuple[float, float]:
        assert self.pose is not None
        p = self.pose
        return mast_angles((p.x, p.y, p.yaw), target, self.ctx.cfg.mast, LIFT_M, p.z_m, (p.roll, p.pitch))

    def _least_turn(self, target: tuple[float, float, float]) -> float | None:
        """The least turn in place that puts the pan to ``target`` ``TURN_MARGIN_DEG`` inside the
        mast's range, when the pan range, not the tilt, is what it misses and the turn is at most
        ``MAX_TURN_DEG``; None otherwise (or when the pan reaches it already)."""
        mast = self.ctx.cfg.mast
        pan, tilt = self._angles(target)
        if not math.radians(mast.tilt_min_deg) <= tilt <= math.radians(mast.tilt_max_deg):
            return None  # below or above the tilt's range: a turn does not bring it in
        lo = math.radians(mast.pan_min_deg + TURN_MARGIN_DEG)
        hi = math.radians(mast.pan_max_deg - TURN_MARGIN_DEG)
        turn = pan - hi if pan > hi else pan - lo if pan < lo else 0.0
        return None if turn == 0.0 or abs(turn) > math.radians(MAX_TURN_DEG) else turn

    def _start_turn(self, turn: float, now: float) -> None:
        """Check the turn in place with the geofence (module docstring), in slack; made once allowed."""
        assert self.pose is not None
        p = self.pose
        self.request_id += 1
        self.turn_id, self.phase, self.deadline = self.request_id, "turn", now + TIMEOUT_S
        self.motion.drain()
        self.submit_job(check_move(self.ctx.cfg, self.ground, p, (p.x, p.y, p.yaw + turn)), f"turn{self.turn_id}",
                        on_done=functools.partial(self._turn_checked, self.turn_id, turn))

    def _turn_checked(self, turn_id: int, turn: float, handle: JobHandle) -> None:
        if self.turn_id != turn_id:
            return  # timed out meanwhile
        verdict: Verdict | None = handle.result if handle.error is None else None
        if verdict is not None and verdict.allowed:
            self.publish(MOTION_REQUEST, MotionRequest(turn_id, "turn", angle_rad=turn))
            return
        reason = verdict.reason if verdict is not None else f"geofence check failed: {handle.error!r}"
        self.event("TURN_REFUSED", turn_deg=math.degrees(turn), reason=reason)
        self._turn_ended(self.ctx.clock.now(), turned=False)

    def _turn_toward(self, seq: int, target: tuple[float, float, float], now: float) -> None:
        """Turn the body in place so that the mast's pan reaches ``target`` (the request after the
        turn is answered from there): :meth:`_least_turn`. The geofence checks it first
        (:meth:`_start_turn`), then the motion task makes it with its own checks (it refuses or
        aborts a turn it may not make; event ``TURNED``)."""
        turn = self._least_turn(target)
        if turn is None:
            return
        self._start_turn(turn, now)
        self.event("TURN_TO_CLIFFBOT", seq=seq, pan_deg=math.degrees(self._angles(target)[0]),
                   turn_deg=math.degrees(turn))

    def _turned(self, now: float) -> None:
        for st in self.motion.drain():
            if st.request_id == self.turn_id:
                self.event("TURNED", outcome=str(st.state), why=f": {st.reason}" if st.reason else "")
                self._turn_ended(now)
                return
        if now > self.deadline:
            self.event("TURNED", outcome="not confirmed", why=f" within {TIMEOUT_S:.0f} s")
            self._turn_ended(now)

    def _turn_ended(self, now: float, turned: bool = True) -> None:
        self.turn_id, self.phase = None, "idle"
        if self.pending is not None and turned:  # a turn toward a plate: view the plates from here, then answer
            self._survey(now)
        elif self.pending is not None:  # not turned: the fix from here, without the plate
            req, self.pending = self.pending, None
            self._aim(req, now)

    def _standing(self) -> tuple[float, ...]:
        p = self.pose
        assert p is not None
        return (p.x, p.y, p.yaw, p.z_m, float(p.fix_id))

    def _joints(self, target: tuple[float, float, float]) -> tuple[float, float, float] | None:
        """The mast's joints that point the camera at ``target`` from the rover's estimate, its body
        attitude included (a rover standing tilted, e.g. a wheel over the lip, aims as it stands);
        None when out of its reach."""
        assert self.pose is not None
        p = self.pose
        joints, reachable = point_mast((p.x, p.y, p.yaw), target, self.ctx.cfg.mast, LIFT_M, p.z_m,
                                       (p.roll, p.pitch))
        return joints if reachable else None

    def _next_shot(self) -> None:
        """Point the mast for the next view (a plate out of the mast's reach is skipped)."""
        while self.shots:
            shot = self.shots.pop(0)
            joints = self._joints(shot.target)
            if joints is None:
                if shot.kind == "cliffbot":
                    assert self.current is not None
                    self._no_fix(self.current.seq, OUT_OF_REACH)
                    return
                self.missed[shot.plate] = "out of the mast's reach"
                continue
            self.shot, self.phase = shot, "aim"
            self.request_id += 1
            self.publish(MOTION_REQUEST, MotionRequest(self.request_id, "mast", joints=joints))
            return
        if self.surveying:
            self._survey_done()

    def _shot_failed(self, reason: int) -> None:
        if self.surveying:
            if self.shot is not None:
                self.missed[self.shot.plate] = "no view" if reason == NO_MARKERS else "mast not pointed"
            self._next_shot()  # that plate is not seen
        elif self.current is not None:
            self._no_fix(self.current.seq, reason)

    def _aimed(self) -> None:
        assert self.shot is not None
        for st in self.motion.drain():
            if st.request_id != self.request_id:
                continue
            if st.state is not MoveOutcome.DONE:
                self._shot_failed(OUT_OF_REACH)
                return
            self.failed.drain()
            self.frames.drain()
            self.phase = "capture"
            self.publish(CAMERA_REQUEST, CaptureRequest(self.shot.view_id))

    def _captured(self) -> None:
        assert self.shot is not None
        view, shot = self.shot.view_id, self.shot
        if any(f.view_id == view for f in self.failed.drain()):
            self._shot_failed(NO_MARKERS)
            return
        fr = next((f for f in self.frames.drain() if f.view_id == view), None)
        if fr is None:
            return
        self.phase = "locate"
        if shot.kind == "anchor":
            self.submit_job(self._resect(fr, self._joints_cov()), f"plates{view - SURVEY_VIEW}",
                            on_done=functools.partial(self._resected, view))
            return
        assert self.current is not None
        ids = self.plate_ids()
        basis = f"on plates {ids}" if ids else "on the rover's estimate"
        assert self.pose is not None
        self.submit_job(self._locate(fr, self._joints_cov(), frame_extra(self.pose, self.ctx.cfg),
                                     self.current.attitude),
                        f"fix{self.current.seq}",
                        on_done=functools.partial(self._located, self.current.seq, int(fr.time_s * 1000), basis))

    def _height(self, x: float, y: float) -> float:
        if self.snapshot is None:
            return math.nan
        iy, ix, inside = self.grid.cell_index(np.array([x]), np.array([y]))
        return float(self.snapshot.z[iy[0], ix[0]]) if inside[0] else math.nan

    def _joints_cov(self) -> NDArray[np.float64]:
        assert self.pose is not None
        return joints_covariance(self.pose, self.ctx.cfg)

    def _pair(self, fr: CameraFrame) -> Generator[None, None, tuple[NDArray[np.uint8], NDArray[np.uint8]]]:
        left, right = fr.left, fr.right
        if self.rectifier is not None:
            left, right = self.rectifier.rectify(left, right)
            yield
        return left, right

    def _resect(self, fr: CameraFrame, joints_cov: NDArray[np.float64]
                ) -> Generator[None, None, Landmark | None]:
        """The slack job of a view of the plates: the camera resected on the plates it sees."""
        yield
        left, right = yield from self._pair(fr)
        got = self.loc.camera_in(self.plates, left, right)
        if got is None or not np.isfinite(got[0].cov).all():
            return None
        return Landmark(got[0], fr.pose, joints_cov, got[1])

    def _resected(self, view: int, handle: JobHandle) -> None:
        if not self.surveying or self.shot is None or self.shot.view_id != view:
            return  # the survey timed out meanwhile
        got: Landmark | None = handle.result if handle.error is None else None
        if got is not None:
            self.landmarks.append(got)
        else:
            self.missed[self.shot.plate] = "not detected"
        self._next_shot()

    def _report_landmarks(self) -> None:
        missed = ", ".join(f"{mid} {why}" for mid, why in sorted(self.missed.items())
                           if not any(mid in lm.ids for lm in self.landmarks))
        if not self.landmarks:
            self.event("NO_LANDMARKS", missed=missed or "no plate configured")
            return
        lm = self.landmarks[0]
        dR = lm.measured.pose.R @ lm.predicted.R.T
        self.event("LANDMARKS", ids=self.plate_ids(), n=len(self.landmarks), views=len(self.plates),
                   dyaw_deg=math.degrees(math.atan2(dR[1, 0], dR[0, 0])),
                   dxy_cm=100 * float(np.linalg.norm((lm.measured.pose.t - lm.predicted.t)[:2])),
                   missed=f"; not {missed}" if missed else "")

    def plate_ids(self) -> str:
        """The plates this standing's fixes rest on (``"11, 12"``; empty: none)."""
        return ", ".join(str(i) for i in sorted({i for lm in self.landmarks for i in lm.ids}))

    def camera_estimate(self, fr: CameraFrame, joints_cov: NDArray[np.float64],
                        extra: NDArray[np.float64] | None = None) -> PoseEstimate:
        """The camera pose of the fix's view: from the views of the plates when there are any
        (each carried to this view, fused), else the rover's estimate with its covariance against
        the team's frame (``extra``: :func:`frame_extra`)."""
        return fix_camera(self.landmarks, fr.pose, fr.pose_cov, joints_cov, extra)

    def _locate(self, fr: CameraFrame, joints_cov: NDArray[np.float64], extra: NDArray[np.float64],
                attitude: tuple[float, float] | None) -> Generator[None, None, BodyEstimate | None]:
        """The slack job: rectify the pair (when the camera has a calibration), find the markers, PnP
        (the pose whose tilt agrees with the request's ``attitude``, roll and pitch, when it has one)."""
        yield
        left, right = yield from self._pair(fr)
        return self.loc.locate(left, self.camera_estimate(fr, joints_cov, extra), right, attitude)

    def _located(self, seq: int, t_ms: int, basis: str, handle: JobHandle) -> None:
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
                   sigma_cm=100 * sigma, basis=basis)
        self._idle()

    def _no_fix(self, seq: int, reason: int) -> None:
        self.publish(RADIO_FIX_OUT, fix_packets.encode(fix_packets.NoFix(seq, reason)))
        self.counts["no_fixes"] += 1
        self.event("NO_FIX_SENT", seq=seq, reason=fix_packets.NO_FIX_REASONS[reason])
        if self.current is not None and self.current.seq == seq:
            self._idle()

    def _idle(self) -> None:
        self.current, self.phase, self.shot, self.shots = None, "idle", None, []
