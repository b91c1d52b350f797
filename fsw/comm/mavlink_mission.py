"""The planned stations and the geofence, readable by the MAVLink MISSION/FENCE protocol.

A stock ground station downloads a plan with MISSION_REQUEST_LIST (``mission_type``) ->
MISSION_COUNT, then MISSION_REQUEST_INT (or MISSION_REQUEST) per item -> MISSION_ITEM_INT,
and ends with MISSION_ACK. The rover has no GPS: every item is in MAV_FRAME_LOCAL_NED
around the mission's origin (the world frame of LOCAL_POSITION_NED and HOME_POSITION),
``x`` = north = world +x, ``y`` = east = world -y, in metres times 1e4 (the MISSION_ITEM_INT
convention for local frames).

* ``MAV_MISSION_TYPE_MISSION``: the stations of the mission, visited ones first, then the
  one the rover goes to, as MAV_CMD_NAV_WAYPOINT (``param4`` = yaw, deg, NED); ``current``
  marks the station in progress.
* ``MAV_MISSION_TYPE_FENCE``: the geofence as exclusion polygons
  (MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION, ``param1`` = vertex count): the ground within
  the fence margin of the fitted edge, where no wheel may go (``fsw.core.edge.geofence``).
* ``MAV_MISSION_TYPE_RALLY``: none (count 0).

The plan is read-only: uploads (MISSION_COUNT from the ground) are not handled. Sans-I/O.
"""

from __future__ import annotations

import math

from fsw.comm.mavlink_dialect import mavlink
from fsw.comm.mavlink_plan import GroundPlan

LOCAL_SCALE = 1e4  # MISSION_ITEM_INT x/y in local frames: metres * 1e4


def _xy(x: float, y: float) -> tuple[int, int]:
    """World (x, y) -> MISSION_ITEM_INT x (north) and y (east) in 1e-4 m, clamped to int32."""
    def c(v: float) -> int:
        return max(-(2**31), min(2**31 - 1, int(round(v * LOCAL_SCALE))))
    return c(x), c(-y)


def items(plan: GroundPlan, mission_type: int) -> list[tuple[int, float, tuple[int, int], bool]]:
    """``(command, param1, (x, y), current)`` of every item of ``mission_type``."""
    if mission_type == mavlink.MAV_MISSION_TYPE_MISSION:
        return [(mavlink.MAV_CMD_NAV_WAYPOINT, 0.0, _xy(x, y), i == plan.current)
                for i, (x, y, _) in enumerate(plan.stations)]
    if mission_type == mavlink.MAV_MISSION_TYPE_FENCE:
        return [(mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION, float(len(ring)), _xy(x, y), False)
                for ring in plan.fence for (x, y) in ring]
    return []


def count(plan: GroundPlan, mission_type: int, target: tuple[int, int]) -> mavlink.MAVLink_mission_count_message:
    return mavlink.MAVLink_mission_count_message(target[0], target[1], len(items(plan, mission_type)), mission_type)


def item(plan: GroundPlan, mission_type: int, seq: int, target: tuple[int, int]) -> mavlink.MAVLink_message:
    """MISSION_ITEM_INT ``seq``, or MISSION_ACK(INVALID_SEQUENCE) when there is no such item."""
    its = items(plan, mission_type)
    if not 0 <= seq < len(its):
        return mavlink.MAVLink_mission_ack_message(target[0], target[1], mavlink.MAV_MISSION_INVALID_SEQUENCE,
                                                   mission_type)
    command, p1, (x, y), current = its[seq]
    yaw = 0.0
    if mission_type == mavlink.MAV_MISSION_TYPE_MISSION:
        yaw = math.degrees(-plan.stations[seq][2])  # CCW from world +x -> CW from north
    return mavlink.MAVLink_mission_item_int_message(
        target[0], target[1], seq, mavlink.MAV_FRAME_LOCAL_NED, command, int(current), 1,
        p1, 0.0, 0.0, yaw, x, y, 0.0, mission_type)
