"""Moves the wheels (CAN motor driver) and the mast (serial driver); keeps the odometry.

Thin: the kinematics are ``fsw.core.wheel_kinematics``; the drivers do the bytes. Moves come
as ground commands (DRIVE, TURN, GOTO, POINT_MAST, STOP, ESTOP, CLEAR_FAULTS, ...) or as
``MotionRequest`` messages on ``motion.request`` (the mission sequencer; ALGORITHM.md §3:
"move (mast + wheels)"), each answered once on ``motion.status``. A wheel move is a list of
segments, each *steer* (wheels to their angles, drive stopped) then *move* (drive or turn in
place on a trapezoidal profile, closed on odometry). A critical driver fault aborts the move
and stops the drives; moves are refused until CLEAR_FAULTS. Every frame the task publishes
the dead-reckoned pose with a growing covariance and the mast joints on ``nav.pose``
(the §5 localization refines it) and sends the commands (``motors.transmit``).

Schedule it after ``devices`` in the fast group (it polls the drivers itself otherwise).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from fsw.config import param
from fsw.core import wheel_kinematics as wk
from fsw.core.attitude import AttitudeTracker
from fsw.drivers import can_motors, mast_serial
from fsw.executive.commands import Arg, CommandDef, CommandError
from fsw.executive.task import Task
from fsw.executive.telemetry import Channel, EventDef, Severity
from fsw.tasks.messages import MOTION_REQUEST, MOTION_STATUS, NAV_POSE, MotionRequest, MotionStatus, NavPose

WHEELS = wk.WHEEL_ORDER


@dataclass(frozen=True)
class MotionConfig:
    drive_speed_mps: float = param(0.15, lo=0.005, hi=5.0, units="m/s", doc="default drive speed")
    turn_rate_dps: float = param(15.0, lo=0.5, hi=360.0, units="deg/s", doc="default turn rate")
    accel_mps2: float = param(0.2, lo=0.01, hi=10.0, units="m/s^2")
    yaw_accel_dps2: float = param(30.0, lo=1.0, hi=1000.0, units="deg/s^2")
    min_speed_mps: float = param(0.01, lo=0.0, hi=1.0, units="m/s", doc="creep speed near the goal")
    steer_tolerance_deg: float = param(2.0, lo=0.1, hi=20.0, units="deg", doc="steered before driving")
    steer_timeout_s: float = param(4.0, lo=0.1, hi=60.0, units="s")
    position_tolerance_m: float = param(0.005, lo=0.0005, hi=0.5, units="m")
    yaw_tolerance_deg: float = param(0.3, lo=0.01, hi=10.0, units="deg")
    mast_tolerance_deg: float = param(0.3, lo=0.01, hi=10.0, units="deg")
    mast_lift_tolerance_m: float = param(0.003, lo=0.0001, hi=0.1, units="m")
    mast_timeout_s: float = param(20.0, lo=0.5, hi=600.0, units="s")
    odo_sigma_per_m: float = param(0.02, lo=0.0, hi=1.0, units="m/m", doc="odometry sigma growth per metre")
    odo_yaw_sigma_per_rad: float = param(0.02, lo=0.0, hi=1.0, units="rad/rad")


@dataclass
class _Segment:
    kind: str  # "drive" | "turn"
    amount: float  # m or rad, signed
    speed: float  # m/s or rad/s
    steer: np.ndarray
    phase: str = "steer"
    t_phase: float = 0.0
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    yaw_acc0: float = 0.0
    cmd: float = 0.0  # last commanded speed (ramp)


class MotionTask(Task):
    KIND: ClassVar[str] = "motion"
    DOC: ClassVar[str] = "Wheel and mast moves through the drivers; odometry; motion fault handling."
    CHANNELS = (
        Channel("state", doc="IDLE, STEER, DRIVE, TURN or ESTOP"),
        Channel("odo_x_m", "m"),
        Channel("odo_y_m", "m"),
        Channel("odo_yaw_deg", "deg"),
        Channel("odo_path_m", "m", doc="distance driven"),
        Channel("cmd_speed", "m/s or rad/s", doc="commanded speed of the active segment"),
        Channel("remaining", "m or deg", doc="left of the active segment"),
        Channel("mast_busy", "bool"),
        Channel("moves_done", "count"),
        Channel("moves_aborted", "count", hi=0),
    )
    EVENTS = (
        EventDef("MOVE_STARTED", Severity.ACTIVITY_HI, "{kind} request {rid}: {what}"),
        EventDef(
            "MOVE_DONE", Severity.ACTIVITY_HI, "{kind} request {rid} done; odometry ({x:.3f}, {y:.3f}) m, {yaw:.1f} deg"
        ),
        EventDef("MOVE_ABORTED", Severity.WARNING_HI, "{kind} request {rid} aborted: {reason}"),
        EventDef("MOVE_REFUSED", Severity.WARNING_LO, "{kind} request {rid} refused: {reason}", throttle=5),
        EventDef("MAST_POINTED", Severity.ACTIVITY_HI, "mast at pan {pan:.2f} tilt {tilt:.2f} deg lift {lift:.3f} m"),
        EventDef("ESTOP_COMMANDED", Severity.WARNING_HI, "emergency stop {action} by command"),
        EventDef("FAULTS_CLEARED", Severity.ACTIVITY_HI, "motor and mast faults cleared by command"),
        EventDef("NO_DEVICE", Severity.WARNING_HI, "motion: no {device} driver configured"),
        EventDef("ODOMETRY_SET", Severity.ACTIVITY_HI, "odometry set to ({x:.3f}, {y:.3f}) m, {yaw:.1f} deg"),
    )
    COMMANDS = (
        CommandDef(
            "DRIVE",
            (Arg("distance_m", float, -20.0, 20.0, units="m"), Arg("speed_mps", float, 0.0, 5.0, units="m/s")),
            "drive straight; speed 0: default",
        ),
        CommandDef(
            "TURN",
            (Arg("angle_deg", float, -720.0, 720.0, units="deg"), Arg("rate_dps", float, 0.0, 360.0, units="deg/s")),
            "turn in place, CCW +; rate 0: default",
        ),
        CommandDef(
            "GOTO",
            (
                Arg("x_m", float, -1e4, 1e4, units="m"),
                Arg("y_m", float, -1e4, 1e4, units="m"),
                Arg("yaw_deg", float, -360.0, 360.0, units="deg"),
                Arg("use_yaw", bool),
            ),
            "turn, drive, turn to a pose in the odometry frame",
        ),
        CommandDef(
            "POINT_MAST",
            (
                Arg("pan_deg", float, -180.0, 180.0, units="deg"),
                Arg("tilt_deg", float, -90.0, 90.0, units="deg"),
                Arg("lift_m", float, 0.0, 2.0, units="m"),
            ),
            "move the mast joints",
        ),
        CommandDef("SET_SHOULDERS", (Arg("angle_deg", float, -90.0, 90.0, units="deg"),), "all four shoulder joints"),
        CommandDef("STOP", doc="stop the wheels and the mast; drop the active move"),
        CommandDef("ESTOP", (Arg("engage", bool),), "broadcast the CAN emergency stop (or release it)"),
        CommandDef("CLEAR_FAULTS", doc="clear latched motor controller and mast faults"),
        CommandDef(
            "SET_ODOMETRY",
            (Arg("x_m", float, -1e4, 1e4), Arg("y_m", float, -1e4, 1e4), Arg("yaw_deg", float, -360.0, 360.0)),
            "reset the dead-reckoned pose",
        ),
    )

    def setup(self) -> None:
        cfg = self.ctx.cfg
        self.mcfg: MotionConfig = getattr(cfg, "motion", MotionConfig())
        self.r = cfg.rover.wheel_diameter_m / 2.0
        self.wheel_xy = wk.wheel_positions(cfg.rover)
        self.pinv = wk.body_motion_matrix(self.wheel_xy)
        self.pose = (0.0, 0.0, 0.0)
        self.path_m = self.turned_rad = self.yaw_acc = 0.0
        cap = cfg.capture
        self.attitude = AttitudeTracker(cap.unknown_attitude_sigma_deg, cap.z_sigma_per_m)
        self._last_drive: np.ndarray | None = None
        self.segments: deque[_Segment] = deque()
        self.active: tuple[int, str] | None = None  # (request id, kind) of the wheel move
        self.mast_goal: tuple[int, tuple[float, float, float], float] | None = None
        self.steer_hold = np.zeros(4)
        self.done = self.aborted = 0
        self.requests = self.subscribe(MOTION_REQUEST, depth=8)
        self._warned: set[str] = set()

    # -- devices ----------------------------------------------------------------------------
    def _motors(self) -> can_motors.CanMotorDriver | None:
        return self._device("motors", can_motors.CanMotorDriver)

    def _mast(self) -> mast_serial.MastSerialDriver | None:
        return self._device("mast", mast_serial.MastSerialDriver)

    def _device(self, key: str, cls: type) -> Any:
        d = self.ctx.resources.get(key)
        if isinstance(d, cls):
            return d
        if key not in self._warned:
            self._warned.add(key)
            self.event("NO_DEVICE", device=key)
        return None

    # -- the frame --------------------------------------------------------------------------
    def run(self, frame: int) -> None:
        now = self.ctx.clock.now()
        motors, mast = self._motors(), self._mast()
        for drv in (motors, mast):
            if drv is not None and drv.last_poll_s != now:
                drv.poll(now)
        while (req := self.requests.get()) is not None:
            self._on_request(req, now)
        if motors is not None:
            self._odometry(motors)
            if self.active is not None and motors.faults & can_motors.CRITICAL:
                self._abort("motor faults: " + ",".join(motors.fault_names()))
            self._control(motors, now)
            motors.transmit(now)
        self._track_mast(mast, now)
        self._publish(now, mast)

    def _odometry(self, motors: can_motors.CanMotorDriver) -> None:
        drive = [motors.axes[f"DRIVE_{w}"] for w in WHEELS]
        steer = [motors.axes[f"STEER_{w}"] for w in WHEELS]
        if any(s.t_status is None for s in drive + steer):
            return
        pos = np.array([s.position_rad for s in drive])
        if self._last_drive is not None:
            motion = wk.body_motion(
                (pos - self._last_drive) * self.r, np.array([s.position_rad for s in steer]), self.pinv
            )
            self.attitude.integrate(motion, self.pose[2])
            self.pose = wk.integrate_pose(self.pose, motion)
            self.path_m += math.hypot(motion[0], motion[1])
            self.turned_rad += abs(motion[2])
            self.yaw_acc += float(motion[2])
        self._last_drive = pos

    def _control(self, motors: can_motors.CanMotorDriver, now: float) -> None:
        seg = self.segments[0] if self.segments else None
        rates = np.zeros(4)
        if seg is not None:
            rates = self._segment(seg, motors, now)
        if self.active is not None or motors.setpoints["DRIVE_FL"] is not None:
            for i, w in enumerate(WHEELS):
                motors.set_setpoint(f"DRIVE_{w}", float(rates[i]))
                motors.set_setpoint(f"STEER_{w}", float(self.steer_hold[i]))

    def _segment(self, seg: _Segment, motors: can_motors.CanMotorDriver, now: float) -> np.ndarray:
        c = self.mcfg
        self.steer_hold = seg.steer
        if seg.phase == "steer":
            meas = np.array([motors.axes[f"STEER_{w}"].position_rad for w in WHEELS])
            if np.all(np.abs(meas - seg.steer) <= math.radians(c.steer_tolerance_deg)):
                seg.phase, seg.t_phase, seg.origin, seg.yaw_acc0 = "move", now, self.pose, self.yaw_acc
            elif now - seg.t_phase > c.steer_timeout_s:
                self._abort(f"steering not reached in {c.steer_timeout_s:.1f} s")
            return np.zeros(4)
        dt = self.ctx.frame_period_s
        if seg.kind == "drive":
            x0, y0, h0 = seg.origin
            done = (self.pose[0] - x0) * math.cos(h0) + (self.pose[1] - y0) * math.sin(h0)
            rem, tol, acc, vmin = seg.amount - done, c.position_tolerance_m, c.accel_mps2, c.min_speed_mps
        else:
            rem = seg.amount - (self.yaw_acc - seg.yaw_acc0)
            tol, acc = math.radians(c.yaw_tolerance_deg), math.radians(c.yaw_accel_dps2)
            vmin = c.min_speed_mps / float(np.hypot(*self.wheel_xy[0]))
        self.tlm("remaining", rem if seg.kind == "drive" else math.degrees(rem))
        if rem * math.copysign(1.0, seg.amount) <= tol:
            self.segments.popleft()
            if not self.segments:
                self._finish()
            else:  # the next segment's steering time starts now, not when the move began
                self.segments[0].t_phase = now
            return np.zeros(4)
        speed = max(vmin, min(seg.speed, math.sqrt(2.0 * acc * abs(rem)), seg.cmd + acc * dt))
        seg.cmd = speed
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

    def _start(self, rid: int, kind: str, segs: list[tuple[str, float, float]], what: str) -> None:
        self._refuse_if_unsafe()
        if self.active is not None:
            self._abort("superseded")
        now = self.ctx.clock.now()
        for skind, amount, speed in segs:
            if skind == "drive":
                steer = np.zeros(4)
            else:
                steer, _ = wk.wheel_commands(0.0, 0.0, 1.0, self.wheel_xy, self.r)
            self.segments.append(_Segment(skind, amount, speed, steer, t_phase=now))
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
        x, y, yaw = self.pose
        self.event("MOVE_DONE", kind=kind, rid=rid, x=x, y=y, yaw=math.degrees(yaw))
        self._status(rid, kind, "done")

    def _abort(self, reason: str) -> None:
        self.segments.clear()
        if self.active is None:
            return
        rid, kind = self.active
        self.active = None
        self.aborted += 1
        self.event("MOVE_ABORTED", kind=kind, rid=rid, reason=reason)
        self._status(rid, kind, "aborted", reason)

    def _status(self, rid: int, kind: str, state: str, reason: str = "") -> None:
        self.publish(MOTION_STATUS, MotionStatus(rid, kind, state, reason, self.ctx.clock.now()))

    def _drive_segments(self, distance: float, speed: float) -> list[tuple[str, float, float]]:
        return [("drive", distance, speed or self.mcfg.drive_speed_mps)]

    def _turn_segments(self, angle: float, rate: float) -> list[tuple[str, float, float]]:
        return [("turn", angle, rate or math.radians(self.mcfg.turn_rate_dps))]

    def _goto_segments(self, x: float, y: float, yaw: float | None, speed: float) -> list[tuple[str, float, float]]:
        px, py, pyaw = self.pose
        dist, heading = math.hypot(x - px, y - py), math.atan2(y - py, x - px)
        turn1 = wk.wrap_angle(heading - pyaw)
        if abs(turn1) > math.pi / 2:  # closer to back up than to turn around
            turn1, dist = wk.wrap_angle(turn1 - math.pi), -dist
        segs: list[tuple[str, float, float]] = []
        if dist > self.mcfg.position_tolerance_m or -dist > self.mcfg.position_tolerance_m:
            if abs(turn1) > math.radians(self.mcfg.yaw_tolerance_deg):
                segs += self._turn_segments(turn1, 0.0)
            segs += self._drive_segments(dist, speed)
            pyaw += turn1
        if yaw is not None and abs(wk.wrap_angle(yaw - pyaw)) > math.radians(self.mcfg.yaw_tolerance_deg):
            segs += self._turn_segments(wk.wrap_angle(yaw - pyaw), 0.0)
        return segs

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
        fail = ""
        if mast.faults & mast_serial.CRITICAL:
            fail = "mast faults: " + ",".join(mast.fault_names())
        elif mast.last_result.startswith(("nak", "no_ack")) and not mast.busy:
            fail = mast.last_result
        elif now - t0 > self.mcfg.mast_timeout_s:
            fail = f"not at target after {self.mcfg.mast_timeout_s:.0f} s"
        if fail:
            self.mast_goal = None
            self.aborted += 1
            self.event("MOVE_ABORTED", kind="mast", rid=rid, reason=fail)
            self._status(rid, "mast", "aborted", fail)
            return
        q = mast.joints
        if q is None or mast.busy:
            return
        tol = math.radians(self.mcfg.mast_tolerance_deg)
        if (
            abs(q[0] - goal[0]) <= tol
            and abs(q[1] - goal[1]) <= tol
            and abs(q[2] - goal[2]) <= self.mcfg.mast_lift_tolerance_m
        ):
            self.mast_goal = None
            self.done += 1
            self.event("MAST_POINTED", pan=math.degrees(q[0]), tilt=math.degrees(q[1]), lift=q[2])
            self._status(rid, "mast", "done")

    def _publish(self, now: float, mast: mast_serial.MastSerialDriver | None) -> None:
        x, y, yaw = self.pose
        self.tlm(
            "state",
            "ESTOP"
            if (m := self.ctx.resources.get("motors")) is not None and getattr(m, "estopped", False)
            else (
                self.segments[0].kind.upper()
                if self.segments and self.segments[0].phase == "move"
                else "STEER"
                if self.segments
                else "IDLE"
            ),
        )
        self.tlm("odo_x_m", x)
        self.tlm("odo_y_m", y)
        self.tlm("odo_yaw_deg", math.degrees(yaw))
        self.tlm("odo_path_m", self.path_m)
        self.tlm("mast_busy", int(self.mast_goal is not None))
        self.tlm("moves_done", self.done)
        self.tlm("moves_aborted", self.aborted)
        s_xy = self.mcfg.odo_sigma_per_m * self.path_m
        s_yaw = self.mcfg.odo_yaw_sigma_per_rad * self.turned_rad + self.mcfg.odo_sigma_per_m * self.path_m
        joints = mast.joints if mast is not None and mast.joints is not None else (math.nan,) * 3
        imu = self.ctx.resources.get("imu")
        self.attitude.update(imu.attitude(now) if imu is not None else None)
        att = self.attitude.state()
        self.publish(
            NAV_POSE,
            NavPose(
                now,
                x,
                y,
                yaw,
                np.diag([s_xy**2, s_xy**2, s_yaw**2]),
                joints,
                moving=self.active is not None or self.mast_goal is not None,
                roll=att.roll,
                pitch=att.pitch,
                z_m=att.z_m,
                att_cov=att.cov,
                attitude_valid=att.valid,
            ),
        )

    # -- requests and commands --------------------------------------------------------------
    def _on_request(self, req: MotionRequest, now: float) -> None:
        try:
            if req.kind == "drive":
                self._start(
                    req.request_id, "drive", self._drive_segments(req.distance_m, req.speed), f"{req.distance_m:.3f} m"
                )
            elif req.kind == "turn":
                self._start(
                    req.request_id,
                    "turn",
                    self._turn_segments(req.angle_rad, req.speed),
                    f"{math.degrees(req.angle_rad):.1f} deg",
                )
            elif req.kind == "goto" and req.target is not None:
                x, y, yaw = req.target
                self._start(
                    req.request_id,
                    "goto",
                    self._goto_segments(x, y, None if math.isnan(yaw) else yaw, req.speed),
                    f"to ({x:.3f}, {y:.3f})",
                )
            elif req.kind == "mast" and req.joints is not None:
                self._point_mast(req.request_id, *req.joints)
            elif req.kind == "stop":
                self.cmd_STOP()
                self._status(req.request_id, "stop", "done")
            else:
                raise CommandError(f"malformed request kind {req.kind!r}")
        except (CommandError, ValueError) as exc:
            self.event("MOVE_REFUSED", kind=req.kind, rid=req.request_id, reason=str(exc))
            self._status(req.request_id, req.kind, "refused", str(exc))

    def cmd_DRIVE(self, distance_m: float, speed_mps: float) -> None:
        self._start(-1, "drive", self._drive_segments(distance_m, speed_mps), f"{distance_m:.3f} m")

    def cmd_TURN(self, angle_deg: float, rate_dps: float) -> None:
        self._start(
            -1, "turn", self._turn_segments(math.radians(angle_deg), math.radians(rate_dps)), f"{angle_deg:.1f} deg"
        )

    def cmd_GOTO(self, x_m: float, y_m: float, yaw_deg: float, use_yaw: bool) -> None:
        segs = self._goto_segments(x_m, y_m, math.radians(yaw_deg) if use_yaw else None, 0.0)
        self._start(-1, "goto", segs, f"to ({x_m:.3f}, {y_m:.3f})")

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
        self.pose = (x_m, y_m, math.radians(yaw_deg))
        self.path_m = self.turned_rad = 0.0
        self.attitude.reset()
        self.event("ODOMETRY_SET", x=x_m, y=y_m, yaw=yaw_deg)
