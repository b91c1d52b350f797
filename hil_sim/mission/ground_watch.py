"""Bench-side watch of a mission on unfamiliar ground (issue 13 item 3; docs/experiments.md).

The runner only watches: these checks build their own geofence from what the flight software
knows (its latest map and edge fit, its pose estimate) and never touch the flight code's state.

- :func:`reachable_stations`: at a step boundary, how many stations on the edge path (other
  than where the rover stands) the geofence would let the rover drive to (the edge check; the
  mission looks at unknown ground before it drives); with no edge mapped yet, the edge
  search's stations (wheels kept away from any mapped drop). A mission where the rover never moved
  although this was ever above zero is a mission that got stuck.
- :func:`wheels_on_unknown`: the rover moved with a true wheel position on ground the flight
  software's geofence did not know.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from fsw.core.edge.edge import edge_path
from fsw.core.edge.geofence import Geofence
from fsw.core.planning.view_candidates import path_stations
from fsw.tasks.mission_ground import fence_on


def reachable_stations(mission: Any, cfg: Any) -> int:
    """Stations on the edge path the geofence allows from the rover's estimated pose."""
    nav, latest, edge = mission.nav, mission.latest, mission.edge
    if nav is None or latest is None:
        return 0
    if edge is not None and edge.empty:
        edge = None
    here = (float(nav.x), float(nav.y), float(nav.yaw))
    fence = Geofence(cfg.geofence, cfg.rover)
    fence_on(fence, latest, edge, here)
    path = (np.zeros((0, 2)) if edge is None else
            edge_path(edge, cfg.edge.setback_m, cfg.edge.path_spacing_m, cfg.geofence.extend_m))
    stations = path_stations(path, here, lambda a, b: fence.check(a, b, known_ground=False).allowed,
                             cfg.nbv.station_spacing_m, cfg.nbv.max_travel_m)
    return max(0, len(stations) - 1)


def wheels_on_unknown(rig: Any, mission: Any, odo_before: float) -> int:
    """1 if the rover moved this frame with a wheel (true position) on ground the flight
    software's geofence does not know (unmapped, never stood on). The true wheels are taken
    into the flight map's frame (the odometry's, which starts at the world's ``rover_start``)."""
    if rig.rover.odometer_m <= odo_before + 1e-9:
        return 0
    xs, ys = rig.rover.world_wheel_xy()
    x0, y0, yaw0 = (float(v) for v in getattr(rig.world, "rover_start", (0.0, 0.0, 0.0)))
    c, s = math.cos(yaw0), math.sin(yaw0)
    dx, dy = np.asarray(xs) - x0, np.asarray(ys) - y0
    in_map = np.column_stack([c * dx + s * dy, -s * dx + c * dy])
    return int(not mission.ground.geofence.known.known_xy(in_map).all())
