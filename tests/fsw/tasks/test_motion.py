"""The motion task (fsw/tasks/motion.py) on a stepped clock with ideal fake drivers: every
request answered once on ``motion.status``, moves closed on odometry, faults abort, the mast
tracked to its goal (issue 11, item 5).

The fakes stand in for the CAN motor and serial mast drivers at their interface: drive axes
turn at their setpoint (rad/s), steer axes are at their setpoint, the mast reaches its goal
at a fixed joint rate. No bus, no serial port, no HIL.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest
from task_rig import TaskRig, task_config

from fsw.core.localization.nav_fix import NavFix
from fsw.core.motion.wheel_kinematics import WHEEL_ORDER
from fsw.drivers import can_motors, mast_serial
from fsw.drivers.resources import Resources
from fsw.tasks.messages import MOTION_REQUEST, MOTION_STATUS, NAV_FIX, NAV_POSE, MotionRequest

CFG = task_config(("motion", "motion"))


class _Axis:
    def __init__(self) -> None:
        self.position_rad = 0.0
        self.t_status: float | None = None


class FakeMotors:
    """Ideal motor controllers at the driver's interface."""

    def __init__(self) -> None:
        names = [f"{k}_{w}" for k in ("DRIVE", "STEER", "SHOULDER") for w in WHEEL_ORDER]
        self.axes = {n: _Axis() for n in names}
        self.setpoints: dict[str, float | None] = {n: None for n in names}
        self.faults = 0
        self.estopped = False
        self.last_poll_s: float | None = None
        self.transmits = 0

    def poll(self, now: float) -> None:
        dt = 0.0 if self.last_poll_s is None else now - self.last_poll_s
        self.last_poll_s = now
        for name, ax in self.axes.items():
            sp = self.setpoints[name]
            if sp is not None and not self.estopped:
                if name.startswith("DRIVE"):
                    ax.position_rad += sp * dt
                else:
                    ax.position_rad = sp
            ax.t_status = now

    def set_setpoint(self, axis: str, value: float | None) -> None:
        self.setpoints[axis] = value

    def transmit(self, now: float) -> None:
        self.transmits += 1

    def fault_names(self) -> list[str]:
        return [f"0x{self.faults:x}"] if self.faults else []

    def estop(self, engage: bool, now: float) -> None:
        self.estopped = engage

    def clear_faults(self) -> None:
        self.faults = 0


class FakeMast:
    """A mast that moves each joint toward its goal at ``rate`` per second."""

    def __init__(self, rate: float = 0.5) -> None:
        self.joints: tuple[float, float, float] | None = (0.0, 0.0, 0.0)
        self.goal: tuple[float, float, float] | None = None
        self.rate, self.faults, self.busy, self.last_result = rate, 0, False, ""
        self.last_poll_s: float | None = None

    def poll(self, now: float) -> None:
        dt = 0.0 if self.last_poll_s is None else now - self.last_poll_s
        self.last_poll_s = now
        if self.goal is not None and self.joints is not None and not self.faults:
            step = self.rate * dt
            self.joints = tuple(q + max(-step, min(step, g - q)) for q, g in zip(self.joints, self.goal, strict=True))

    def move(self, pan: float, tilt: float, lift: float) -> None:
        self.goal = (pan, tilt, lift)
        self.last_result = "ack"

    def stop(self) -> None:
        self.goal = None

    def fault_names(self) -> list[str]:
        return [f"0x{self.faults:x}"] if self.faults else []

    def clear_fault(self) -> None:
        self.faults = 0


def _rig(motors: bool = True, mast: bool = True) -> tuple[TaskRig, Any, Any]:
    m, s = (FakeMotors() if motors else None), (FakeMast() if mast else None)
    rig = TaskRig(CFG, Resources(motors=m, mast=s))  # type: ignore[arg-type]
    return rig, rig.tap(MOTION_STATUS), rig.tap(NAV_POSE)


def _until_status(rig: TaskRig, statuses: Any, frames: int = 600) -> Any:
    rig.run_until(lambda: len(statuses) > 0, frames)
    (st,) = statuses.drain()
    return st


def test_a_drive_request_ends_done_at_the_distance_on_odometry() -> None:
    rig, statuses, poses = _rig()
    rig.publish(MOTION_REQUEST, MotionRequest(1, "drive", distance_m=0.3))
    st = _until_status(rig, statuses)
    assert (st.request_id, st.kind, st.state) == (1, "drive", "done")
    nav = poses.drain()[-1]  # the odometry pose, published every frame
    assert nav.x == pytest.approx(0.3, abs=CFG.motion.position_tolerance_m)
    assert abs(nav.y) < 1e-9 and abs(nav.yaw) < 1e-9 and not nav.moving
    assert nav.cov[0, 0] > 0 and rig.tlm("motion.odo_x_m") == nav.x  # the covariance grows with the path
    assert rig.tlm("motion.moves_done") == 1 and len(rig.events("motion.MOVE_DONE")) == 1
    rig.run(20)
    assert not statuses.drain()  # answered once


def test_goto_turns_drives_and_turns_to_the_pose() -> None:
    rig, statuses, poses = _rig()
    rig.publish(MOTION_REQUEST, MotionRequest(2, "goto", target=(0.2, 0.2, math.radians(90.0))))
    st = _until_status(rig, statuses, 2000)
    assert (st.request_id, st.state) == (2, "done")
    nav = poses.drain()[-1]
    x, y, yaw = nav.x, nav.y, nav.yaw
    assert x == pytest.approx(0.2, abs=0.01) and y == pytest.approx(0.2, abs=0.01)
    assert math.degrees(yaw) == pytest.approx(90.0, abs=0.5)


def test_a_critical_motor_fault_aborts_the_move_and_refuses_the_next() -> None:
    rig, statuses, _ = _rig()
    motors = rig.exe.ctx.res.motors
    rig.publish(MOTION_REQUEST, MotionRequest(3, "drive", distance_m=1.0))
    rig.run(10)
    motors.faults = can_motors.F_MOTOR
    st = _until_status(rig, statuses, 5)
    assert (st.request_id, st.state) == (3, "aborted") and "motor faults" in st.reason
    rig.publish(MOTION_REQUEST, MotionRequest(4, "drive", distance_m=0.1))
    st = _until_status(rig, statuses, 5)
    assert (st.request_id, st.state) == (4, "refused") and "CLEAR_FAULTS" in st.reason
    assert rig.command("motion.CLEAR_FAULTS").status.name == "OK" and motors.faults == 0
    rig.publish(MOTION_REQUEST, MotionRequest(5, "drive", distance_m=0.05))
    assert _until_status(rig, statuses).state == "done"


def test_stop_and_a_superseding_move_answer_the_active_one() -> None:
    rig, statuses, _ = _rig()
    rig.publish(MOTION_REQUEST, MotionRequest(6, "drive", distance_m=1.0))
    rig.run(5)
    rig.publish(MOTION_REQUEST, MotionRequest(7, "turn", angle_rad=0.2))
    rig.run(1)
    assert [(s.request_id, s.state, s.reason) for s in statuses.drain()] == [(6, "aborted", "superseded")]
    rig.publish(MOTION_REQUEST, MotionRequest(0, "stop"))
    rig.run(1)
    assert [(s.request_id, s.state) for s in statuses.drain()] == [(7, "aborted"), (0, "done")]


def test_the_mast_is_tracked_to_its_goal() -> None:
    rig, statuses, poses = _rig()
    goal = (math.radians(20.0), math.radians(-40.0), 0.4)
    rig.publish(MOTION_REQUEST, MotionRequest(8, "mast", joints=goal))
    rig.run(1)
    assert rig.tlm("motion.mast_busy") == 1
    st = _until_status(rig, statuses)
    assert (st.request_id, st.kind, st.state) == (8, "mast", "done")
    assert poses.drain()[-1].joints == pytest.approx(goal, abs=math.radians(CFG.motion.mast_tolerance_deg))
    assert len(rig.events("motion.MAST_POINTED")) == 1


def test_mast_outside_its_limits_or_faulted_is_refused_or_aborted() -> None:
    rig, statuses, _ = _rig()
    rig.publish(MOTION_REQUEST, MotionRequest(9, "mast", joints=(0.0, math.radians(80.0), 0.0)))
    st = _until_status(rig, statuses, 2)
    assert (st.state, st.reason) == ("refused", "mast joints outside the limits of [mast]")
    mast = rig.exe.ctx.res.mast
    rig.publish(MOTION_REQUEST, MotionRequest(10, "mast", joints=(0.5, -0.5, 0.3)))
    rig.run(2)
    mast.faults = mast_serial.CRITICAL
    st = _until_status(rig, statuses, 3)
    assert (st.request_id, st.state) == (10, "aborted") and st.reason.startswith("mast faults")


def test_without_drivers_requests_are_refused_with_an_event() -> None:
    rig, statuses, poses = _rig(motors=False, mast=False)
    rig.publish(MOTION_REQUEST, MotionRequest(11, "drive", distance_m=0.1))
    rig.publish(MOTION_REQUEST, MotionRequest(12, "mast", joints=(0.0, -0.5, 0.2)))
    rig.publish(MOTION_REQUEST, MotionRequest(13, "hover"))
    rig.run(1)
    assert [(s.request_id, s.state) for s in statuses.drain()] == [(11, "refused"), (12, "refused"), (13, "refused")]
    assert sorted(e.text for e in rig.events("motion.NO_DEVICE")) == [
        "motion: no mast driver configured", "motion: no motors driver configured"]
    assert rig.task("motion").exceptions == 0 and len(poses.drain()) == 1  # the pose goes on


def test_estop_holds_the_wheels_and_refuses_moves() -> None:
    rig, statuses, _ = _rig()
    assert rig.command("motion.ESTOP", engage=True).status.name == "OK"
    assert rig.command("motion.DRIVE", distance_m=0.1, speed_mps=0.0).status.name == "EXECUTION_ERROR"
    rig.run(1)
    assert rig.tlm("motion.state") == "ESTOP"
    assert rig.command("motion.ESTOP", engage=False).status.name == "OK"
    assert rig.command("motion.DRIVE", distance_m=0.1, speed_mps=0.0).status.name == "OK"
    st = _until_status(rig, statuses)
    assert (st.request_id, st.state) == (-1, "done")


def test_a_clear_faults_request_clears_latched_faults_but_never_an_estop() -> None:
    """The mission's SAFE recovery asks the motion task to clear the latched driver faults
    (fsw/tasks/mission_safe.py); an engaged emergency stop is the operator's to release."""
    rig, statuses, _ = _rig()
    motors, mast = rig.exe.ctx.res.motors, rig.exe.ctx.res.mast
    motors.faults, mast.faults = can_motors.F_MOTOR, 1
    rig.publish(MOTION_REQUEST, MotionRequest(8, "clear_faults"))
    st = _until_status(rig, statuses, 5)
    assert (st.request_id, st.kind, st.state) == (8, "clear_faults", "done")
    assert motors.faults == 0 and mast.faults == 0 and len(rig.events("motion.FAULTS_CLEARED")) == 1
    assert rig.command("motion.ESTOP", engage=True).status.name == "OK"
    motors.faults = can_motors.F_MOTOR
    rig.publish(MOTION_REQUEST, MotionRequest(9, "clear_faults"))
    st = _until_status(rig, statuses, 5)
    assert (st.request_id, st.state) == (9, "refused") and "emergency stop" in st.reason
    assert motors.estopped and motors.faults == can_motors.F_MOTOR


def test_a_navigation_fix_corrects_the_pose_between_moves_only_on_its_frame() -> None:
    """A registered view's correction (``nav.fix``, fsw.core.localization.nav_fix) waits for the active move
    to end, then moves the pose and resets its covariance; one found on another frame of the
    pose is refused with an event, never applied twice."""
    rig, statuses, poses = _rig()
    rig.publish(MOTION_REQUEST, MotionRequest(1, "drive", distance_m=0.3))
    rig.run(3)
    fix = NavFix.from_correction(1, 0.0, np.array([0.1, 0.0, 0.8]), np.r_[0.0, 0.0, 0.0, 0.05, -0.02, 0.01],
                                 np.eye(6) * 1e-6)
    rig.publish(NAV_FIX, fix)
    rig.run(3)
    assert poses.drain()[-1].fix_id == 0  # not during the drive
    st = _until_status(rig, statuses)
    assert st.state == "done"
    rig.run(2)
    nav = poses.drain()[-1]
    assert (nav.fix_id, nav.fix_seen) == (1, 1)
    assert nav.x == pytest.approx(0.35, abs=CFG.motion.position_tolerance_m)
    assert nav.y == pytest.approx(-0.02) and nav.z_m == pytest.approx(0.01)
    assert nav.cov[0, 0] == pytest.approx(1e-6) and len(rig.events("motion.NAV_FIXED")) == 1
    rig.publish(NAV_FIX, dataclasses.replace(fix, fix_id=2, base_id=0))  # found before fix 1
    rig.run(2)
    nav2 = poses.drain()[-1]
    assert (nav2.fix_id, nav2.fix_seen) == (1, 2) and nav2.x == nav.x
    assert len(rig.events("motion.NAV_FIX_REFUSED")) == 1
