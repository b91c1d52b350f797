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

    def focus_regions(self, weight: float = 4.0, margin_m: float = 0.6) -> tuple[tuple[float, ...], ...]:
        """What the Cliff-bot's task needs mapped, as the RECON-bot's view planning focus
        (``[nbv] focus_regions``, docs/algorithm.md §3.4): the plateau between the anchors and
        the lip (the Cliff-bot's start), and the face from the lip down past the targets."""
        ax0, ax1 = float(self.anchors_xy[:, 0].min()), float(self.anchors_xy[:, 0].max())
        ay = float(self.anchors_xy[:, 1].max())
        xs = np.concatenate([self.targets_xyz[:, 0], [self.cliffbot_start_xy[0]]])
        lip = self.edge_y_m + 0.3
        plateau = (ax0, lip, ax1, ay + 0.3, weight)
        face = (float(xs.min()) - margin_m, float(self.targets_xyz[:, 1].min()) - margin_m,
                float(xs.max()) + margin_m, lip, weight)
        return (plateau, face)
