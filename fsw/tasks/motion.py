"""Moves the wheels (CAN motor driver) and the mast (serial driver); keeps the odometry.

Thin: the profile is ``fsw.core.motion.motion_profile``, dead reckoning ``fsw.core.localization.odometry``, the
kinematics ``fsw.core.motion.wheel_kinematics``; the drivers do the bytes. Moves come as ground
commands (DRIVE, TURN, GOTO, POINT_MAST, STOP, ESTOP, CLEAR_FAULTS, ...) or as
``MotionRequest`` messages on ``motion.request`` (the mission sequencer; docs/algorithm.md §3:
"move (mast + wheels)"), each answered once on ``motion.status`` (a ``MoveOutcome``). A
critical driver fault aborts the move and stops the drives; moves are refused until
CLEAR_FAULTS. Every frame the task publishes the dead-reckoned pose with its covariance and
the mast joints on ``nav.pose`` and sends the commands (``motors.transmit``). Schedule it
after the device components in the fast group (it polls the drivers itself otherwise).
"""

from __future__ import annotations

import math
from collections import deque
from typing import ClassVar, TypeVar

import numpy as np
from numpy.typing import NDArray

from fsw.core.localization.attitude import AttitudeTracker
from fsw.core.localization.nav_fix import NavFix, apply_to_body
from fsw.core.localization.odometry import Odometry
from fsw.core.motion import motion_profile as mp
from fsw.core.motion import wheel_kinematics as wk
from fsw.drivers import can_motors, mast_serial
from fsw.framework.commands import CommandError
from fsw.tasks import motion_dictionary as md
from fsw.tasks import motion_state
from fsw.tasks.base import FlightTask
from fsw.tasks.messages import (
    MOTION_REQUEST,
    MOTION_STATUS,
    NAV_FIX,
    NAV_POSE,
    MotionRequest,
    MotionStatus,
    MoveOutcome,
    NavPose,
)
from fsw.tasks.mission_state import restore_into
from fsw.tasks.motion_state import AttitudeSection, MotionSection
from fsw.tasks.state_json import JsonObject

WHEELS = wk.WHEEL_ORDER
D = TypeVar("D")


class MotionTask(FlightTask):
    KIND: ClassVar[str] = "motion"
    RATE_HZ: ClassVar[tuple[float, float]] = (5.0, 50.0)  # its timeouts and moves assume ~10 Hz
    REQUIRES: ClassVar[tuple[str, ...]] = ("can_motors_device", "mast_device", "imu_device")
    DOC: ClassVar[str] = "Wheel and mast moves through the drivers; odometry; motion fault handling."
    CHANNELS, EVENTS, COMMANDS = md.CHANNELS, md.EVENTS, md.COMMANDS

    def setup(self) -> None:
        cfg = self.ctx.cfg
        self.mcfg: mp.MotionConfig = cfg.motion
        self.r = cfg.rover.wheel_diameter_m / 2.0
        self.wheel_xy = wk.wheel_positions(cfg.rover)
        self.odo = Odometry(self.r, wk.body_motion_matrix(self.wheel_xy))
        cap = cfg.capture
        self.attitude = AttitudeTracker(cap.unknown_attitude_sigma_deg, cap.z_sigma_per_m)
        self.segments: deque[mp.Segment] = deque()
        self.active: tuple[int, str] | None = None  # (request id, kind) of the wheel move
        self.mast_goal: tuple[int, tuple[float, float, float], float] | None = None
        self.steer_hold = np.zeros(4)
        self.done = self.aborted = 0
        self.requests = self.subscribe(MOTION_REQUEST, depth=8)
        self.fixes = self.subscribe(NAV_FIX, depth=4)
        self.fix_pending: deque[NavFix] = deque()  # applied between moves, in order
        self.fix_id = self.fix_seen = 0  # the last navigation fix applied / received
        self._warned: set[str] = set()
        restore_into(self)  # a resumed mission (fsw.tasks.mission_state)

    # -- a resumed mission's odometry, encoder baseline and held set-points (fsw.tasks.motion_state) --
    def checkpoint_state(self) -> JsonObject:
        """The odometry (``Odometry.state``), move counters, held steering and motor set-points."""
        motors = self._motors()
        h = [float(v) for v in self.steer_hold]
        return MotionSection(self.odo.state(), AttitudeSection.of(self.attitude), self.done, self.aborted,
                             (h[0], h[1], h[2], h[3]), self.fix_id, self.fix_seen,
                             None if motors is None else dict(motors.setpoints)).to_json()

    def restore_state(self, st: JsonObject) -> None:
        s = motion_state.section(st)
        s.apply_odometry(self.odo)
        self.fix_id, self.fix_seen = s.fix_id, s.fix_seen
        if s.attitude is not None:  # the attitude sensor's last reading and the dead-reckoned body height
            s.attitude.apply(self.attitude)
        self.done, self.aborted = s.done, s.aborted
        self.steer_hold = np.asarray(s.steer_hold, dtype=np.float64)
        motors = self._motors()
        if motors is not None and s.setpoints is not None:  # hold what was held (wheels still)
            for axis, sp in s.setpoints.items():
                motors.set_setpoint(axis, sp)

    # -- devices ----------------------------------------------------------------------------
    def _motors(self) -> can_motors.CanMotorDriver | None:
        return self._warn_absent("motors", self.ctx.res.motors)

    def _mast(self) -> mast_serial.MastSerialDriver | None:
        return self._warn_absent("mast", self.ctx.res.mast)

    def _warn_absent(self, key: str, driver: D | None) -> D | None:
        if driver is None and key not in self._warned:
            self._warned.add(key)
            self.event("NO_DEVICE", device=key)
        return driver

    # -- the frame --------------------------------------------------------------------------
    def run(self, frame: int) -> None:
        now = self.ctx.clock.now()
        motors, mast = self._motors(), self._mast()
        for drv in (motors, mast):
            if drv is not None and drv.last_poll_s != now:
                drv.poll(now)
        if motors is not None:
            self._odometry(motors)
        self.fix_pending.extend(self.fixes.drain())
        while self.fix_pending and self.active is None and not self.segments:
            self._apply_fix(self.fix_pending.popleft())  # before a request plans from the pose
        while (req := self.requests.get()) is not None:
            self._on_request(req, now)
        if motors is not None:
            if self.active is not None and motors.faults & can_motors.CRITICAL:
                self._abort("motor faults: " + ",".join(motors.fault_names()))
            self._control(motors, now)
            motors.transmit(now)
        self._track_mast(mast, now)
        self._publish(now, mast)

    def _apply_fix(self, fix: NavFix) -> None:
        """A registered view's correction of the pose (docs/algorithm.md §5.1, ``fsw.core.localization.nav_fix``),
        between moves; only on the frame it was found in (``base_id``), else refused."""
        self.fix_seen = max(self.fix_seen, fix.fix_id)
        if fix.base_id != self.fix_id or not fix.valid():
            why = "invalid" if not fix.valid() else f"found on fix {fix.base_id}, pose holds {self.fix_id}"
            self.event("NAV_FIX_REFUSED", fix=fix.fix_id, reason=why)
            return
        before = self.odo.pose
        pose, cov = apply_to_body(before, fix)
        self.odo.correct(pose, cov)
        a = self.attitude
        a.reset(a.z_m + fix.dt[2], math.sqrt(max(float(fix.cov[3, 3]), 0.0)))
        self.fix_id = fix.fix_id
        self.event("NAV_FIXED", fix=fix.fix_id, dxy_cm=100 * math.hypot(pose[0] - before[0], pose[1] - before[1]),
                   dyaw=math.degrees(math.remainder(pose[2] - before[2], math.tau)), dz_cm=100 * fix.dt[2],
                   sxy_cm=100 * math.sqrt(max(0.0, 0.5 * (cov[0, 0] + cov[1, 1]))))

    def _odometry(self, motors: can_motors.CanMotorDriver) -> None:
        drive = [motors.axes[f"DRIVE_{w}"] for w in WHEELS]
        steer = [motors.axes[f"STEER_{w}"] for w in WHEELS]
        if any(s.t_status is None for s in drive + steer):
            return
        yaw0 = self.odo.pose[2]
        motion = self.odo.update([s.position_rad for s in drive], [s.position_rad for s in steer])
        if motion is not None:
            self.attitude.integrate(motion, yaw0)

    def _control(self, motors: can_motors.CanMotorDriver, now: float) -> None:
        seg = self.segments[0] if self.segments else None
        rates = np.zeros(4)
        if seg is not None:
            rates = self._segment(seg, motors, now)
        if self.active is not None or motors.setpoints["DRIVE_FL"] is not None:
            for i, w in enumerate(WHEELS):
                motors.set_setpoint(f"DRIVE_{w}", float(rates[i]))
                motors.set_setpoint(f"STEER_{w}", float(self.steer_hold[i]))

    def _segment(self, seg: mp.Segment, motors: can_motors.CanMotorDriver, now: float) -> NDArray[np.float64]:
        c = self.mcfg
        self.steer_hold = seg.steer
        if seg.phase == "steer":
            meas = np.array([motors.axes[f"STEER_{w}"].position_rad for w in WHEELS])
            if np.all(np.abs(meas - seg.steer) <= math.radians(c.steer_tolerance_deg)):
                seg.phase, seg.t_phase, seg.origin, seg.yaw_acc0 = "move", now, self.odo.pose, self.odo.yaw_acc
            elif now - seg.t_phase > c.steer_timeout_s:
                self._abort(f"steering not reached in {c.steer_timeout_s:.1f} s")
            return np.zeros(4)
        rem, tol, acc, vmin = mp.remaining(seg, self.odo.pose, self.odo.yaw_acc, c, self.wheel_xy)
        self.tlm("remaining", rem if seg.kind == "drive" else math.degrees(rem))
        if mp.arrived(seg, rem, tol):
            self.segments.popleft()
            if not self.segments:
                self._finish()
            else:  # the next segment's steering time starts now, not when the move began
                self.segments[0].t_phase = now
            return np.zeros(4)
        speed = mp.ramp_speed(seg, rem, acc, vmin, self.ctx.frame_period_s)
        self.tlm("cmd_speed", speed)
        v = math.copysign(speed, rem)
        _, rates = (
            wk.wheel_commands(v, 0.0, 0.0, self.wheel_xy, self.r)
            if seg.kind == "drive"
            else wk.wheel_commands(0.0, 0.0, v, self.wheel_xy, self.r, seg.steer)
        )
        return rates

    # -- starting and ending moves --------------------------------------------------------
    def _refuse_if_unsafe(self) -> None:
        motors = self._motors()
        if motors is None:
            raise CommandError("no motor driver configured")
        if motors.estopped:
            raise CommandError("emergency stop engaged")
        if motors.faults & can_motors.CRITICAL:
            raise CommandError("motor faults: " + ",".join(motors.fault_names()) + " (CLEAR_FAULTS)")

    def _start(self, rid: int, kind: str, segs: mp.SegmentPlan, what: str) -> None:
        self._refuse_if_unsafe()
        if self.active is not None:
            self._abort("superseded")
        now = self.ctx.clock.now()
        for skind, amount, speed in segs:
            if skind == "drive":
                steer = np.zeros(4)
            else:
                steer, _ = wk.wheel_commands(0.0, 0.0, 1.0, self.wheel_xy, self.r)
            self.segments.append(mp.Segment(skind, amount, speed, steer, t_phase=now))
        self.active = (rid, kind)
        self.event("MOVE_STARTED", kind=kind, rid=rid, what=what)
        if not self.segments:
            self._finish()

    def _finish(self) -> None:
        if self.active is None:
            return
        rid, kind = self.active
        self.active = None
        self.done += 1
        x, y, yaw = self.odo.pose
        self.event("MOVE_DONE", kind=kind, rid=rid, x=x, y=y, yaw=math.degrees(yaw))
        self._status(rid, kind, MoveOutcome.DONE)

    def _abort(self, reason: str) -> None:
        self.segments.clear()
        if self.active is None:
            return
        rid, kind = self.active
        self.active = None
        self.aborted += 1
        self.event("MOVE_ABORTED", kind=kind, rid=rid, reason=reason)
        self._status(rid, kind, MoveOutcome.ABORTED, reason)

    def _status(self, rid: int, kind: str, outcome: MoveOutcome, reason: str = "") -> None:
        self.publish(MOTION_STATUS, MotionStatus(rid, kind, outcome, reason, self.ctx.clock.now()))

    def _point_mast(self, rid: int, pan: float, tilt: float, lift: float) -> None:
        mast = self._mast()
        if mast is None:
            raise CommandError("no mast driver configured")
        if not self.ctx.cfg.mast.within_limits(pan, tilt, lift):
            raise CommandError("mast joints outside the limits of [mast]")
        if mast.faults & mast_serial.CRITICAL:
            raise CommandError("mast faults: " + ",".join(mast.fault_names()) + " (CLEAR_FAULTS)")
        mast.move(pan, tilt, lift)
        self.mast_goal = (rid, (pan, tilt, lift), self.ctx.clock.now())

    def _track_mast(self, mast: mast_serial.MastSerialDriver | None, now: float) -> None:
        if self.mast_goal is None or mast is None:
            return
        rid, goal, t0 = self.mast_goal
        c = self.mcfg
        verdict = mast_serial.move_progress(
            mast, goal, now - t0, math.radians(c.mast_tolerance_deg), c.mast_lift_tolerance_m, c.mast_timeout_s
        )
        if verdict == "moving":
            return
        self.mast_goal = None
        if verdict == "arrived":
            assert mast.joints is not None
            q = mast.joints
            self.done += 1
            self.event("MAST_POINTED", pan=math.degrees(q[0]), tilt=math.degrees(q[1]), lift=q[2])
            self._status(rid, "mast", MoveOutcome.DONE)
        else:
            self.aborted += 1
            self.event("MOVE_ABORTED", kind="mast", rid=rid, reason=verdict)
            self._status(rid, "mast", MoveOutcome.ABORTED, verdict)

    def _publish(self, now: float, mast: mast_serial.MastSerialDriver | None) -> None:
        x, y, yaw = self.odo.pose
        self.tlm(
            "state",
            "ESTOP"
            if (m := self.ctx.res.motors) is not None and m.estopped
            else (
                self.segments[0].kind.upper()
                if self.segments and self.segments[0].phase == "move"
                else "STEER"
                if self.segments
                else "IDLE"
            ),
        )
        self.tlm_record({"odo_x_m": x, "odo_y_m": y, "odo_yaw_deg": math.degrees(yaw),
                         "odo_path_m": self.odo.path_m, "mast_busy": int(self.mast_goal is not None),
                         "moves_done": self.done, "moves_aborted": self.aborted})
        joints = mast.joints if mast is not None and mast.joints is not None else (math.nan,) * 3
        imu = self.ctx.res.imu
        self.attitude.update(imu.attitude(now) if imu is not None else None)
        att = self.attitude.state()
        self.publish(
            NAV_POSE,
            NavPose(
                now,
                x,
                y,
                yaw,
                self.odo.covariance(self.mcfg),
                joints,
                moving=self.active is not None or self.mast_goal is not None,
                roll=att.roll,
                pitch=att.pitch,
                z_m=att.z_m,
                att_cov=att.cov,
                attitude_valid=att.valid,
                fix_id=self.fix_id,
                fix_seen=self.fix_seen,
                frame_cov=self.odo.frame_covariance(self.mcfg),
            ),
        )

    # -- requests and commands --------------------------------------------------------------
    def _drive(self, rid: int, distance_m: float, speed_mps: float) -> None:
        self._start(rid, "drive", mp.drive_plan(distance_m, speed_mps, self.mcfg), f"{distance_m:.3f} m")

    def _turn(self, rid: int, angle_rad: float, rate_rps: float) -> None:
        self._start(rid, "turn", mp.turn_plan(angle_rad, rate_rps, self.mcfg), f"{math.degrees(angle_rad):.1f} deg")

    def _goto(self, rid: int, x: float, y: float, yaw: float | None, speed_mps: float) -> None:
        self._start(rid, "goto", mp.goto_plan(self.odo.pose, x, y, yaw, speed_mps, self.mcfg), f"to ({x:.3f}, {y:.3f})")

    def _on_request(self, req: MotionRequest, now: float) -> None:
        try:
            if req.kind == "drive":
                self._drive(req.request_id, req.distance_m, req.speed)
            elif req.kind == "turn":
                self._turn(req.request_id, req.angle_rad, req.speed)
            elif req.kind == "goto" and req.target is not None:
                x, y, yaw = req.target
                self._goto(req.request_id, x, y, None if math.isnan(yaw) else yaw, req.speed)
            elif req.kind == "mast" and req.joints is not None:
                self._point_mast(req.request_id, *req.joints)
            elif req.kind == "stop":
                self.cmd_STOP()
                self._status(req.request_id, "stop", MoveOutcome.DONE)
            elif req.kind == "clear_faults":  # the mission's SAFE recovery (never releases an E-stop)
                motors = self._motors()
                if motors is not None and motors.estopped:
                    raise CommandError("emergency stop engaged: only the operator releases it")
                self.cmd_CLEAR_FAULTS()
                self._status(req.request_id, "clear_faults", MoveOutcome.DONE)
            else:
                raise CommandError(f"malformed request kind {req.kind!r}")
        except (CommandError, ValueError) as exc:
            self.event("MOVE_REFUSED", kind=req.kind, rid=req.request_id, reason=str(exc))
            self._status(req.request_id, req.kind, MoveOutcome.REFUSED, str(exc))

    def cmd_DRIVE(self, distance_m: float, speed_mps: float) -> None:
        self._drive(-1, distance_m, speed_mps)

    def cmd_TURN(self, angle_deg: float, rate_dps: float) -> None:
        self._turn(-1, math.radians(angle_deg), math.radians(rate_dps))

    def cmd_GOTO(self, x_m: float, y_m: float, yaw_deg: float, use_yaw: bool) -> None:
        self._goto(-1, x_m, y_m, math.radians(yaw_deg) if use_yaw else None, 0.0)

    def cmd_POINT_MAST(self, pan_deg: float, tilt_deg: float, lift_m: float) -> None:
        self._point_mast(-1, math.radians(pan_deg), math.radians(tilt_deg), lift_m)

    def cmd_SET_SHOULDERS(self, angle_deg: float) -> None:
        self._refuse_if_unsafe()
        motors = self._motors()
        assert motors is not None
        for w in WHEELS:
            motors.set_setpoint(f"SHOULDER_{w}", math.radians(angle_deg))

    def cmd_STOP(self) -> None:
        self._abort("STOP commanded")
        mast = self._mast()
        if mast is not None and self.mast_goal is not None:
            mast.stop()
            self.mast_goal = None

    def cmd_ESTOP(self, engage: bool) -> None:
        motors = self._motors()
        if motors is None:
            raise CommandError("no motor driver configured")
        if engage:
            self.cmd_STOP()
        motors.estop(engage, self.ctx.clock.now())
        self.event("ESTOP_COMMANDED", action="engaged" if engage else "released")

    def cmd_CLEAR_FAULTS(self) -> None:
        motors, mast = self._motors(), self._mast()
        if motors is None and mast is None:
            raise CommandError("no motor or mast driver configured")
        if motors is not None:
            motors.clear_faults()
        if mast is not None:
            mast.clear_fault()
        self.event("FAULTS_CLEARED")

    def cmd_SET_ODOMETRY(self, x_m: float, y_m: float, yaw_deg: float) -> None:
        self.odo.reset((x_m, y_m, math.radians(yaw_deg)))
        self.attitude.reset()
        self.event("ODOMETRY_SET", x=x_m, y=y_m, yaw=yaw_deg)
