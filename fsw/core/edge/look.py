"""Look before you drive: the mast pose that views the ground a move would cross
(docs/algorithm.md §2, §4; issue 13 item 3).

The geofence refuses a move whose wheels would cross ground the map has not measured
(``fsw.core.edge.known_ground``). Before giving up on such a station, the mission takes one view
from where the rover stands, aimed at the unknown ground: pan toward the centroid of the
unknown cells, the tilt that puts it at the image centre (within the mast limits), the mast
at full lift. The view is an ordinary imaging step: it is merged and fitted like any other.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import MastConfig

Pose3 = tuple[float, float, float]


def look_joints(rover: Pose3, target_xy: NDArray[np.float64], mast: MastConfig,
                ground_z_m: float = 0.0) -> Pose3:
    """Mast joints ``(pan, tilt, lift)`` that centre the view on the mean of ``target_xy``;
    ``ground_z_m``: the target ground's height relative to the ground under the rover (the
    unknown ground a move would cross is taken at the rover's own height)."""
    x, y, yaw = rover
    c, s = math.cos(yaw), math.sin(yaw)
    bx = x + c * mast.base_x_m - s * mast.base_y_m
    by = y + s * mast.base_x_m + c * mast.base_y_m
    tx, ty = (float(v) for v in np.asarray(target_xy, dtype=np.float64).reshape(-1, 2).mean(axis=0))
    lift = mast.lift_max_m
    height = mast.base_z_m + lift - ground_z_m
    pan = math.remainder(math.atan2(ty - by, tx - bx) - yaw, math.tau)
    tilt = -math.atan2(height, max(math.hypot(tx - bx, ty - by), 1e-3))
    return mast.clamp(pan, tilt, lift)
