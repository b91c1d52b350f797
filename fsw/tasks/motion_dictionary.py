"""What the motion task offers the outside: its channels, events and commands (F Prime: the
component's dictionary, declared apart from its implementation in ``fsw.tasks.motion``)."""

from __future__ import annotations

from fsw.framework.commands import Arg, CommandDef
from fsw.framework.telemetry import Channel, EventDef, Severity

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
    EventDef("NAV_FIXED", Severity.ACTIVITY_LO,
             "pose corrected by fix {fix}: {dxy_cm:.1f} cm, {dyaw:+.2f} deg, height {dz_cm:+.1f} cm; "
             "sigma {sxy_cm:.1f} cm"),
    EventDef("NAV_FIX_REFUSED", Severity.WARNING_LO, "navigation fix {fix} not applied: {reason}", throttle=5),
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
