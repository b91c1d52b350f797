"""The mission's plan as the ground sees it: stations and geofence (``fsw.comm.mavlink_mission`` serves it).

Free of pymavlink, so that the mission task can build and publish it (bus topic ``[mavlink]
plan_topic``) without loading the MAVLink dialect.
"""

from __future__ import annotations

from dataclasses import dataclass

from fsw.core.edge.edge import EdgeModel
from fsw.core.edge.geofence import GeofenceConfig

XY = tuple[float, float]


@dataclass(frozen=True)
class GroundPlan:
    """What the mission publishes for the ground (bus topic ``[mavlink] plan_topic``)."""

    stations: tuple[tuple[float, float, float], ...] = ()  # x, y (m), yaw (rad), world frame
    current: int = -1  # index of the station in progress (-1: none)
    fence: tuple[tuple[XY, ...], ...] = ()  # exclusion polygons (world x, y, m), open rings


def ground_plan(stations: list[tuple[float, float, float]], edge: EdgeModel | None, fence: GeofenceConfig,
                tolerance_m: float = 0.05) -> GroundPlan:
    """The plan the mission publishes for the MISSION/FENCE protocol: the stations so far (the
    last one in progress) and the ground within ``margin_m`` of the fitted edge, extended as the
    geofence extends it, as exclusion polygons simplified to ``tolerance_m``."""
    rings: list[tuple[tuple[float, float], ...]] = []
    if edge is not None and not edge.empty:
        zone = edge.barrier(fence.extend_m).buffer(max(fence.margin_m, tolerance_m)).simplify(tolerance_m)
        for poly in getattr(zone, "geoms", [zone]):
            coords = list(poly.exterior.coords)[:-1]  # open ring: the protocol closes it
            rings.append(tuple((float(x), float(y)) for x, y in coords))
    return GroundPlan(tuple(stations), len(stations) - 1, tuple(rings))
