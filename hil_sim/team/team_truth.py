"""What a team scenario adds to a world's truth (docs/algorithm.md §8): the Anchorbots, the
Cliff-bot's start, the science targets and the rock jumble."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class TeamTruth:
    anchors_xy: F64  # (2, 2) the Anchorbots' winch positions on the plateau
    cliffbot_start_xy: F64  # (2,) where the Cliff-bot starts, on the plateau between them
    targets_xyz: F64  # (K, 3) science targets on the face
    jumble_xy_r: tuple[float, float, float, float]  # the jumble's centre x, y and semi-axes (m)
    face_slope_deg: float
    drop_m: float
    edge_y_m: float
